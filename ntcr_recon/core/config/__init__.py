"""The rig configuration: reading, validating and documenting the parameter file."""
