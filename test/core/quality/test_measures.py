"""quality.measures: the surface depth nearest a camera, a camera's reach along the tube, a line of sight into the
slots, the depth step. Points are drawn analytically on the true surface (no renderer), so every figure is known
exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import GEOMETRY, R_O, straight_centerline

from ntcr_recon.core.quality.measures import cameras_looking_into_slots, depth_step, surface_depth


def test_the_surface_depth_nearest_a_camera_is_the_axis_less_the_ring_it_turns_to_the_camera():
    looking_down_x = np.eye(4)
    looking_down_x[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]  # optical z = base -x
    looking_down_x[:3, 3] = [0.08, 0.0, 0.0]
    axis = np.array([[0.0, 0.0, 0.01], [0.0, 0.0, 0.01], [0.0, 0.0, 0.01]])
    tangents = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [math.sqrt(0.5), 0.0, math.sqrt(0.5)]])
    depth = surface_depth(axis, tangents, looking_down_x, R_O)
    print(f"\nside-on, end-on, at 45 deg: {depth * 1e3} mm")
    # side-on the near wall, end-on the end cap's disc (at the axis's depth), at 45 deg its rim
    assert depth == pytest.approx([0.08 - R_O, 0.08, 0.08 - R_O * math.sqrt(0.5)], abs=1e-9)


def test_the_distal_stretch_every_camera_sees_end_on_is_measured_from_the_tip_back():
    """Sight angles sampled along s: cam_a's axis turns within 30 deg of its line of sight from 30 mm on, cam_b's
    from 25 mm on, and back out of it past 45 mm. Seen to 40 mm, the distal 10 mm is end-on to both (least angles
    20 and 10 deg); seen to 50 mm, the tube ends outside it: none."""
    from ntcr_recon.core.quality.measures import CameraReach

    s = np.arange(0.0, 50.25e-3, 0.25e-3)
    past = s > 45e-3
    sight = {"cam_a": np.radians(np.where((s >= 30e-3) & ~past, 20.0, 60.0)),
             "cam_b": np.radians(np.where((s >= 25e-3) & ~past, 10.0, 60.0))}
    reach = CameraReach(s, {name: np.full_like(s, 0.09) for name in sight}, {}, sight)
    length, angles = reach.end_on_to_every_camera(40e-3)
    assert length == pytest.approx(10e-3) and angles == pytest.approx({"cam_a": np.radians(20.0),
                                                                       "cam_b": np.radians(10.0)})
    assert reach.end_on_to_every_camera(50e-3) == (0.0, {})


def test_a_camera_looks_into_the_slots_when_its_line_of_sight_through_them_meets_their_floor():
    """Default robot: the cut reaches d = 0.7 mm past the axis, so a line of sight within
    atan(sqrt(r^2 - d^2) / (r + d)) = 33 deg of the notch side (+x here) meets a slot's floor."""
    assert math.degrees(GEOMETRY.slot_floor_view_angle) == pytest.approx(33.2, abs=0.1)
    centerline = straight_centerline(50e-3)

    def looking(*angles_deg):
        origins = [[0.09 * math.cos(math.radians(a)), 0.09 * math.sin(math.radians(a)), 0.025] for a in angles_deg]
        return cameras_looking_into_slots(centerline, GEOMETRY, np.array(origins),
                                          tuple(f"cam{a}" for a in angles_deg))

    assert looking(-90, 90) == []            # the notches open between the cameras: seen through, edge-on
    assert looking(0, 180) == ["cam0"]       # facing cam0: it sees the floors, cam180 the backbone
    assert looking(30, 45, -30) == ["cam30", "cam-30"]


def test_depth_step_is_read_from_the_data():
    image = (np.arange(480 * 848).reshape(480, 848) % 700 + 800).astype(np.uint16)
    assert depth_step(image, 1e-4) == pytest.approx(1e-4)
    assert depth_step(image * 10, 1e-4) == pytest.approx(1e-3)
    assert depth_step(np.zeros((4, 4), np.uint16), 1e-4) == 0.0
