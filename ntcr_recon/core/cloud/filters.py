"""Filters (paper Sec. II-B), each optional and configured in the `filters` section.

Public API (masks are boolean arrays over the points; the per-point loops, the image-window k-NN, SOR's mean
distances and MLS's local fits, are compiled kernels, core.base.compiled):
    crop_box_mask(xyz, box_min, box_max)             spatial condition
    crop_mask(xyz, config, box=None, viewpoints=None) the rig's crop box, less the clamp and what it hides
    color_mask(rgb, color_min, color_max)            colour condition on packed 0x00RRGGBB
    statistical_outlier_mask(xyz, k, alpha)          Eq. 5: mean k-NN distance <= mu + alpha sigma
    mls_smooth(xyz, k, order, radius=0)              Eq. 6: project each point onto its weighted local
                                                     plane (order 1) or quadric (order 2)
    voxel_downsample(cloud, size)                    one point (the centroid) per occupied voxel
    nearest_neighbours(cloud, k) -> (distances, index) k nearest of each point, self included: in the image
                                                     (a pixel window per camera) when the cloud has pixel
                                                     coordinates, else by a KD-tree
    filter_cloud(cloud, config) -> Cloud             the configured chain, in the paper's order
    smallest_eigenvector(xx, xy, xz, yy, yz, zz)     least eigenvector of a symmetric 3x3 matrix (a kernel)
"""

from __future__ import annotations

from dataclasses import replace

import numba
import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.cloud.points import Cloud, rows, unpack_rgb


def crop_box_mask(xyz: np.ndarray, box_min, box_max) -> np.ndarray:
    """Points inside the axis-aligned box [box_min, box_max] (inclusive)."""
    # a column at a time: np.all over an axis of length 3 costs five times more
    inside = np.ones(len(xyz), dtype=bool)
    for coordinate, low, high in zip(np.asarray(xyz).T, np.asarray(box_min, dtype=float),
                                     np.asarray(box_max, dtype=float), strict=True):
        inside &= coordinate >= low
        inside &= coordinate <= high
    return inside


def crop_mask(xyz: np.ndarray, config, box: tuple[np.ndarray, np.ndarray] | None = None,
              viewpoints: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the points (base frame) inside the rig's crop box - or `box` within it - and outside the clamp's
    cylinder below the robot's base plane (filters.clamp_radius); with `viewpoints` (the origin of the
    camera that saw each point, (3,) or (N, 3)), also those the clamp hides from it: a stereo matcher
    mixes the clamp's edge with the background behind it, and those pixels fly out along their rays."""
    inside = crop_box_mask(xyz, *(config.crop_box() if box is None else box))
    radius = config.filters.clamp_radius
    if radius > 0 and np.any(inside):
        index = np.flatnonzero(inside)
        base = np.asarray(config.robot.base_position, float)
        local = (np.take(xyz, index, axis=0) - base) @ config.robot.base_rotation  # in the robot base's frame
        out = (local[:, 2] < 0) & (local[:, 0] ** 2 + local[:, 1] ** 2 < radius ** 2)
        if viewpoints is not None:
            origin = (np.asarray(viewpoints, float) - base) @ config.robot.base_rotation
            origin = np.take(origin, index, axis=0) if origin.ndim == 2 else np.broadcast_to(origin, local.shape)
            # a line of sight between two points above the base plane stays above it
            below = np.flatnonzero((local[:, 2] < 0) | (origin[:, 2] < 0))
            out[below] |= _through_clamp(origin[below], local[below], radius)
        inside[index[out]] = False
    return inside


def _through_clamp(origin: np.ndarray, point: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: the line of sight from `origin` to each point (robot base frame) passes through the cylinder of
    `radius` about the z axis below z = 0 before it reaches the point."""
    direction = point - origin
    # |origin_xy + t direction_xy| < radius over (t_in, t_out); z < 0 over (t_below, t_above)
    a = direction[:, 0] ** 2 + direction[:, 1] ** 2
    b = origin[:, 0] * direction[:, 0] + origin[:, 1] * direction[:, 1]
    c = origin[:, 0] ** 2 + origin[:, 1] ** 2 - radius ** 2
    root = np.sqrt(np.maximum(b * b - a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in, t_out = (-b - root) / a, (-b + root) / a
        crossing = -origin[:, 2] / direction[:, 2]
    level = np.where(origin[:, 2] < 0, -np.inf, np.inf)  # a level line of sight: below all along, or never
    t_below = np.where(direction[:, 2] < 0, crossing, np.where(direction[:, 2] > 0, -np.inf, level))
    t_above = np.where(direction[:, 2] > 0, crossing, np.where(direction[:, 2] < 0, np.inf, -level))
    start = np.maximum.reduce([t_in, t_below, np.zeros(len(a))])
    end = np.minimum.reduce([t_out, t_above, np.full(len(a), 1.0 - 1e-9)])
    return (b * b > a * c) & (a > 0) & (start < end)


def color_mask(rgb: np.ndarray, color_min, color_max) -> np.ndarray:
    """Points whose 8-bit R, G and B each lie within [color_min, color_max]."""
    channels = unpack_rgb(rgb)
    return np.all((channels >= np.asarray(color_min)) & (channels <= np.asarray(color_max)), axis=1)


@jit
def _mean_neighbour_distances(distances, k):
    """Eq. 5's per-point statistic: the mean distance to the point's k nearest neighbours (the first k + 1
    columns of `distances`, the point itself at 0 among them). Missing neighbours (inf) count out, so a point
    at a hole or a thin part of the image is judged by the neighbours it has; with fewer than 3, inf."""
    means = np.empty(len(distances))
    for point in range(len(distances)):
        total, count = 0.0, -1                  # the point itself counts out
        for n in range(min(k + 1, distances.shape[1])):
            if np.isfinite(distances[point, n]):
                total += distances[point, n]
                count += 1
        means[point] = total / count if count >= 3 else np.inf
    return means


def statistical_outlier_mask(xyz: np.ndarray, k: int, alpha: float,
                             distances: np.ndarray | None = None) -> np.ndarray:
    """Eq. 5: keep points whose mean distance to their k nearest neighbours is <= mu + alpha * sigma.

    distances: optional (N, k') distances to each point's nearest, itself included and nearest first, k' >= k + 1,
    from an earlier query.
    """
    if len(xyz) <= k:
        return np.ones(len(xyz), dtype=bool)
    if distances is None:
        distances, _ = cKDTree(xyz).query(xyz, k=k + 1, workers=-1)
    mean_distance = _mean_neighbour_distances(np.ascontiguousarray(distances, dtype=np.float64), k)
    finite = np.isfinite(mean_distance)
    if not finite.any():
        return finite
    threshold = mean_distance[finite].mean() + alpha * mean_distance[finite].std()
    return mean_distance <= threshold


# floor of p^2 (the spread of a 3x3 matrix's eigenvalues) in the closed-form eigensolver: a neighbourhood of
# coincident points has p = 0, and p^3 of a 1e-300 floor underflowed to 0 (0 / 0 = NaN normals)
_TINY_SPREAD = 1e-60


@jit
def smallest_eigenvector(xx, xy, xz, yy, yz, zz):
    """Unit eigenvector (x, y, z) of the smallest eigenvalue of the symmetric 3x3 matrix given by its six
    distinct entries.

    The eigenvalue by the trigonometric solution of the characteristic cubic; the eigenvector is the longest
    cross product of two rows of (A - lambda I), which is orthogonal to both ((0, 0, 1) when all vanish).
    """
    trace = (xx + yy + zz) / 3.0
    dx, dy, dz = xx - trace, yy - trace, zz - trace
    p = np.sqrt(max((dx * dx + dy * dy + dz * dz + 2.0 * (xy * xy + xz * xz + yz * yz)) / 6.0, _TINY_SPREAD))
    # det(shifted / p) / 2
    det = dx * (dy * dz - yz * yz) - xy * (xy * dz - yz * xz) + xz * (xy * yz - dy * xz)
    half_det = min(max(det / (2.0 * p * p * p), -1.0), 1.0)
    smallest = trace + 2.0 * p * np.cos(np.arccos(half_det) / 3.0 + 2.0 * np.pi / 3.0)
    mx, my, mz = xx - smallest, yy - smallest, zz - smallest
    # rows of (A - lambda I): r0 = (mx, xy, xz), r1 = (xy, my, yz), r2 = (xz, yz, mz); ties go to the first cross
    best = (xy * yz - xz * my, xz * xy - mx * yz, mx * my - xy * xy)                     # r0 x r1
    best_squared = best[0] * best[0] + best[1] * best[1] + best[2] * best[2]
    for cross in ((xy * mz - xz * yz, xz * xz - mx * mz, mx * yz - xy * xz),             # r0 x r2
                  (my * mz - yz * yz, yz * xz - xy * mz, xy * yz - my * xz)):            # r1 x r2
        squared = cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]
        if squared > best_squared:
            best, best_squared = cross, squared
    length = np.sqrt(best_squared)
    if length < 1e-300:
        return 0.0, 0.0, 1.0
    return best[0] / length, best[1] / length, best[2] / length


# the quadric's monomials a^i b^j as (i, j); the constant last: c0 is then the last unknown, which forward
# substitution alone yields
_QUADRIC_EXPONENTS = ((2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0))
_QUADRIC_REGULARISATION = 1e-6    # added to the normal matrix's diagonal (a, b are in units of the scale)
_TINY_PIVOT = 1e-30               # floor of a Cholesky pivot: a degenerate neighbourhood gives c0 = 0, not NaN


@jit
def _quadric_height(a, b, h, weights, normal_matrix, rhs):
    """c0 of the weighted least-squares quadric h ~ c0 + c1 a + c2 b + c3 a^2 + c4 ab + c5 b^2 (Eq. 6's
    polynomial of order 2) over one neighbourhood.

    a, b, h, weights: (k,) the neighbours' tangent coordinates, heights and weights. normal_matrix (6, 6),
    rhs (6,): scratch space. The 6x6 normal matrix is assembled from the 15 moments m_ij = sum w a^i b^j
    (i + j <= 4) and solved by Cholesky; c0 is the last unknown, so forward substitution and one division by
    the last pivot yield it.
    """
    # the moments and right-hand sides as scalars: in registers, not in memory that might alias the inputs
    m00 = m10 = m01 = m20 = m11 = m02 = m30 = m21 = m12 = m03 = m40 = m31 = m22 = m13 = m04 = 0.0
    r20 = r11 = r02 = r10 = r01 = r00 = 0.0       # sum w h a^i b^j
    for n in range(len(a)):
        w, x, y = weights[n], a[n], b[n]
        wx, wy = w * x, w * y
        wxx, wxy, wyy = wx * x, wx * y, wy * y
        # one line per degree i + j
        m00 += w
        m10, m01 = m10 + wx, m01 + wy
        m20, m11, m02 = m20 + wxx, m11 + wxy, m02 + wyy
        m30, m21, m12, m03 = m30 + wxx * x, m21 + wxx * y, m12 + wxy * y, m03 + wyy * y
        m40, m31, m22, m13, m04 = (m40 + wxx * x * x, m31 + wxx * x * y, m22 + wxx * y * y, m13 + wxy * y * y,
                                   m04 + wyy * y * y)
        r20 += wxx * h[n]
        r11 += wxy * h[n]
        r02 += wyy * h[n]
        r10 += wx * h[n]
        r01 += wy * h[n]
        r00 += w * h[n]
    # entry (row, column) = m_(ri + ci)(rj + cj) over _QUADRIC_EXPONENTS; the lower triangle is what Cholesky reads
    moments = ((m00, m01, m02, m03, m04), (m10, m11, m12, m13, 0.0), (m20, m21, m22, 0.0, 0.0),
               (m30, m31, 0.0, 0.0, 0.0), (m40, 0.0, 0.0, 0.0, 0.0))
    for row in range(6):
        ri, rj = _QUADRIC_EXPONENTS[row]
        for column in range(row + 1):
            ci, cj = _QUADRIC_EXPONENTS[column]
            normal_matrix[row, column] = moments[ri + ci][rj + cj]
        normal_matrix[row, row] += _QUADRIC_REGULARISATION
    rhs[0], rhs[1], rhs[2], rhs[3], rhs[4], rhs[5] = r20, r11, r02, r10, r01, r00
    # in place: the lower triangle becomes L with the inverse pivots on its diagonal; rhs becomes L^-1 rhs
    for row in range(6):
        for column in range(row + 1):
            entry = normal_matrix[row, column]
            for m in range(column):
                entry -= normal_matrix[row, m] * normal_matrix[column, m]
            if row == column:
                normal_matrix[row, row] = 1.0 / np.sqrt(max(entry, _TINY_PIVOT))
            else:
                normal_matrix[row, column] = entry * normal_matrix[column, column]
        value = rhs[row]
        for m in range(row):
            value -= normal_matrix[row, m] * rhs[m]
        rhs[row] = value * normal_matrix[row, row]
    return rhs[5] * normal_matrix[5, 5]


@jit
def _weight_exponents(index, distances, radius):
    """Eq. 6's weights w = exp(-d^2 / s^2) before the exponential, per neighbour (index, distances (N, k)):
    -d^2 / s^2, s the point's farthest neighbour, or -inf (w = 0) for a missing neighbour (index < 0,
    infinite distance, or beyond radius > 0). Returns them and s per point. (The exponential is numpy's: its
    SIMD version is several times faster than a compiled scalar call.)"""
    count, k = index.shape
    exponents = np.empty((count, k))
    scale = np.empty(count)
    for point in range(count):
        farthest = 1e-12
        for n in range(k):
            if index[point, n] >= 0 and distances[point, n] < np.inf:
                farthest = max(farthest, distances[point, n])
        for n in range(k):
            distance = distances[point, n]
            present = index[point, n] >= 0 and distance < np.inf and not (radius > 0 and distance > radius)
            exponents[point, n] = -(distance / farthest) ** 2 if present else -np.inf
        scale[point] = farthest
    return exponents, scale


@jit
def _neighbour_offsets(xyz, point, index, weights, relative):
    """Each neighbour's offset from the point (into `relative` (k, 3)); a neighbour of weight 0 stands at the
    point itself. Returns the count of weighted neighbours."""
    weighted = 0
    x, y, z = xyz[point, 0], xyz[point, 1], xyz[point, 2]
    for n in range(len(index)):
        if weights[n] > 0.0:
            neighbour = index[n]
            relative[n, 0] = xyz[neighbour, 0] - x
            relative[n, 1] = xyz[neighbour, 1] - y
            relative[n, 2] = xyz[neighbour, 2] - z
            weighted += 1
        else:
            relative[n, 0] = relative[n, 1] = relative[n, 2] = 0.0
    return weighted


@jit
def _weighted_normal(relative, weights, mean):
    """The weighted centroid of a neighbourhood (into `mean` (3,)) and the unit normal of its weighted
    least-squares plane: the least eigenvector of the weighted covariance."""
    # sums as scalars: in registers, not in memory that might alias the inputs
    sw = sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
    for n in range(len(weights)):
        w, x, y, z = weights[n], relative[n, 0], relative[n, 1], relative[n, 2]
        wx, wy, wz = w * x, w * y, w * z
        sw += w
        sx += wx
        sy += wy
        sz += wz
        sxx += wx * x
        sxy += wx * y
        sxz += wx * z
        syy += wy * y
        syz += wy * z
        szz += wz * z
    inverse = 1.0 / sw               # one division, not nine
    mx, my, mz = sx * inverse, sy * inverse, sz * inverse
    mean[0], mean[1], mean[2] = mx, my, mz
    return smallest_eigenvector(sxx * inverse - mx * mx, sxy * inverse - mx * my, sxz * inverse - mx * mz,
                                syy * inverse - my * my, syz * inverse - my * mz, szz * inverse - mz * mz)


@jit
def _tangent_coordinates(relative, normal, scale, a, b, h):
    """Offsets in a local frame: (a, b) along an orthonormal tangent pair, in units of `scale`, and the height
    h along the normal. Any tangent pair will do: the quadric's basis spans the same space under rotation
    about the normal."""
    # normal x (1, 0, 0), or normal x (0, 1, 0) when the normal is close to x
    tangent = (0.0, normal[2], -normal[1]) if abs(normal[0]) < 0.9 else (-normal[2], 0.0, normal[0])
    length = np.sqrt(tangent[0] ** 2 + tangent[1] ** 2 + tangent[2] ** 2)
    axis_a = (tangent[0] / length, tangent[1] / length, tangent[2] / length)
    axis_b = (normal[1] * axis_a[2] - normal[2] * axis_a[1], normal[2] * axis_a[0] - normal[0] * axis_a[2],
              normal[0] * axis_a[1] - normal[1] * axis_a[0])
    # the axes in units of the scale: two divisions per neighbour saved
    inverse = 1.0 / scale
    ax, ay, az = axis_a[0] * inverse, axis_a[1] * inverse, axis_a[2] * inverse
    bx, by, bz = axis_b[0] * inverse, axis_b[1] * inverse, axis_b[2] * inverse
    for n in range(len(relative)):
        x, y, z = relative[n, 0], relative[n, 1], relative[n, 2]
        a[n] = x * ax + y * ay + z * az
        b[n] = x * bx + y * by + z * bz
        h[n] = x * normal[0] + y * normal[1] + z * normal[2]


@jit(parallel=True)
def _moving_least_squares(xyz, index, weights, scale, order, minimum, chunks):
    """Eq. 6 for every point: moved along its local normal onto the weighted least-squares plane through its
    neighbours' centroid (order 1) or onto their quadric h(a, b) at its own (a, b) = (0, 0), i.e. by c0
    (order 2); left where it is with fewer than `minimum` weighted neighbours. index, weights: (N, k) rows of
    neighbours and their Eq. 6 weights; scale (N,): the unit of the quadric's tangent coordinates."""
    count, k = index.shape
    smoothed = xyz.copy()
    size = (count + chunks - 1) // chunks  # a block of points per thread, each with its own scratch space
    for chunk in numba.prange(chunks):
        relative = np.empty((k, 3))
        a, b, h = np.empty(k), np.empty(k), np.empty(k)
        mean = np.empty(3)
        normal_matrix, rhs = np.empty((6, 6)), np.empty(6)
        for point in range(chunk * size, min(count, (chunk + 1) * size)):
            if _neighbour_offsets(xyz, point, index[point], weights[point], relative) < minimum:
                continue
            normal = _weighted_normal(relative, weights[point], mean)
            if order == 1:
                height = mean[0] * normal[0] + mean[1] * normal[1] + mean[2] * normal[2]
            else:
                _tangent_coordinates(relative, normal, scale[point], a, b, h)
                height = _quadric_height(a, b, h, weights[point], normal_matrix, rhs)
            for d in range(3):
                smoothed[point, d] += height * normal[d]
    return smoothed


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
    if neighbour_index is None:
        neighbour_distances, neighbour_index = cKDTree(xyz).query(xyz, k=min(k, count), workers=-1)
    index = np.ascontiguousarray(neighbour_index, dtype=np.int64)
    exponents, scale = _weight_exponents(index, np.ascontiguousarray(neighbour_distances, dtype=np.float64),
                                         float(radius))
    weights = np.exp(exponents, out=exponents)
    return _moving_least_squares(np.ascontiguousarray(xyz, dtype=np.float64), index, weights, scale, order,
                                 minimum, numba.get_num_threads())


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


@jit(parallel=True)
def _image_window_neighbours(xyz, camera, pixel, k, half, chunks):
    """The k nearest of each point among the points of its (2 half + 1)^2 pixel window in the same camera,
    itself included, nearest first: (distances (N, k), indices (N, k)); inf and -1 where the window holds
    fewer. Squared distances in float32 (positions rounded to float32 first), ties going to the lower index,
    then their square roots in float64."""
    count = len(xyz)
    position = xyz.astype(np.float32)
    u0, v0 = pixel[:, 0].min() - half, pixel[:, 1].min() - half
    width, height = pixel[:, 0].max() - u0 + half + 1, pixel[:, 1].max() - v0 + half + 1
    # point index per (camera, pixel), -1 where none, with a margin of `half`: no window leaves the grid
    grid = np.full((camera.max() + 1, height, width), -1, dtype=np.int64)
    for point in range(count):
        grid[camera[point], pixel[point, 1] - v0, pixel[point, 0] - u0] = point
    nearest = np.full((count, k), np.inf)
    index = np.full((count, k), -1, dtype=np.int64)
    # a window's candidates as keys (the float32 distance's bits, which order non-negative floats, above the
    # index): distinct, so a candidate's rank is the count of smaller keys; this branch-free count takes half
    # the time of an insertion sort
    size = (count + chunks - 1) // chunks  # a block of points per thread, each with its own scratch space
    for chunk in numba.prange(chunks):
        distances = np.empty((2 * half + 1) ** 2, dtype=np.float32)
        keys = np.empty((2 * half + 1) ** 2, dtype=np.int64)
        distance_bits = distances.view(np.int32)
        for point in range(chunk * size, min(count, (chunk + 1) * size)):
            u, v = pixel[point, 0] - u0, pixel[point, 1] - v0
            found = 0
            for row in range(v - half, v + half + 1):
                for column in range(u - half, u + half + 1):
                    candidate = grid[camera[point], row, column]
                    if candidate >= 0:
                        distance = np.float32(0.0)
                        for d in range(3):
                            difference = position[candidate, d] - position[point, d]
                            distance += difference * difference
                        distances[found] = distance
                        keys[found] = candidate
                        found += 1
            for n in range(found):
                keys[n] |= np.int64(distance_bits[n]) << 32
            for n in range(found):
                rank = 0
                for m in range(found):
                    rank += keys[m] < keys[n]
                if rank < k:
                    nearest[point, rank] = np.sqrt(np.float64(distances[n]))
                    index[point, rank] = keys[n] & 0xFFFFFFFF
    return nearest, index


def nearest_neighbours(cloud: Cloud, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances and indices (N, k) of each point's k nearest neighbours, itself included, nearest first.

    A cloud deprojected from depth images is organised: a point's 3-D neighbours are among its image
    neighbours, so a (2h+1)^2 pixel window (h from k) of the same camera replaces a KD-tree query, which
    costs ten times more. Missing neighbours have index -1 and distance inf.
    """
    count = len(cloud)
    if cloud.pixel is None or cloud.camera is None:
        distances, index = cKDTree(cloud.xyz).query(cloud.xyz, k=min(k, count), workers=-1)
        return distances.reshape(count, -1), index.reshape(count, -1)
    half = max(int(np.ceil((np.sqrt(k + 1.0) - 1.0) / 2.0)), 1)   # the smallest window with k neighbours
    return _image_window_neighbours(cloud.xyz, cloud.camera, cloud.pixel, k, half, numba.get_num_threads())


@jit
def _neighbours_among_kept(index, keep):
    """The neighbour index rows of the kept points, renumbered to the kept points' order; a neighbour that was
    not kept becomes -1 (dropped)."""
    renumbered = np.cumsum(keep) - 1
    kept = np.empty((renumbered[-1] + 1, index.shape[1]), dtype=index.dtype)
    for point in range(len(index)):
        if keep[point]:
            for n in range(index.shape[1]):
                neighbour = index[point, n]
                kept[renumbered[point], n] = renumbered[neighbour] if neighbour >= 0 and keep[neighbour] else -1
    return kept


def filter_cloud(cloud: Cloud, config) -> Cloud:
    """The configured filter chain: crop box (the clamp kept out), colour condition, SOR (Eq. 5), MLS (Eq. 6),
    voxel grid."""
    f = config.filters
    origins = None if cloud.camera is None or not f.clamp_radius else np.take(config.camera_origins, cloud.camera,
                                                                              axis=0)
    inside = crop_mask(cloud.xyz, config, viewpoints=origins)
    if not inside.all():           # (fusion crops to the same box: usually nothing to drop, nothing to copy)
        cloud = cloud.subset(inside)
    if f.color_filter and cloud.rgb is not None:
        cloud = cloud.subset(color_mask(cloud.rgb, f.color_min, f.color_max))
    # one k-NN query serves both SOR and MLS; MLS then ignores the neighbours SOR dropped
    k = max(f.sor_neighbors + 1 if f.sor else 0, f.mls_neighbors if f.mls else 0)
    if k and len(cloud) > k:
        distances, index = nearest_neighbours(cloud, k)
        if cloud.pixel_footprint <= 0 and distances.shape[1] > 1:  # unknown intrinsics: nearest spacing
            nearest = distances[:, 1]  # rows are nearest first; [:, 0] is the point itself
            cloud = replace(cloud, pixel_footprint=float(np.median(nearest[np.isfinite(nearest)])))
        if f.sor:
            keep = statistical_outlier_mask(cloud.xyz, f.sor_neighbors, f.sor_alpha, distances)
            if not keep.all():
                index = _neighbours_among_kept(index, keep)
                distances = np.take(distances, rows(keep), axis=0)
                cloud = cloud.subset(keep)
        if f.mls and len(cloud) > f.mls_neighbors:
            radius = f.mls_radius_px * cloud.pixel_footprint
            cloud = cloud.with_points(mls_smooth(cloud.xyz, f.mls_neighbors, f.mls_order, radius, index, distances))
    if f.voxel_size > 0:
        cloud = voxel_downsample(cloud, f.voxel_size)
    return cloud
