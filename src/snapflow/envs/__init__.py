"""Simulated benchmarks behind one interface (:mod:`snapflow.envs.base`), registered by name in ``factory``.
Importing them is free: a simulator is imported when its first environment is built."""
