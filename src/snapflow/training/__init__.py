"""Training teachers and SnapFlow students: data, loop, checkpoints."""
