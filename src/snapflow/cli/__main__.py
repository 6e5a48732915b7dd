"""``python -m snapflow.cli`` (as ``accelerate launch -m snapflow.cli`` runs it): the ``snapflow`` command."""

from snapflow.cli import entry_point

entry_point()
