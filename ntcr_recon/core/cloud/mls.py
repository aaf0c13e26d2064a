"""Moving least squares (paper Eq. 6): each point projected onto its weighted local plane (order 1) or quadric
(order 2) over its k nearest neighbours, the local fits compiled kernels (smallest_eigenvector: the least
eigenvector of a symmetric 3x3 matrix, the local plane's normal)."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.base.compiled import jit

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
