"""The robot: its geometry, kinematics, true surface and comb of notches."""
