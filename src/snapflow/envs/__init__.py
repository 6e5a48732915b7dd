"""Simulated benchmarks. Import the submodule you need (``snapflow.envs.metaworld``); each pulls in its simulator."""
