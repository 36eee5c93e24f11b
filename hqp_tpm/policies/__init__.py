"""Dynamic stack policies; importing this package registers them with the scenario builder."""
