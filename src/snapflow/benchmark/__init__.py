"""Benchmarks that write result files: batch-1 latency of any policy (``bench``) and the cost of a training step."""
