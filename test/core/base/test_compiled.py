"""The compiled kernels' wrappers (base.compiled) keep the edges of the numpy code they replaced: what numpy refused
or handled, they refuse or handle."""

from __future__ import annotations

import numpy as np
import pytest

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.robot.comb import inside_intervals


def test_compiled_steps_keep_the_edges_of_the_numpy_code_they_replaced():
    """The kernels check no index and unify types: their wrappers refuse or handle what numpy did."""
    from ntcr_recon.core.base.robust import median
    from ntcr_recon.core.relocation.centerline_fit import fixed_radius_circle_fit
    from ntcr_recon.core.relocation.wall import surface_band

    curve = Centerline.from_points(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01], [1e-3, 0.0, 0.02]]),
                                   np.array([0.0, 1.0, 0.0]), 1e-3)
    assert curve.bend_angle(0.0, np.array([])).shape == (0,)
    with pytest.raises(ValueError):
        curve.bend_angle([0.0, 1e-3], [1e-3, 2e-3, 3e-3])  # lengths that do not pair
    assert np.isnan(median(np.array([1.0, np.nan, 3.0])))
    assert median(np.array([4.0, 1.0, 3.0, 2.0])) == 2.5
    with pytest.raises(ValueError, match="spine"):
        surface_band(np.zeros(50), 1e-4, np.ones(10, bool))
    with pytest.raises(ValueError, match="slab indices"):
        fixed_radius_circle_fit(np.array([0, 0, 5]), np.zeros(3), np.zeros(3), 2, 1e-3, 1e-4)
    assert not inside_intervals(np.array([0.0, 1.0]), np.empty((0, 2))).any()
