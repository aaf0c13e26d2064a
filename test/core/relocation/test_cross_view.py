"""relocation.cross_view: how far each camera alone puts the axis across its view, and the stretches no camera sees
facing it. Points are drawn analytically on the true surface (no renderer), so every figure is known exactly; each
number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT, R_O, opposed_cameras_on_a_straight_tube

from ntcr_recon.core.relocation import alignment
from ntcr_recon.core.relocation.alignment import WallTrust
from ntcr_recon.core.relocation.cross_view import cross_view_spread


def test_cross_view_spread_is_how_far_each_camera_alone_puts_the_axis_across_its_view():
    """Opposed cameras at -y and +y see a straight tube on its axis: they agree (spread under 5 um). Then cam_a's
    wall is moved 0.1 mm across its view (+x), as a matcher's window reaching the slots on one side of its view
    moves it: cam_a alone puts the axis 0.1 mm off, cam_b on it, an RMS over the cameras of 0.1 / sqrt(2) mm;
    moved along its view (-y, a level) it places the axis no differently across."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)

    def spread(moved_by):
        moved = points + np.where(camera[:, None] == 0, moved_by, 0.0)
        coords, frames = centerline.project_with_frames(moved)
        return cross_view_spread(centerline, coords, frames, viewpoints, camera, 2,
                                 WallTrust(geometry, 0.8e-3, FOOTPRINT, length)).spread

    agreed, across, along = spread([0.0, 0.0, 0.0]), spread([0.1e-3, 0.0, 0.0]), spread([0.0, -0.1e-3, 0.0])
    print(f"\ncameras agree: {agreed * 1e6:.1f} um; cam_a's wall 0.1 mm across its view: {across * 1e6:.1f} um "
          f"(expected {0.1e3 / math.sqrt(2):.1f}); along it: {along * 1e6:.1f} um")
    assert agreed < 10e-6 and along < 10e-6
    assert across == pytest.approx(0.1e-3 / math.sqrt(2), rel=0.1)
    # moved over the last window only (a matcher reaching the slots of the last notch), the spread over the length
    # stays small and the spread at the end (`distal`) is the camera's own 0.1 mm
    moved = points + np.where((camera[:, None] == 0) & (points[:, 2:] > length - 3e-3), [0.1e-3, 0.0, 0.0], 0.0)
    coords, frames = centerline.project_with_frames(moved)
    at_end = cross_view_spread(centerline, coords, frames, viewpoints, camera, 2,
                               WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    print(f"cam_a's wall moved 0.1 mm over the last window: over the length {at_end.spread * 1e6:.1f} um, at the "
          f"end {at_end.distal * 1e6:.1f} um")
    assert at_end.distal == pytest.approx(0.1e-3 / math.sqrt(2), rel=0.1)
    assert at_end.spread < 0.5 * at_end.distal
    # too few trusted points in every window (the tube seen only edge-on): nothing to tell
    edge_on = np.abs(points[:, 0]) > 0.99 * R_O
    coords, frames = centerline.project_with_frames(points[edge_on])
    seen_edge_on = cross_view_spread(centerline, coords, frames, viewpoints[edge_on], camera[edge_on], 2,
                                     WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    assert seen_edge_on.spread is None
    margin = alignment.SILHOUETTE_MARGIN_PX * FOOTPRINT
    assert len(seen_edge_on.unsupported) == 1
    assert seen_edge_on.unsupported[0] == pytest.approx((margin, length - margin))


def test_a_stretch_where_no_camera_sees_its_wall_facing_it_is_reported_unsupported():
    """Past s = 21 mm of a 30 mm tube, both cameras see only its wall edge-on (as where a matcher spoils every pixel
    whose window meets the background): the windows there hold no trusted point, and the stretch from 21 mm to the
    end's margin is reported; a 3 mm window (one notch pitch) thinned alone is bridged, not reported."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)
    margin = alignment.SILHOUETTE_MARGIN_PX * FOOTPRINT

    def unsupported(kept):
        coords, frames = centerline.project_with_frames(points[kept])
        return cross_view_spread(centerline, coords, frames, viewpoints[kept], camera[kept], 2,
                                 WallTrust(geometry, 0.8e-3, FOOTPRINT, length)).unsupported

    edge_on = np.abs(points[:, 0]) > 0.99 * R_O
    distal = unsupported(edge_on | (points[:, 2] < 21e-3))
    one_window = unsupported(edge_on | (points[:, 2] < 12e-3) | (points[:, 2] >= 15e-3))
    print(f"\nunsupported: distal {np.round(np.array(distal) * 1e3, 2).tolist()} mm, one window "
          f"{np.round(np.array(one_window) * 1e3, 2).tolist()} mm")
    assert len(distal) == 1 and distal[0] == pytest.approx((21e-3, length - margin))
    assert one_window == ()


def test_level_scatter_is_half_how_much_the_walls_apart_vary_along_the_tube():
    """Opposed cameras' walls at their true level: nothing varies (under 2 um). cam_a's wall moved along its view
    (-y) by +-0.05 mm in alternate 3 mm windows: the walls apart vary by 0.05 mm about their mean, half of which is
    0.025 mm (what the fused axis, midway, may be off along the views where the biases vary independently); the same
    move in every window (a depth bias, or a pose off along the view) varies nothing."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)

    def scatter(shift_of_window):
        along = np.where(camera == 0, shift_of_window(points[:, 2]), 0.0)
        moved = points + along[:, None] * np.array([0.0, -1.0, 0.0])
        coords, frames = centerline.project_with_frames(moved)
        return cross_view_spread(centerline, coords, frames, viewpoints, camera, 2,
                                 WallTrust(geometry, 0.8e-3, FOOTPRINT, length)).level_scatter

    still = scatter(lambda z: np.zeros_like(z))
    alternating = scatter(lambda z: np.where((z // geometry.notch_pitch) % 2 == 0, 0.05e-3, -0.05e-3))
    uniform = scatter(lambda z: np.full_like(z, 0.05e-3))
    print(f"\nlevel scatter: still {still * 1e6:.1f} um, alternating +-0.05 mm {alternating * 1e6:.1f} um, "
          f"uniform 0.05 mm {uniform * 1e6:.1f} um")
    assert still < 2e-6 and uniform < 2e-6
    assert alternating == pytest.approx(0.05e-3 / 2 * math.sqrt(10 / 9), rel=0.2)
