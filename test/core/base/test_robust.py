"""base.robust: the compiled median and quantile equal numpy's."""

from __future__ import annotations

import math

import numpy as np
import pytest


@pytest.mark.parametrize("count", [1, 2, 7, 5400, 5401])
def test_median_is_numpys_median(count):
    from ntcr_recon.core.base.robust import median

    rng = np.random.default_rng(count)
    for values in (rng.normal(size=count), np.round(rng.normal(size=count), 1), np.sort(rng.normal(size=count)),
                   np.full(count, 0.25)):
        assert median(values) == np.median(values)
    assert math.isnan(median(np.zeros(0)))


@pytest.mark.parametrize("count", [1, 2, 7, 100, 5401])
def test_quantile_is_numpys_quantile(count):
    from ntcr_recon.core.base.robust import quantile

    rng = np.random.default_rng(count)
    for values in (rng.normal(size=count), np.round(rng.normal(size=count), 1), np.full(count, 0.25)):
        for q in (0.0, 0.25, 0.5, 0.75, 0.98, 1.0):
            assert quantile(values, q) == np.quantile(values, q), (count, q)
    assert math.isnan(quantile(np.zeros(0), 0.5)) and math.isnan(quantile(np.array([1.0, np.nan]), 0.5))
