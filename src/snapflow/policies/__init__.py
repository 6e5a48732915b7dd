"""Built-in policies, one folder each with its configuration and modeling."""
