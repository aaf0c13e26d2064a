"""The robot's own model fitted to one frame's points and limbs (issue 61, part 2): core.fit.robot_fit."""
