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


def test_a_cache_missing_a_file_it_held_when_complete_is_compiled_again(tmp_path, monkeypatch):
    """ensure_compiled writes the cache's files into its ready record; a cache copied or cleaned in part (one of
    them gone) is not complete, and the workload runs again, instead of its kernels compiling inside the frames."""
    import numba

    from ntcr_recon.core.base import compiled

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "digest"))
    runs = []

    def workload():  # as numba writes a kernel's cache: an index and its data, in a folder per source folder
        runs.append(1)
        (tmp_path / "digest" / "relocation_0559").mkdir(exist_ok=True)
        for name in ("kernels.f-1.py311.nbi", "kernels.f-1.py311.1.nbc"):
            (tmp_path / "digest" / "relocation_0559" / name).write_bytes(b"cached")

    assert compiled.ensure_compiled(workload, print) is not None and len(runs) == 1
    assert compiled.ready_at() is not None
    assert compiled.ensure_compiled(workload, print) is None and len(runs) == 1  # complete: nothing to do
    (tmp_path / "digest" / "relocation_0559" / "kernels.f-1.py311.1.nbc").unlink()
    assert compiled.ready_at() is None
    assert compiled.ensure_compiled(workload, print) is not None and len(runs) == 2
    assert compiled.ready_at() is not None
