"""A real stereo matcher on the rendered imagers: OpenCV's semi-global block matcher (`simulate --matcher sgbm`).

The left and right images (`imagers.render_pair`, one exposure each) are matched in grey by
`cv2.StereoSGBM_create` with what a D405-like matcher uses: a 7 px block, a search from 0 to the disparity of
the D405's minimum depth (`D405Intrinsics.min_depth`, rounded up to 16 px: 112 px at 848x480), a uniqueness
margin, speckle removal and the left-right check (`disp12MaxDiff`, -1: none). Its disparity (1/16 px) becomes
depth z = f b / d, quantised to the device's unit with 0 invalid, exactly as the emulation writes it
(`stereo.raw_depth`). cv2 (opencv-python-headless) is imported only here, when the matcher runs.

Public API:
    SgbmParameters(...)                                        # the matcher's settings
    disparity_range(intrinsics) -> (min_disparity, count)      # px
    match_disparity(left, right, intrinsics, params) -> (H, W) float px, 0 where invalid
    matched_frame(clean_pair, intrinsics, params, noise, rng) -> (raw depth uint16, left image uint8)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ntcr_recon.sim.camera import D405Intrinsics
from ntcr_recon.sim.imagers import sensor_image
from ntcr_recon.sim.stereo import raw_depth

MODES = ("sgbm", "hh", "3way", "hh4")  # cv2.STEREO_SGBM_MODE_SGBM, _HH, _SGBM_3WAY, _HH4


@dataclass(frozen=True)
class SgbmParameters:
    """cv2.StereoSGBM's settings (P1, P2: 8 and 32 times the block's area, as OpenCV recommends)."""

    block_size: int = 7  # px, odd
    uniqueness: int = 10  # %: the best match's cost beats the second best by this margin
    speckle_window: int = 100  # px: smaller disparity blobs are speckles, dropped
    speckle_range: int = 2  # px: the disparity variation within one blob
    left_right_max_diff: int = 1  # px, the left-right check (disp12MaxDiff); -1: no check
    pre_filter_cap: int = 31
    mode: str = "sgbm"  # 5 directions; "hh" 8 (slower), "3way" (faster)

    def validate(self) -> None:
        if not (isinstance(self.block_size, int) and self.block_size >= 1 and self.block_size % 2 == 1):
            raise ValueError(f"block size must be an odd number of pixels >= 1, got {self.block_size}")
        if not 0 <= self.uniqueness <= 100:
            raise ValueError(f"uniqueness must be 0 to 100 %, got {self.uniqueness}")
        if self.speckle_window < 0 or self.speckle_range < 0:
            raise ValueError(f"speckle window and range must be >= 0, got {self.speckle_window}, "
                             f"{self.speckle_range}")
        if self.left_right_max_diff < -1:
            raise ValueError(f"left-right max difference must be >= -1 px, got {self.left_right_max_diff}")
        if not 1 <= self.pre_filter_cap <= 63:
            raise ValueError(f"pre-filter cap must be 1 to 63, got {self.pre_filter_cap}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")

    def to_dict(self) -> dict:
        return asdict(self)


def disparity_range(intrinsics: D405Intrinsics) -> tuple[int, int]:
    """The search: from 0 px to the disparity of the minimum depth, as a multiple of 16 px (OpenCV's)."""
    nearest = intrinsics.focal_baseline / intrinsics.min_depth
    return 0, max(16, 16 * math.ceil(nearest / 16))


def _matcher(params: SgbmParameters, intrinsics: D405Intrinsics):
    import cv2  # only when the real matcher runs: nothing else pays its import

    minimum, count = disparity_range(intrinsics)
    area = params.block_size**2
    mode = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
            "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}[params.mode]
    return cv2.StereoSGBM_create(minDisparity=minimum, numDisparities=count, blockSize=params.block_size,
                                 P1=8 * area, P2=32 * area, disp12MaxDiff=params.left_right_max_diff,
                                 preFilterCap=params.pre_filter_cap, uniquenessRatio=params.uniqueness,
                                 speckleWindowSize=params.speckle_window, speckleRange=params.speckle_range,
                                 mode=mode)


def grey(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 luma (ITU-R BT.601) of an (H, W, 3) RGB uint8 image."""
    luma = image.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(luma), 0, 255).astype(np.uint8)


def match_disparity(left: np.ndarray, right: np.ndarray, intrinsics: D405Intrinsics,
                    params: SgbmParameters) -> np.ndarray:
    """(H, W) disparity (px) of the left image's pixels, 0 where the matcher found none."""
    params.validate()
    raw = _matcher(params, intrinsics).compute(grey(left), grey(right))
    disparity = raw.astype(np.float64) / 16.0  # StereoSGBM's fixed point: 4 fractional bits
    minimum, _ = disparity_range(intrinsics)
    return np.where(disparity > max(minimum, 0), disparity, 0.0)


def matched_frame(clean_pair: tuple[np.ndarray, np.ndarray], intrinsics: D405Intrinsics, params: SgbmParameters,
                  noise: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One frame: an exposure of each imager (sensor noise `noise` levels), matched. Raw 16UC1 depth (device
    units, 0 invalid) and the left image (the colour a D405 gives, aligned with its depth)."""
    left = sensor_image(clean_pair[0], noise, rng)
    right = sensor_image(clean_pair[1], noise, rng)
    return raw_depth(match_disparity(left, right, intrinsics, params), intrinsics), left
