"""End-to-end experiments that the CLI runs."""
