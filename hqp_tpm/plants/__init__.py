"""Physics plants: MuJoCo models built from the robot's own description, stepped under the project's controllers."""
