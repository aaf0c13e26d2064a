"""relocation.outline: the outline check of an axis moved across the views, and the fit placing the axis across the
views where the alignment places it along them. Points are drawn analytically on the true surface (no renderer), so
every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import numpy as np
import pytest
from support.analytic_tube import opposed_cameras_on_a_straight_tube

from ntcr_recon.core.relocation import alignment
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.outline import across_views_from, outline_offset


def test_the_outline_check_finds_an_axis_moved_across_the_views_not_along_them():
    """Opposed cameras at -y and +y see a straight tube's wall, each its own half: the middle of each camera's outline
    (its points' extent along x, across its view) lies on the true axis; an axis 0.3 mm off along x lies 0.3 mm from
    both middles, one 0.3 mm off along y (along the views) on them. Seen end-on (the cameras on the tube's axis) no
    outline checks it; nor where the extent is not the tube's diameter (the wall's half cut away)."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)

    def offset(shift, kept=slice(None), at=viewpoints):
        moved = Centerline.from_points(centerline.points + shift, np.array([0.0, 1.0, 0.0]), 0.1e-3)
        coords, frames = moved.project_with_frames(points[kept])
        return outline_offset(coords, frames, points[kept], at[kept], camera[kept], geometry, 0.8e-3, length)

    on_axis, across, along = offset([0.0, 0.0, 0.0]), offset([0.3e-3, 0.0, 0.0]), offset([0.0, 0.3e-3, 0.0])
    print(f"\noutline offset: axis on the tube {on_axis * 1e6:.1f} um, 0.3 mm across the views {across * 1e6:.1f} um, "
          f"0.3 mm along them {along * 1e6:.1f} um")
    assert on_axis < 10e-6 and along < 10e-6
    assert across == pytest.approx(0.3e-3, abs=10e-6)
    end_on = np.tile([0.0, 0.0, 0.12], (len(points), 1))
    assert offset([0.3e-3, 0.0, 0.0], at=end_on) is None
    assert offset([0.3e-3, 0.0, 0.0], kept=points[:, 0] > 0) is None


def test_the_fit_places_the_axis_across_the_views_and_the_alignment_along_them():
    """A straight axis along z and a reference 0.2 mm off it along x, 0.1 mm along y. Opposed cameras at -y and +y
    (both views along y, across them x): the axis takes the reference's x and keeps its own y, and the alignment
    moved to it reports that move as its lean and its end's move. Cameras at -y and +x (views 90 deg apart): what
    is along one view is across the other, and the axis takes the reference's place whole."""
    z = np.linspace(0.0, 30e-3, 301)
    axis = Centerline.from_points(np.stack([0 * z, 0 * z, z], axis=1), np.array([0.0, 1.0, 0.0]), 0.1e-3)
    offset = np.array([0.2e-3, 0.1e-3, 0.0])
    reference = Centerline.from_points(axis.points + offset, np.array([0.0, 1.0, 0.0]), 0.1e-3)
    opposed = across_views_from(reference, axis, np.array([[0.0, -0.09, 15e-3], [0.0, 0.09, 15e-3]]))
    crossed = across_views_from(reference, axis, np.array([[0.0, -0.09, 15e-3], [0.09, 0.0, 15e-3]]))
    print(f"\nmoved by (um): opposed cameras {np.round(np.mean(opposed.points - axis.points, axis=0) * 1e6, 2)}, "
          f"cameras 90 deg apart {np.round(np.mean(crossed.points - axis.points, axis=0) * 1e6, 2)}")
    np.testing.assert_allclose(opposed.points - axis.points, np.tile([0.2e-3, 0.0, 0.0], (len(axis.s), 1)),
                               atol=1e-9)
    np.testing.assert_allclose(crossed.points - axis.points, np.tile(offset, (len(axis.s), 1)), atol=1e-9)
    moved = alignment.Alignment(axis, 0.0, 0.0, 0).moved_to(opposed, axis)
    assert moved.centerline is opposed and moved.end_shift == pytest.approx(0.2e-3)
    # the axis's normal (towards the notch side) is x here: the fit leaned 0.2 mm away from it
    assert moved.bias_notch_side == pytest.approx(-0.2e-3) and moved.bias_binormal == pytest.approx(0.0, abs=1e-12)
