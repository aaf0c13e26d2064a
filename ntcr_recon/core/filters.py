"""Filters (paper Sec. II-B), each optional and configured in the `filters` section.

Public API (all vectorised; masks are boolean arrays over the points):
    crop_box_mask(xyz, box_min, box_max)             spatial condition
    color_mask(rgb, color_min, color_max)            colour condition on packed 0x00RRGGBB
    statistical_outlier_mask(xyz, k, alpha)          Eq. 5: mean k-NN distance <= mu + alpha sigma
    mls_smooth(xyz, k, order, radius=0)              Eq. 6: project each point onto its weighted local
                                                     plane (order 1) or quadric (order 2)
    voxel_downsample(cloud, size)                    one point (the centroid) per occupied voxel
    nearest_neighbours(cloud, k) -> (distances, index) k nearest of each point, self included: in the image
                                                     (a pixel window per camera) when the cloud has pixel
                                                     coordinates, else by a KD-tree
    filter_cloud(cloud, config) -> Cloud             the configured chain, in the paper's order
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.spatial import cKDTree

from ntcr_recon.core.cloud import Cloud, unpack_rgb


def crop_box_mask(xyz: np.ndarray, box_min, box_max) -> np.ndarray:
    """Points inside the axis-aligned box [box_min, box_max] (inclusive)."""
    # a column at a time: np.all over an axis of length 3 costs five times more
    inside = np.ones(len(xyz), dtype=bool)
    for coordinate, low, high in zip(np.asarray(xyz).T, np.asarray(box_min, dtype=float),
                                     np.asarray(box_max, dtype=float), strict=True):
        inside &= coordinate >= low
        inside &= coordinate <= high
    return inside


def color_mask(rgb: np.ndarray, color_min, color_max) -> np.ndarray:
    """Points whose 8-bit R, G and B each lie within [color_min, color_max]."""
    channels = unpack_rgb(rgb)
    return np.all((channels >= np.asarray(color_min)) & (channels <= np.asarray(color_max)), axis=1)


def statistical_outlier_mask(xyz: np.ndarray, k: int, alpha: float,
                             distances: np.ndarray | None = None) -> np.ndarray:
    """Eq. 5: keep points whose mean distance to their k nearest neighbours is <= mu + alpha * sigma.

    distances: optional (N, k + 1) distances to each point's k + 1 nearest, itself included, from an earlier
    query (any order).
    """
    if len(xyz) <= k:
        return np.ones(len(xyz), dtype=bool)
    if distances is None:
        distances, _ = cKDTree(xyz).query(xyz, k=k + 1, workers=-1)
    # the point itself is at distance 0 and counts out; neighbours missing from an image window (inf) count
    # out too, so a point at a hole or a thin part of the image is judged by the neighbours it has
    near = distances[:, : k + 1]
    present = np.isfinite(near)
    count = np.count_nonzero(present, axis=1) - 1                        # (a boolean sum converts to int first)
    mean_distance = np.where(present, near, 0.0).sum(axis=1) / np.maximum(count, 1)
    mean_distance[count < 3] = np.inf                                     # (almost) alone: an outlier
    finite = np.isfinite(mean_distance)
    if not finite.any():
        return finite
    threshold = mean_distance[finite].mean() + alpha * mean_distance[finite].std()
    return mean_distance <= threshold


# floor of p^2 (the spread of a 3x3 matrix's eigenvalues) in the closed-form eigensolver: a neighbourhood of
# coincident points has p = 0, and p^3 of the old 1e-300 floor underflowed to 0 (0 / 0 = NaN normals)
_TINY_SPREAD = 1e-60


def smallest_eigenvectors(matrices: np.ndarray) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of each symmetric (N, 3, 3) matrix (closed form)."""
    a = np.asarray(matrices, dtype=float)
    return _smallest_eigenvectors_of(a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 1, 1], a[:, 1, 2], a[:, 2, 2])


def _smallest_eigenvectors_of(xx, xy, xz, yy, yz, zz) -> np.ndarray:
    """Smallest-eigenvalue unit eigenvectors of symmetric 3x3 matrices given by their six distinct entries
    (each (N,) float64), vectorised over N.

    Eigenvalues by the trigonometric solution of the characteristic cubic; the eigenvector is the largest
    cross product of two rows of (A - lambda I), which is orthogonal to both.
    """
    trace = (xx + yy + zz) / 3.0
    dx, dy, dz = xx - trace, yy - trace, zz - trace
    p = np.sqrt(np.maximum((dx * dx + dy * dy + dz * dz + 2.0 * (xy * xy + xz * xz + yz * yz)) / 6.0,
                           _TINY_SPREAD))
    # det(shifted / p) / 2
    det = dx * (dy * dz - yz * yz) - xy * (xy * dz - yz * xz) + xz * (xy * yz - dy * xz)
    half_det = np.clip(det / (2.0 * p * p * p), -1.0, 1.0)
    smallest = trace + 2.0 * p * np.cos(np.arccos(half_det) / 3.0 + 2.0 * np.pi / 3.0)
    mx, my, mz = xx - smallest, yy - smallest, zz - smallest
    # rows of (A - lambda I): r0 = (mx, xy, xz), r1 = (xy, my, yz), r2 = (xz, yz, mz); crosses r0xr1, r0xr2, r1xr2
    crosses = np.stack([
        np.stack([xy * yz - xz * my, xz * xy - mx * yz, mx * my - xy * xy]),
        np.stack([xy * mz - xz * yz, xz * xz - mx * mz, mx * yz - xy * xz]),
        np.stack([my * mz - yz * yz, yz * xz - xy * mz, xy * yz - my * xz]),
    ])                                                                         # (3 crosses, 3, N)
    squared = np.einsum("cdn,cdn->cn", crosses, crosses)
    # the longest cross by two selections (an argmax over the short axis and a fancy gather cost twice as
    # much); ties go to the first, as with argmax
    first = squared[0] >= squared[1]
    longer = np.where(first, squared[0], squared[1])
    third = squared[2] > longer
    vector = np.where(third, crosses[2], np.where(first, crosses[0], crosses[1]))   # (3, N)
    length = np.sqrt(np.where(third, squared[2], longer))
    degenerate = length < 1e-300
    vector[:, degenerate] = ((0.0,), (0.0,), (1.0,))
    length[degenerate] = 1.0
    return (vector / length).T


_QUADRIC_EXPONENTS = ((2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0))   # the constant last: c0 is then
# the last unknown, which forward substitution alone yields


def _quadric_height(a: np.ndarray, b: np.ndarray, h: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """c0 of the weighted least-squares quadric h ~ c0 + c1 a + c2 b + c3 a^2 + c4 ab + c5 b^2 per column.

    a, b, h, weights: (k, N). The 6x6 normal matrix is assembled from the 15 weighted moments sum w a^i b^j
    (i + j <= 4) and solved by a Cholesky factorisation vectorised over the N systems (a loop over rows).
    """
    # sum over the neighbours of w a^i times b^j as one einsum each: a product and its sum in one pass, no
    # (moments, k, N) buffer written and read back (half the time)
    weighted_a = [weights]                                                 # w a^i, i = 0..4
    for _ in range(4):
        weighted_a.append(weighted_a[-1] * a)
    powers_b = [None, b]                                                   # b^j, j = 1..4
    for _ in range(3):
        powers_b.append(powers_b[-1] * b)

    def weighted_sum(weighted: np.ndarray, j: int) -> np.ndarray:
        return weighted.sum(axis=0) if j == 0 else np.einsum("kn,kn->n", weighted, powers_b[j])

    moments = {(i, j): weighted_sum(weighted_a[i], j) for i in range(5) for j in range(5 - i)}
    weighted_h = [weights * h]                                             # w h a^i, i = 0..1
    weighted_h.append(weighted_h[0] * a)
    rhs = [np.einsum("kn,kn->n", weighted_h[1], a) if i == 2 else weighted_sum(weighted_h[i], j)
           for i, j in _QUADRIC_EXPONENTS]
    regularisation = np.float32(1e-6)
    tiny = np.float32(1e-30)
    lower: list[list[np.ndarray]] = []
    inverse_diagonal: list[np.ndarray] = []
    solution: list[np.ndarray] = []
    for row, (ri, rj) in enumerate(_QUADRIC_EXPONENTS):
        lower.append([])
        for column in range(row + 1):
            ci, cj = _QUADRIC_EXPONENTS[column]
            entry = moments[(ri + ci, rj + cj)]
            if row == column:
                entry = entry + regularisation
            for m in range(column):
                entry = entry - lower[row][m] * lower[column][m]
            if row == column:
                inverse_diagonal.append(1.0 / np.sqrt(np.maximum(entry, tiny)))
                lower[row].append(None)
            else:
                lower[row].append(entry * inverse_diagonal[column])
        value = rhs[row]
        for m in range(row):
            value = value - lower[row][m] * solution[m]
        solution.append(value * inverse_diagonal[row])
    return solution[-1] * inverse_diagonal[-1]


def mls_smooth(xyz: np.ndarray, k: int, order: int = 2, radius: float = 0.0,
               neighbour_index: np.ndarray | None = None, neighbour_distances: np.ndarray | None = None
               ) -> np.ndarray:
    """Moving least squares (Eq. 6): each point projected onto a polynomial fitted to its neighbourhood.

    The neighbourhood is the k nearest points (and, with radius > 0, only those within radius); the weight
    w = exp(-d^2 / h^2) decreases with distance, h being the distance to the farthest neighbour. A local frame
    comes from the weighted covariance (normal = least eigenvector); order 1 projects onto that plane,
    order 2 fits the height h(a, b) = c0 + c1 a + c2 b + c3 a^2 + c4 ab + c5 b^2 by weighted least squares
    and moves the point to h at its own (a, b). Points with too few neighbours are left where they are.
    neighbour_index / neighbour_distances: an earlier k-NN query (N, k'), all of whose columns are used,
    entries < 0 for dropped neighbours.
    """
    count = len(xyz)
    minimum = 3 * order + 1
    if count < minimum + 1:
        return xyz.copy()
    k = min(k, count)
    if neighbour_index is None:
        neighbour_distances, neighbour_index = cKDTree(xyz).query(xyz, k=k, workers=-1)
    # neighbour-major (k, N) layout: every per-neighbour quantity is a contiguous row, sums over neighbours
    # are row additions (copies: numpy's results keep the memory order of a transposed view, strided)
    index, distances = np.ascontiguousarray(neighbour_index.T), np.ascontiguousarray(neighbour_distances.T)
    origin = xyz.mean(axis=0)
    # float32 in metres about the centroid: sub-micrometre resolution, half the memory traffic
    local = np.ascontiguousarray((xyz - origin).T, dtype=np.float32)      # (3, N)
    # a dropped neighbour's distance is NaN: fmax skips it in the scale and turns its weight into 0
    present = (index >= 0) & np.isfinite(distances)
    known = np.where(present, distances, np.nan).astype(np.float32)
    scale = np.maximum(np.fmax.reduce(known, axis=0), np.float32(1e-12))
    weights = np.fmax(np.exp(-np.square(known / scale)), np.float32(0.0))
    if radius > 0:
        weights[known > radius] = 0.0
    enough = np.count_nonzero(weights, axis=0) >= minimum
    # neighbours relative to the point: the covariance is translation invariant, and the quadric's basis is
    # centred at the point. A dropped neighbour stands at the point itself (0): a far one's powers in the
    # quadric's sums would overflow. np.take: 3x faster than indexing with an array
    relative = np.take(local, np.where(present, index, np.arange(count)), axis=1)   # (3, k, N)
    relative -= local[:, None, :]
    weight_sum = np.maximum(weights.sum(axis=0), np.float32(1e-30))
    weighted = relative * weights
    mean = weighted.sum(axis=1) / weight_sum                               # (3, N) centroid - point
    entries = [(weighted[i] * relative[j]).sum(axis=0) / weight_sum - mean[i] * mean[j]
               for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))]
    normal = _smallest_eigenvectors_of(*(e.astype(np.float64) for e in entries)).T.astype(np.float32)  # (3, N)
    if order == 1:
        smoothed = local + (mean * normal).sum(axis=0) * normal             # onto the plane through the centroid
    else:
        # any orthonormal tangent pair: the quadric's basis spans the same space under rotation about the
        # normal, and under translation, so the basis is centred at the point itself: its height is then c0
        use_x = np.abs(normal[0]) < 0.9
        zero = np.zeros_like(normal[0])
        # normal x (1, 0, 0) = (0, n_z, -n_y); normal x (0, 1, 0) = (-n_z, 0, n_x)
        axis_a = np.stack([np.where(use_x, zero, -normal[2]), np.where(use_x, normal[2], zero),
                           np.where(use_x, -normal[1], normal[0])])
        axis_a /= np.sqrt((axis_a * axis_a).sum(axis=0))
        axis_b = np.cross(normal, axis_a, axis=0)
        inverse_scale = 1.0 / scale
        # each coordinate row by row, in place: no (3, k, N) temporaries (einsum was slower still)
        in_frame, term = np.empty_like(relative), np.empty_like(relative[0])
        for coordinate, axis in zip(in_frame, (axis_a * inverse_scale, axis_b * inverse_scale, normal),
                                    strict=True):
            np.multiply(relative[0], axis[0], out=coordinate)
            for d in (1, 2):
                np.multiply(relative[d], axis[d], out=term)
                coordinate += term
        a, b, h = in_frame
        smoothed = local + _quadric_height(a, b, h, weights) * normal
    return np.where(enough, smoothed, local).T.astype(np.float64) + origin


def voxel_downsample(cloud: Cloud, size: float) -> Cloud:
    """The centroid of each occupied voxel of edge `size`; colour and camera of the voxel's first point."""
    if size <= 0 or len(cloud) == 0:
        return cloud
    keys = np.floor(cloud.xyz / size).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse)
    centroids = np.stack([np.bincount(inverse, weights=cloud.xyz[:, d]) for d in range(3)], axis=1)
    picked = cloud.subset(first)
    return picked.with_points(centroids / counts[:, None])


def _window_candidates(cloud: Cloud, half: int) -> np.ndarray:
    """(N, (2 half + 1)^2) indices of the points in each point's pixel window (same camera), N (one past
    the last point) where none; column (2 half + 1)^2 // 2 is the point itself. Needs cloud.pixel and
    cloud.camera."""
    count = len(cloud)
    u = cloud.pixel[:, 0]
    v = cloud.pixel[:, 1]
    u0, v0 = int(u.min()) - half, int(v.min()) - half
    width, height = int(u.max()) - u0 + half + 1, int(v.max()) - v0 + half + 1
    # intp: numpy converts any other index type at every gather
    grid = np.full((int(cloud.camera.max()) + 1, height, width), count, dtype=np.intp)
    grid[cloud.camera, v - v0, u - u0] = np.arange(count)
    # a strided view of every window: one gather of (side, side) blocks, no (N, W) index arithmetic
    side = 2 * half + 1
    windows = sliding_window_view(grid, (side, side), axis=(1, 2))
    return windows[cloud.camera, v - v0 - half, u - u0 - half].reshape(count, side * side)


def nearest_neighbours(cloud: Cloud, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances and indices (N, k) of each point's k nearest neighbours, itself included (in no order).

    A cloud deprojected from depth images is organised: a point's 3-D neighbours are among its image
    neighbours, so a (2h+1)^2 pixel window (h from k) of the same camera replaces a KD-tree query, which
    costs ten times more. Missing neighbours have index -1 and distance inf.
    """
    count = len(cloud)
    if cloud.pixel is None or cloud.camera is None:
        distances, index = cKDTree(cloud.xyz).query(cloud.xyz, k=min(k, count), workers=-1)
        return distances.reshape(count, -1), index.reshape(count, -1)
    half = max(int(np.ceil((np.sqrt(k + 1.0) - 1.0) / 2.0)), 1)   # the smallest window with k neighbours
    candidates = _window_candidates(cloud, half)
    # coordinates as contiguous float32 rows with an infinite point at index N: a missing neighbour is then
    # infinitely far without a mask
    coordinates = np.empty((3, count + 1), dtype=np.float32)
    coordinates[:, :count] = cloud.xyz.T
    coordinates[:, count] = np.inf
    squared = np.zeros(candidates.shape, dtype=np.float32)
    for coordinate in coordinates:
        difference = np.take(coordinate, candidates)                      # take: faster than []
        difference -= coordinate[:count, None]
        difference *= difference
        squared += difference
    take = min(k, squared.shape[1])
    if take < squared.shape[1]:
        # the k smallest by one partition of int64 keys (the float32's bits, which order non-negative floats,
        # above the index): half the cost of argpartition and two gathers; ties go to the lower index
        keys = squared.view(np.int32).astype(np.int64)
        keys <<= 32
        keys |= candidates
        nearest = np.partition(keys, take - 1, axis=1)[:, :take]
        squared = (nearest >> 32).astype(np.int32).view(np.float32)
        candidates = nearest & 0xFFFFFFFF
    distances = np.sqrt(squared, dtype=np.float64)
    candidates[candidates == count] = -1
    return distances, candidates


def filter_cloud(cloud: Cloud, config) -> Cloud:
    """The configured filter chain: crop box, colour condition, SOR (Eq. 5), MLS (Eq. 6), voxel grid."""
    f = config.filters
    box_min, box_max = config.crop_box()
    cloud = cloud.subset(crop_box_mask(cloud.xyz, box_min, box_max))
    if f.color_filter and cloud.rgb is not None:
        cloud = cloud.subset(color_mask(cloud.rgb, f.color_min, f.color_max))
    # one k-NN query serves both SOR and MLS; MLS then ignores the neighbours SOR dropped
    k = max(f.sor_neighbors + 1 if f.sor else 0, f.mls_neighbors if f.mls else 0)
    if k and len(cloud) > k:
        distances, index = nearest_neighbours(cloud, k)
        if cloud.pixel_footprint <= 0 and distances.shape[1] > 1:  # unknown intrinsics: nearest spacing
            nearest = np.partition(distances, 1, axis=1)[:, 1]  # [:, 0] is the point itself
            cloud = replace(cloud, pixel_footprint=float(np.median(nearest[np.isfinite(nearest)])))
        if f.sor:
            keep = statistical_outlier_mask(cloud.xyz, f.sor_neighbors, f.sor_alpha, distances)
            if not keep.all():
                renumber = np.cumsum(keep) - 1
                index = np.where((index >= 0) & keep[index], renumber[index], -1)[keep]
                distances = distances[keep]
                cloud = cloud.subset(keep)
        if f.mls and len(cloud) > f.mls_neighbors:
            radius = f.mls_radius_px * cloud.pixel_footprint
            cloud = cloud.with_points(mls_smooth(cloud.xyz, f.mls_neighbors, f.mls_order, radius, index, distances))
    if f.voxel_size > 0:
        cloud = voxel_downsample(cloud, f.voxel_size)
    return cloud
