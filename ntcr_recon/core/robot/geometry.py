"""The robot's geometry: the notched tube as the rig configuration's `robot` section describes it.

A notch cut to depth g from the outer surface leaves a backbone whose cross-section is the part of the annulus
on the far side of the chord at distance d = g - r_o from the axis; its neutral axis sits at ybar from the
tube's axis (away from the notches), and a notch closes at theta_max = h / (r_o + ybar) (York et al. 2015;
Swaney et al. 2017). How the tube bends is `kinematics`; its sampled true surface is `surface`.

Frames: the robot base pose (``base_position``, ``base_orientation``) is given in the base frame and its +z is
the robot's axis. Units: metres and radians throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ntcr_recon.core.base.schema import ConfigError, build_section, check_section, section_mapping, setting
from ntcr_recon.core.base.transforms import quaternion_to_matrix

# A millimetre-scale robot: what the ranges below admit (a larger value is a typo or a unit slip, and some
# would hang or exhaust memory downstream: sampling, crop boxes and grids scale with these lengths).
MAX_ROBOT_LENGTH = 1.0  # m, base to tip


def _segment_area_and_centroid(radius: float, chord_offset: float) -> tuple[float, float, float]:
    """Angle phi, area and centroid distance of the circular segment beyond a chord at chord_offset.

    The segment is the part of the disc on the far side (from the notches) of the chord x = -d, i.e.
    phi = 2 acos(d / r), A = r^2 (phi - sin phi) / 2, ybar = 4 r sin^3(phi / 2) / (3 (phi - sin phi)).
    A chord that misses the disc leaves all of it (phi = 2 pi) or none of it (phi = 0).
    """
    phi = 2.0 * math.acos(min(1.0, max(-1.0, chord_offset / radius)))
    area = radius**2 * (phi - math.sin(phi)) / 2.0
    if phi - math.sin(phi) <= 0.0:
        return phi, 0.0, 0.0
    centroid = 4.0 * radius * math.sin(phi / 2.0) ** 3 / (3.0 * (phi - math.sin(phi)))
    return phi, area, centroid


@dataclass(frozen=True)
class TubeGeometry:
    """The robot's reference geometry (the rig configuration's `robot` section); metres and radians."""

    outer_diameter: float = setting(3.5e-3, "outer diameter of the tube", unit="m", minimum=0.5e-3, maximum=20e-3)
    inner_diameter: float = setting(2.5e-3, "inner diameter (the bore), below outer_diameter", unit="m",
                                    minimum=0.0, maximum=20e-3, exclusive_minimum=True)
    notch_count: int = setting(16, "number of notches", minimum=1, maximum=500)
    notch_width: float = setting(1.5e-3, "h: width of a notch along the axis, undeformed", unit="m",
                                 minimum=0.0, maximum=MAX_ROBOT_LENGTH, exclusive_minimum=True)
    notch_pitch: float = setting(3.0e-3, "distance of two notches, centre to centre (above notch_width)", unit="m",
                                 minimum=0.0, maximum=MAX_ROBOT_LENGTH, exclusive_minimum=True)
    notch_depth: float | None = setting(None, "g: cut depth from the outer surface, below outer_diameter; "
                                        "null = 0.7 outer_diameter", unit="m", minimum=0.0, maximum=20e-3,
                                        exclusive_minimum=True)
    notch_side: float = setting(0.0, "angle about the axis of the side the notches open to, from +x towards +y",
                                unit="rad", minimum=-2 * math.pi, maximum=2 * math.pi)
    roll_tolerance: float | None = setting(
        math.radians(0.2), "how well the robot's roll in its clamp is known about notch_side (one standard "
        "deviation; `ntcr-recon calibrate` puts the base frame's x where the robot bends, so a calibrated rig knows "
        "it as well as that fit's bend plane): the centreline is held to the plane its notches bend it in, at that "
        "roll unless the points show another (core.relocation.bend_plane); null = not held to a plane", unit="rad",
        minimum=0.0, maximum=math.pi, exclusive_minimum=True)
    proximal_length: float = setting(5.0e-3, "base to the first notch's proximal edge", unit="m", minimum=0.0,
                                     maximum=MAX_ROBOT_LENGTH, exclusive_maximum=True)
    distal_length: float = setting(1.5e-3, "last notch's distal edge to the tip", unit="m", minimum=0.0,
                                   maximum=MAX_ROBOT_LENGTH, exclusive_maximum=True)
    length_tolerance: float | None = setting(
        0.1e-3, "how well the robot's length from its base is known (the tube's cut, its seating in the clamp): the "
        "tip is put between the end the cameras see and that length, each weighed by its uncertainty; null = not "
        "known, the tip is where the end is seen", unit="m", minimum=0.0, maximum=MAX_ROBOT_LENGTH,
        exclusive_minimum=True)
    base_position: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), "position of the robot's base in the base frame (x, y, z)", unit="m", minimum=-10.0,
        maximum=10.0)
    base_orientation: tuple[float, float, float, float] = setting(
        (0.0, 0.0, 0.0, 1.0), "orientation of the robot's base in the base frame, a unit quaternion (x, y, z, w); "
        "its +z is the robot's unbent axis")

    def __post_init__(self) -> None:
        # Lists from YAML/JSON become tuples so the dataclass stays hashable and immutable.
        object.__setattr__(self, "base_position", tuple(float(v) for v in self.base_position))
        object.__setattr__(self, "base_orientation", tuple(float(v) for v in self.base_orientation))

    # ----------------------------------------------------------------------------------- validation
    def validate(self) -> None:
        """Raise ConfigError (a ValueError) naming the field when the description is not a buildable robot."""
        check_section(self, "robot")
        self._check_consistency()

    @classmethod
    def from_mapping(cls, mapping) -> TubeGeometry:
        """Build from a mapping whose keys are field names; refuses unknown keys and bad values."""
        geometry = build_section(cls, mapping, "robot")
        geometry._check_consistency()
        return geometry

    def _check_consistency(self) -> None:
        """What the per-key ranges cannot say: how the fields fit together."""
        if not self.inner_diameter < self.outer_diameter:
            raise ConfigError(f"robot.inner_diameter must be > 0 and < outer_diameter ({self.outer_diameter}), "
                              f"got {self.inner_diameter}")
        if self.notch_pitch <= self.notch_width:
            raise ConfigError(f"robot.notch_pitch ({self.notch_pitch}) must exceed robot.notch_width "
                              f"({self.notch_width}): the notches would overlap")
        if self.notch_depth is not None and self.notch_depth >= self.outer_diameter:
            raise ConfigError(f"robot.notch_depth ({self.notch_depth}) must be less than robot.outer_diameter "
                              f"({self.outer_diameter}): the cut would sever the tube")
        if self.length > MAX_ROBOT_LENGTH:
            raise ConfigError(f"robot: length {self.length:.6g} m (proximal_length + (notch_count - 1) notch_pitch "
                              f"+ notch_width + distal_length) exceeds {MAX_ROBOT_LENGTH:g} m")
        try:
            quaternion_to_matrix(self.base_orientation)
        except ValueError as error:
            raise ConfigError(f"robot.base_orientation: {error}") from None

    def to_dict(self) -> dict:
        """The fields as plain JSON/YAML values (tuples as lists)."""
        return section_mapping(self)

    # -------------------------------------------------------------------------------------- derived
    @property
    def outer_radius(self) -> float:
        return self.outer_diameter / 2.0

    @property
    def inner_radius(self) -> float:
        return self.inner_diameter / 2.0

    @property
    def cut_depth(self) -> float:
        """g, with the default (70 % of the outer diameter) resolved."""
        return 0.7 * self.outer_diameter if self.notch_depth is None else float(self.notch_depth)

    @property
    def chord_offset(self) -> float:
        """d = g - r_o: the cut plane lies at x = -d in the notch-side frame."""
        return self.cut_depth - self.outer_radius

    @property
    def length(self) -> float:
        """Undeformed length, base to tip."""
        return (self.proximal_length + (self.notch_count - 1) * self.notch_pitch + self.notch_width
                + self.distal_length)

    def bent_length(self, total_bend: float) -> float:
        """The centreline's length, base to tip, bent by total_bend (rad): each notch closes about the backbone's
        neutral axis, which keeps its length while the axis, ybar off it, shortens by ybar x the bend."""
        return self.length - self.neutral_axis_offset * abs(total_bend)

    def notch_arc_at_bend(self, bend: float) -> float:
        """The centreline's arc length across a notch closed by `bend` (rad): h - ybar |theta| (kinematics)."""
        return self.notch_width - self.neutral_axis_offset * abs(bend)

    def notch_width_at_bend(self, bend: float) -> float:
        """The width (outer-surface gap facing the notches) of a notch closed by `bend` (rad): its arc less
        |theta| r_o, never below 0."""
        return max(self.notch_arc_at_bend(bend) - abs(bend) * self.outer_radius, 0.0)

    @property
    def reach(self) -> float:
        """How far along its centreline the robot can be seen from its base: its length and a diameter (the
        end cap, and the stereo matcher's spread at the end). No tube is searched for past it."""
        return self.length + self.outer_diameter

    @cached_property
    def notch_centers_s(self) -> np.ndarray:
        """Undeformed arc length of each notch's centre."""
        centres = self.proximal_length + self.notch_width / 2.0 + self.notch_pitch * np.arange(self.notch_count)
        centres.flags.writeable = False  # computed once and shared
        return centres

    @cached_property
    def neutral_axis_offset(self) -> float:
        """ybar: distance from the tube axis to the backbone's neutral axis (away from the notches)."""
        d = self.chord_offset
        _, area_o, ybar_o = _segment_area_and_centroid(self.outer_radius, d)
        _, area_i, ybar_i = _segment_area_and_centroid(self.inner_radius, d)
        return (ybar_o * area_o - ybar_i * area_i) / (area_o - area_i)

    @cached_property
    def max_notch_bend(self) -> float:
        """theta_max = h / (r_o + ybar): the bend at which a notch's faces meet on the outer surface."""
        return self.notch_width / (self.outer_radius + self.neutral_axis_offset)

    def pixel_footprint_or_default(self, footprint: float) -> float:
        """A measured pixel footprint (m), or r_o / 8 where none is known (a cloud without camera intrinsics):
        about what a D405 at 90 mm gives a 3.5 mm tube, and what the stages' lengths are scaled by."""
        return footprint if footprint > 0 else self.outer_radius / 8.0

    @cached_property
    def gap_half_angle(self) -> float:
        """Half the angle about the axis over which a notch is open on the outer surface: acos(-d / r_o)."""
        return math.acos(-self.chord_offset / self.outer_radius)

    @cached_property
    def slot_floor_view_angle(self) -> float:
        """The largest angle about the axis between a line of sight and the notch side at which the line through
        the middle of a slot (from its opening's apex) meets the slot's floor - the backbone's cut face at the
        chord d beyond the axis - rather than passing out through the other side: atan(sqrt(r_o^2 - d^2) / (r_o + d)).
        A camera looking at the notches from within this angle sees the floors behind the spines."""
        r, d = self.outer_radius, self.chord_offset
        return math.atan2(math.sqrt(max(r * r - d * d, 0.0)), r + d)

    @cached_property
    def base_rotation(self) -> np.ndarray:
        """Rotation of the robot base pose (its +z = the robot's axis) in the base frame (computed once: every
        frame asks; read-only, as it is shared)."""
        rotation = quaternion_to_matrix(self.base_orientation)
        rotation.flags.writeable = False
        return rotation
