"""What a D405's stereo matcher does to an exact depth image.

The D405 computes depth by matching a window of pixels of its left imager (the depth reference, which
also gives colour) against its right imager, 18 mm to the right. Each parameter of `StereoEmulation`
models one consequence of that; all act on disparity d = f b / z (pixels), where the matcher works:

- occlusion (left-right check): a surface the right imager cannot see (left of a nearer object's left
  edge, `occlusion_check`) has no match and reads 0 (invalid).
- window smoothing (`window`, `segment_tolerance`): the matcher reports one disparity for a whole window,
  i.e. the mean disparity of the window over the surface the centre pixel belongs to (pixels whose
  disparity is within `segment_tolerance` of it). A plane is left unchanged (disparity is affine in the
  image over a plane); a 17-pixel-wide tube is flattened — the artefact the paper reports.
- silhouettes (`silhouette_band`, `silhouette_invalid`, `silhouette_mixing`): pixels within
  `silhouette_band` px of a depth edge match badly; with s the fraction of their (2 band + 1)^2
  neighbourhood on the other side, they are dropped with probability `silhouette_invalid` s, or else get
  a depth mixed between the two sides (flying pixels) with a random weight up to `silhouette_mixing` s.
- noise (`disparity_noise`): sub-pixel matching error, sigma_d ~ 0.08 px, independent per pixel and per
  frame; in depth it is sigma_z = z^2 sigma_d / (f b), growing with z^2.
- dropouts (`dropout`, `grazing_angle`, `grazing_dropout`): random pixels with no valid match, and more of
  them where the surface is seen at a grazing angle (little texture survives foreshortening).
- range (`D405Intrinsics.min_depth`, `.max_depth`): nearer than the disparity search range or farther than
  the useful range reads 0.
- quantisation: depth is reported as an integer multiple of the depth unit (0.1 mm), 0 = invalid.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.ndimage import uniform_filter

from ntcr_recon.sim.camera import D405Intrinsics


@dataclass(frozen=True)
class StereoEmulation:
    """Parameters of the stereo artefacts (see the module docstring for what each models)."""

    window: int = 9  # px, side of the matching window
    segment_tolerance: float = 2.5  # px of disparity: neighbours this close belong to the same surface
    disparity_noise: float = 0.08  # px, sigma_d
    silhouette_band: int = 2  # px: pixels this close to a depth edge match badly
    silhouette_invalid: float = 0.8  # probability scale of dropping a pixel near an edge (x straddled fraction)
    silhouette_mixing: float = 0.8  # largest mixing weight of a flying pixel (x straddled fraction)
    dropout: float = 0.003  # probability of a random dropped pixel
    grazing_angle: float = 75.0  # degrees between view ray and normal beyond which matching degrades
    grazing_dropout: float = 0.5  # dropout probability reached at 90 degrees (linear from grazing_angle)
    occlusion_check: bool = True

    @classmethod
    def ideal(cls) -> StereoEmulation:
        """No artefacts at all: exact depth, only quantised and range-limited."""
        return cls(window=1, silhouette_band=0, disparity_noise=0.0, silhouette_invalid=0.0, silhouette_mixing=0.0,
                   dropout=0.0, grazing_dropout=0.0, occlusion_check=False)

    def scaled_noise(self, level: float) -> StereoEmulation:
        """The same artefacts with the disparity noise times `level`."""
        if not level >= 0:
            raise ValueError(f"noise level must be >= 0, got {level}")
        return replace(self, disparity_noise=self.disparity_noise * level)

    def validate(self) -> None:
        if self.window < 1 or self.window % 2 == 0:
            raise ValueError(f"window must be an odd number of pixels >= 1, got {self.window}")
        if self.silhouette_band < 0:
            raise ValueError(f"silhouette_band must be >= 0 px, got {self.silhouette_band}")
        for name in ("segment_tolerance", "disparity_noise", "silhouette_invalid", "silhouette_mixing", "dropout",
                     "grazing_dropout"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0 < self.grazing_angle <= 90:
            raise ValueError(f"grazing_angle must be in (0, 90] degrees, got {self.grazing_angle}")

    def to_dict(self) -> dict:
        return asdict(self)


def occluded_in_right_imager(disparity: np.ndarray) -> np.ndarray:
    """Pixels of the left image whose surface the right imager does not see.

    A pixel at column u lands at u - d in the right image; it is hidden when a pixel further right in
    the left image lands further left in the right image (a nearer surface covers it there).
    """
    width = disparity.shape[1]
    right_column = np.arange(width)[None, :] - disparity
    right_column = np.where(disparity > 0, right_column, np.inf)
    # smallest right-image column among the pixels strictly to the right
    suffix_min = np.minimum.accumulate(right_column[:, ::-1], axis=1)[:, ::-1]
    to_the_right = np.concatenate([suffix_min[:, 1:], np.full((disparity.shape[0], 1), np.inf)], axis=1)
    return (disparity > 0) & (to_the_right < right_column - 0.5)


def _window_statistics(disparity: np.ndarray, window: int, tolerance: float):
    """Per pixel: mean disparity of its window over its own surface, over other surfaces, and the
    fraction of the window on other surfaces (missing pixels count as other)."""
    half = window // 2
    height, width = disparity.shape
    centre = disparity.astype(np.float32)
    padded = np.pad(centre, half, mode="edge")  # the image border is no depth edge
    same_sum = np.zeros_like(centre)
    same_count = np.zeros_like(centre)
    difference = np.empty_like(centre)
    same = np.empty(centre.shape, dtype=bool)
    for dy in range(window):
        for dx in range(window):
            shifted = padded[dy:dy + height, dx:dx + width]
            np.subtract(shifted, centre, out=difference)
            np.abs(difference, out=difference)
            np.less_equal(difference, tolerance, out=same)
            same &= shifted > 0
            np.add(same_sum, shifted, out=same_sum, where=same)
            same_count += same
    # everything valid in the window, by a (separable) box filter; the rest of it is "other"
    valid = (centre > 0).astype(np.float32)
    area = float(window * window)
    valid_sum = uniform_filter(centre * valid, window, mode="nearest") * area
    valid_count = np.rint(uniform_filter(valid, window, mode="nearest") * area)
    other_sum = np.maximum(valid_sum - same_sum, 0.0)
    other_count = np.maximum(valid_count - same_count, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        same_mean = (same_sum / same_count).astype(np.float64)
        other_mean = np.where(other_count > 0, other_sum / np.maximum(other_count, 1), 0.0).astype(np.float64)
    straddled = 1.0 - same_count.astype(np.float64) / area
    return same_mean, other_mean, straddled


def emulate_depth(exact_depth: np.ndarray, normals: np.ndarray, intrinsics: D405Intrinsics,
                  params: StereoEmulation, rng: np.random.Generator) -> np.ndarray:
    """Raw 16UC1 depth (device units, 0 = invalid) a D405 reports for an exact depth image (metres, inf = none).

    `normals`: (H, W, 3) unit surface normals in the optical frame (for the grazing-angle dropouts).
    """
    params.validate()
    depth = np.asarray(exact_depth, dtype=np.float64)
    fb = intrinsics.focal_baseline
    with np.errstate(divide="ignore"):
        disparity = np.where(np.isfinite(depth) & (depth > 0), fb / depth, 0.0)
    has_surface = disparity > 0

    if params.occlusion_check:
        disparity[occluded_in_right_imager(disparity)] = 0.0
    if params.window > 1:
        same_mean, _, _ = _window_statistics(disparity, params.window, params.segment_tolerance)
        disparity = np.where(disparity > 0, same_mean, 0.0)
    if params.silhouette_band > 0:
        _, other_mean, straddled = _window_statistics(disparity, 2 * params.silhouette_band + 1,
                                                      params.segment_tolerance)
        edge = (disparity > 0) & (straddled > 0)
        drop = edge & (rng.random(disparity.shape) < params.silhouette_invalid * straddled)
        weight = rng.random(disparity.shape) * params.silhouette_mixing * straddled * (other_mean > 0)
        disparity = np.where(drop, 0.0, np.where(edge, (1.0 - weight) * disparity + weight * other_mean, disparity))
    valid = disparity > 0
    if params.disparity_noise > 0:
        disparity = disparity + rng.normal(0.0, params.disparity_noise, disparity.shape) * valid
    if params.dropout > 0:
        disparity[rng.random(disparity.shape) < params.dropout] = 0.0
    if params.grazing_dropout > 0:
        rays = intrinsics.pixel_rays()
        cos_incidence = np.abs(np.einsum("hwi,hwi->hw", normals, rays)) / np.linalg.norm(rays, axis=2)
        limit = math.cos(math.radians(params.grazing_angle))
        severity = np.clip((limit - cos_incidence) / limit, 0.0, 1.0) if limit > 0 else 0.0
        grazing_drop = has_surface & (rng.random(disparity.shape) < params.grazing_dropout * severity)
        disparity[grazing_drop] = 0.0
    return raw_depth(disparity, intrinsics)


def raw_depth(disparity: np.ndarray, intrinsics: D405Intrinsics) -> np.ndarray:
    """Raw 16UC1 depth (device units, 0 = invalid) of a disparity image (px, <= 0 = no match): z = f b / d,
    0 outside the D405's range, quantised to the depth unit (the emulation's and the real matcher's alike)."""
    fb = intrinsics.focal_baseline
    with np.errstate(divide="ignore"):
        z = np.where(disparity > 0, fb / np.where(disparity > 0, disparity, 1.0), 0.0)
    in_range = (z >= intrinsics.min_depth) & (z <= intrinsics.max_depth)
    raw = np.rint(np.where(in_range, z, 0.0) / intrinsics.depth_unit)
    return np.clip(raw, 0, np.iinfo(np.uint16).max).astype(np.uint16)
