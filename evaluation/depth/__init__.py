"""The depth mask measured against the simulator's true masks."""
