"""Adapters that give other libraries' flow-matching policies the :class:`snapflow.protocol.FlowPolicy` protocol."""
