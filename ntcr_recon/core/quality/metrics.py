"""Figures of merit: point density consistency (paper Table I) and errors against ground truth.

Public API:
    pdc(xyz, voxel) -> {"mu", "sigma", "lambda"}   per-voxel point counts over the occupied voxels of a grid
                                                   of `voxel` (0.5 mm in the paper): mean, std, std / mean
    centerline_rmse(estimated (M,3), truth (K,3)) -> m   RMS distance of the estimate's samples to the true
                                                   polyline (densified so its sampling does not count)
    centerline_error_by_view(estimated, truth, viewpoints) -> (along, across) m   the same error split: along the
                                                   cameras' views (depth) and across them (silhouettes only)
    notch_width_errors(notches, truth_notches) -> (detected, widths m, true widths m)
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.relocation.centerline import resample_polyline


def pdc(xyz: np.ndarray, voxel: float) -> dict[str, float]:
    """Point density consistency: counts of points per occupied voxel, their mean, std and ratio."""
    if len(xyz) == 0:
        return {"mu": 0.0, "sigma": 0.0, "lambda": 0.0}
    keys = np.floor(np.asarray(xyz) / voxel).astype(np.int64)
    _, counts = np.unique(keys, axis=0, return_counts=True)
    mu = float(counts.mean())
    sigma = float(counts.std())
    return {"mu": mu, "sigma": sigma, "lambda": sigma / mu}


def _nearest_true(estimated: np.ndarray, truth: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The true centreline densified to `step` (so its own sampling does not count) and, per estimated sample, the
    index of its nearest dense point."""
    _, dense = resample_polyline(np.asarray(truth, float), step)
    _, index = cKDTree(dense).query(np.asarray(estimated, float))
    return dense, index


def centerline_rmse(estimated: np.ndarray, truth: np.ndarray, step: float = 5e-6) -> float:
    """RMS of the distances of the estimated centreline's samples to the true centreline."""
    dense, index = _nearest_true(estimated, truth, step)
    return float(np.sqrt(np.mean(np.sum((np.asarray(estimated, float) - dense[index]) ** 2, axis=1))))


def centerline_error_by_view(estimated: np.ndarray, truth: np.ndarray, viewpoints: np.ndarray,
                             step: float = 5e-6) -> tuple[float, float]:
    """RMS of the estimated centreline's error split in each true cross-section: along the cameras' views (what
    stereo depth measures) and across them (what only the tube's silhouettes place), the latter the direction of
    the cross-section the cameras' viewing directions span least (for two opposed cameras: across both views).
    The two add up in quadrature to centerline_rmse. viewpoints: (C, 3) the cameras' optical centres."""
    dense, index = _nearest_true(estimated, truth, step)
    error = np.asarray(estimated, float) - dense[index]
    tangent = np.gradient(dense, axis=0)[index]
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    spread = np.zeros((len(index), 3, 3))
    for origin in np.asarray(viewpoints, float):
        view = origin - dense[index]
        view -= tangent * np.einsum("ij,ij->i", view, tangent)[:, None]
        view /= np.maximum(np.linalg.norm(view, axis=1), 1e-12)[:, None]
        spread += np.einsum("ij,ik->ijk", view, view)
    # the tangent is no direction of the cross-section: it goes last, the least seen direction within it first
    spread += 2.0 * len(viewpoints) * np.einsum("ij,ik->ijk", tangent, tangent)
    least_seen = np.linalg.eigh(spread)[1][:, :, 0]
    across = np.einsum("ij,ij->i", error, least_seen)
    along = np.einsum("ij,ij->i", error, np.cross(tangent, least_seen))
    return float(np.sqrt(np.mean(along**2))), float(np.sqrt(np.mean(across**2)))


def notch_width_errors(notches, truth_notches: list[dict]) -> tuple[int, np.ndarray, np.ndarray]:
    """Detected notch count and the (measured, true) widths of the detected ones, matched by index."""
    by_index = {int(n["index"]): n for n in truth_notches}
    matched = [(n.width, by_index[n.index]["width_m"]) for n in notches if n.index in by_index]
    if not matched:
        return 0, np.empty(0), np.empty(0)
    measured, true = (np.array(v) for v in zip(*matched, strict=True))
    return len(matched), measured, true
