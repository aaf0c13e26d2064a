"""Point clouds from the cameras: deprojection, pairing by stamp, fusion into the base frame, filters."""
