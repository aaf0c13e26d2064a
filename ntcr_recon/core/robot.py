"""The robot model, by the names it had before it was split (kept so that rig-side scripts importing
`ntcr_recon.core.robot` keep working): geometry in `geometry`, bending in `kinematics`, the sampled true surface
in `robot_surface`. New code imports from those modules.
"""

from ntcr_recon.core.geometry import TubeGeometry
from ntcr_recon.core.kinematics import TubeShape
from ntcr_recon.core.robot_surface import (
    DISTANCE_SAMPLE_SPACING,
    PART_CUT_FACE,
    PART_END_CAP,
    PART_INNER_WALL,
    PART_NOTCH_FLOOR,
    PART_OUTER_WALL,
    SurfaceSample,
)

__all__ = ["DISTANCE_SAMPLE_SPACING", "PART_CUT_FACE", "PART_END_CAP", "PART_INNER_WALL", "PART_NOTCH_FLOOR",
           "PART_OUTER_WALL", "SurfaceSample", "TubeGeometry", "TubeShape"]
