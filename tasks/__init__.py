"""mocapflow stages: pure functions of labelled arrays."""
