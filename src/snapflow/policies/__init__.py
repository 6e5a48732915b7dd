"""Built-in policies, one folder each (configuration, modeling, processor), registered by name in ``factory``."""
