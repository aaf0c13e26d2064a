"""relocation.profile: the compiled counts bin as np.histogram does, and a run of evidence is found around its
centre."""

from __future__ import annotations

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT


def test_coverage_counts_bin_as_numpys_histogram_and_runs_are_found_around_their_centre():
    """The compiled counts put every value in the bin np.histogram does (values on an edge, beyond the last
    edge, NaN); a run of evidence is found from the cell nearest the centre, and none that touches an end."""
    from ntcr_recon.core.relocation.notches import _run_around
    from ntcr_recon.core.relocation.profile import _counts_in_bins

    rng = np.random.default_rng(3)
    cell = FOOTPRINT / 8
    edges = np.arange(0.0, 0.05 + cell, cell)
    values = np.concatenate([rng.uniform(-0.001, 0.052, 5000), edges[::7], [edges[-1], np.nan, -0.0]])
    assert np.array_equal(_counts_in_bins(values, edges), np.histogram(values[np.isfinite(values)], edges)[0])

    grid = np.arange(100) * 1.0
    evidence = np.zeros(100)
    evidence[20:30] = 1.0
    evidence[40:45] = 0.8
    evidence[19], evidence[30] = 0.25, 0.75   # the crossings of 1/2: 19 + 1/3 and 30 + 1/3
    assert _run_around(grid, evidence, 26.0, 10.0) == pytest.approx((19 + 1 / 3, 30 + 1 / 3))
    assert _run_around(grid, evidence, 41.0, 10.0) == pytest.approx((39.625, 44.375))  # the nearer run
    assert _run_around(grid, evidence, 70.0, 10.0) is None                         # nothing within reach
    evidence[:5] = 1.0
    assert _run_around(grid, evidence, 2.0, 10.0) is None                          # touches the base
