"""The colour profile across a tube's limb in a camera's image, and where it crosses from the tube to the background
(issue 61, part 1): what relocation.limbs reads the limbs by, and relocation.outline_tip the end's outline.

    limbs, contrast = limb_crossings(color, pixel, sideways, half_width, shaded=True)
"""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.base.compiled import jit

# Profile samples per pixel across the tube.
SAMPLES_PER_PX = 4

# A limb is looked for this far either side of where the axis puts it (px): the axis as aligned on depth is off
# by up to a millimetre's fraction (about a pixel at 90 mm), a shaded limb reads up to a pixel inward.
SEARCH_PX = 3.0

# The background is read this far outside the expected limb, the tube this far inside it (px): beyond the blur
# of the lens and the search.
BACKGROUND_PX = (1.5, 4.0)
TUBE_PX = (1.5, 3.0)

# Where the axis is placed, a limb's crossing is read half-way to the tube's colour this far inside it (px: past the
# lens's blur), the tube's profile carried on there from its samples further in (TUBE_PX), not to their mean: shading
# darkens a round tube towards its limbs, more on the side away from the light, and against a dark background the
# crossing read at the mean lies inward, by up to a pixel and a half on the real matcher's scenes (on the cloth
# behind one camera's view: the stations fell out of limbs.WIDTH_TOLERANCE_PX, and the axis took depth's place there).
SHADED_EDGE_PX = 1.5

# The least colour contrast between tube and background at a limb (8-bit levels, Euclidean in RGB): a few times
# a sensor's noise, so that noise does not place the crossing.
MIN_CONTRAST = 15.0


def limb_crossings(color: np.ndarray, pixel: np.ndarray, sideways: np.ndarray, half_width: np.ndarray,
                   shaded: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per station (S, 2), where the colour profile along `sideways` (unit, px) from `pixel` crosses half-way from
    the tube to the background nearest -half_width and +half_width (px; NaN where none was found): its limbs, or
    (along the axis, at the end) the end's outline; and (S, 2, 3) the colour it took for the tube's less the
    background's there (NaN where too faint to read). shaded: the crossing read half-way to the tube's colour
    SHADED_EDGE_PX inside the limb (a round limb's), not to its mean inside (an end's flat face)."""
    most = float(np.max(half_width)) + SEARCH_PX + BACKGROUND_PX[1]
    ks = np.arange(-most, most + 0.5 / SAMPLES_PER_PX, 1.0 / SAMPLES_PER_PX)
    return _limbs_kernel(np.ascontiguousarray(color), np.ascontiguousarray(pixel, dtype=float),
                         np.ascontiguousarray(sideways, dtype=float), np.ascontiguousarray(half_width, dtype=float),
                         ks, SEARCH_PX, *BACKGROUND_PX, *TUBE_PX, MIN_CONTRAST, shaded, SHADED_EDGE_PX)


@jit
def _limbs_kernel(color, pixel, sideways, half_width, ks, search, background_from, background_to, tube_from,
                  tube_to, min_contrast, shaded, edge_px):
    """Per station (S, 2): where its colour profile along `sideways` crosses half-way from the background to the
    tube (px along ks) nearest each expected limb (-half_width, +half_width), NaN without contrast or crossing;
    and (S, 2, 3) the tube's mean colour less the background's (NaN without contrast).
    The background is the profile's mean background_from..to px outside the expected limb, the tube its mean
    tube_from..to px inside it (shaded: the line through the means of its nearer and farther halves, at edge_px
    inside, where that stands off the background along the mean's colour); the profile is sampled bilinearly from
    the (H, W, 3) uint8 image."""
    stations, samples = pixel.shape[0], ks.shape[0]
    height, width = color.shape[0], color.shape[1]
    step = ks[1] - ks[0]
    # each side reads only the samples about its expected limb (its background, tube and search), not the tube's
    # middle: the index range below holds every sample the tests inside the loops accept, with a margin
    reach = max(background_to, tube_to, search)
    profile = np.empty((samples, 3))
    limbs = np.full((stations, 2), np.nan)
    contrast = np.full((stations, 2, 3), np.nan)
    for i in range(stations):
        for j in range(2):
            side = -1.0 if j == 0 else 1.0
            expected = side * half_width[i]
            lo = max(int(np.floor((expected - reach - ks[0]) / step)) - 2, 0)
            hi = min(int(np.ceil((expected + reach - ks[0]) / step)) + 2, samples - 1)
            for k in range(lo, hi + 1):  # bilinear, from the uint8 image itself
                u = pixel[i, 0] + ks[k] * sideways[i, 0]
                v = pixel[i, 1] + ks[k] * sideways[i, 1]
                u0 = min(max(int(np.floor(u)), 0), width - 2)
                v0 = min(max(int(np.floor(v)), 0), height - 2)
                du, dv = u - u0, v - v0
                for c in range(3):
                    top = color[v0, u0, c] * (1.0 - du) + color[v0, u0 + 1, c] * du
                    bottom = color[v0 + 1, u0, c] * (1.0 - du) + color[v0 + 1, u0 + 1, c] * du
                    profile[k, c] = top * (1.0 - dv) + bottom * dv
            b0 = b1 = b2 = t0 = t1 = t2 = n0 = n1 = n2 = 0.0
            count_background = count_tube = count_near = 0
            depth_in = near_in = 0.0  # px inside the expected limb, summed over the tube's samples, its near ones
            near_to = (tube_from + tube_to) / 2.0
            for k in range(lo, hi + 1):
                beyond = side * (ks[k] - expected)  # px outward from the expected limb
                if background_from <= beyond <= background_to:
                    b0, b1, b2 = b0 + profile[k, 0], b1 + profile[k, 1], b2 + profile[k, 2]
                    count_background += 1
                if tube_from <= -beyond <= tube_to:
                    t0, t1, t2 = t0 + profile[k, 0], t1 + profile[k, 1], t2 + profile[k, 2]
                    count_tube += 1
                    depth_in -= beyond
                    if -beyond <= near_to:
                        n0, n1, n2 = n0 + profile[k, 0], n1 + profile[k, 1], n2 + profile[k, 2]
                        count_near += 1
                        near_in -= beyond
            nb, nt = max(count_background, 1), max(count_tube, 1)
            b0, b1, b2 = b0 / nb, b1 / nb, b2 / nb
            c0, c1, c2 = t0 / nt - b0, t1 / nt - b1, t2 / nt - b2  # the tube's colour against the background's
            strength = c0 * c0 + c1 * c1 + c2 * c2
            if strength < min_contrast * min_contrast:
                continue
            contrast[i, j, 0], contrast[i, j, 1], contrast[i, j, 2] = c0, c1, c2
            # the level the crossing is read at (shaded: the tube's profile carried on to edge_px inside the limb)
            e0, e1, e2 = c0, c1, c2
            count_far = count_tube - count_near
            if shaded and count_near > 0 and count_far > 0:
                # from the near samples' mean depth inside, by the slope between it and the far ones'
                near_in, far_in = near_in / count_near, (depth_in - near_in) / count_far
                lever = (near_in - edge_px) / (far_in - near_in)
                f0, f1, f2 = (t0 - n0) / count_far, (t1 - n1) / count_far, (t2 - n2) / count_far
                n0, n1, n2 = n0 / count_near, n1 / count_near, n2 / count_near
                x0, x1, x2 = n0 + (n0 - f0) * lever - b0, n1 + (n1 - f1) * lever - b1, n2 + (n2 - f2) * lever - b2
                # the same colour as the tube's (not across the background), and standing off the background
                if x0 * c0 + x1 * c1 + x2 * c2 >= min_contrast * np.sqrt(strength):
                    e0, e1, e2 = x0, x1, x2
            level = e0 * e0 + e1 * e1 + e2 * e2
            best = np.inf
            previous = ((profile[lo, 0] - b0) * e0 + (profile[lo, 1] - b1) * e1
                        + (profile[lo, 2] - b2) * e2) / level - 0.5
            for k in range(lo, hi):
                following = ((profile[k + 1, 0] - b0) * e0 + (profile[k + 1, 1] - b1) * e1
                             + (profile[k + 1, 2] - b2) * e2) / level - 0.5
                if np.sign(previous) != np.sign(following) and abs(side * (ks[k] - expected)) <= search:
                    at = ks[k] + previous / (previous - following) * step
                    if abs(at - expected) < best:
                        best = abs(at - expected)
                        limbs[i, j] = at
                previous = following
    return limbs, contrast
