"""The rig calibrated from the robot it watches: the robot's tube as the target (rig_fit, tube_distance)."""
