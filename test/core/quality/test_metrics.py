"""quality.metrics: the centreline's error against the truth, along and across the cameras' views."""

from __future__ import annotations

import math

import numpy as np
import pytest


def test_the_centreline_error_splits_into_along_and_across_the_cameras_views():
    """A straight axis along z, the estimate 0.05 mm off along y (towards the cameras) and 0.12 mm along x: for
    cameras facing each other along y the error is 0.05 along their views and 0.12 across; for cameras along x it
    is the other way round; the two parts add up to centerline_rmse."""
    from ntcr_recon.core.quality.metrics import centerline_error_by_view, centerline_rmse

    z = np.linspace(0.0, 30e-3, 301)
    truth = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    estimate = truth[5:-5] + [0.12e-3, 0.05e-3, 0.0]
    opposed_along_y = np.array([[0.0, -0.1, 0.015], [0.0, 0.1, 0.015]])
    along, across = centerline_error_by_view(estimate, truth, opposed_along_y)
    assert along == pytest.approx(0.05e-3, rel=1e-3) and across == pytest.approx(0.12e-3, rel=1e-3)
    along, across = centerline_error_by_view(estimate, truth, opposed_along_y[:, [1, 0, 2]])
    assert along == pytest.approx(0.12e-3, rel=1e-3) and across == pytest.approx(0.05e-3, rel=1e-3)
    assert math.hypot(along, across) == pytest.approx(centerline_rmse(estimate, truth), rel=1e-3)
