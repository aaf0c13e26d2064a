"""Figures of merit: point density consistency (paper Table I) and errors against ground truth.

Public API:
    pdc(xyz, voxel) -> {"mu", "sigma", "lambda"}   per-voxel point counts over the occupied voxels of a grid
                                                   of `voxel` (0.5 mm in the paper): mean, std, std / mean
    centerline_rmse(estimated (M,3), truth (K,3)) -> m   RMS distance of the estimate's samples to the true
                                                   polyline (densified so its sampling does not count)
    notch_width_errors(notches, truth_notches) -> (detected, widths m, true widths m)
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.centerline import resample_polyline


def pdc(xyz: np.ndarray, voxel: float) -> dict[str, float]:
    """Point density consistency: counts of points per occupied voxel, their mean, std and ratio."""
    if len(xyz) == 0:
        return {"mu": 0.0, "sigma": 0.0, "lambda": 0.0}
    keys = np.floor(np.asarray(xyz) / voxel).astype(np.int64)
    _, counts = np.unique(keys, axis=0, return_counts=True)
    mu = float(counts.mean())
    sigma = float(counts.std())
    return {"mu": mu, "sigma": sigma, "lambda": sigma / mu}


def centerline_rmse(estimated: np.ndarray, truth: np.ndarray, step: float = 5e-6) -> float:
    """RMS of the distances of the estimated centreline's samples to the true centreline."""
    _, dense = resample_polyline(np.asarray(truth, float), step)  # so the truth's own sampling does not count
    distance, _ = cKDTree(dense).query(np.asarray(estimated, float))
    return float(np.sqrt(np.mean(distance**2)))


def notch_width_errors(notches, truth_notches: list[dict]) -> tuple[int, np.ndarray, np.ndarray]:
    """Detected notch count and the (measured, true) widths of the detected ones, matched by index."""
    by_index = {int(n["index"]): n for n in truth_notches}
    matched = [(n.width, by_index[n.index]["width_m"]) for n in notches if n.index in by_index]
    if not matched:
        return 0, np.empty(0), np.empty(0)
    measured, true = (np.array(v) for v in zip(*matched, strict=True))
    return len(matched), measured, true
