"""Filters (paper Sec. II-B), each optional and configured in the `filters` section.

Public API (masks are boolean arrays over the points; the per-point loops, the image-window k-NN, SOR's mean
distances and MLS's local fits, are compiled kernels, core.base.compiled):
    crop_box_mask(xyz, box_min, box_max)             spatial condition
    crop_mask(xyz, config, box=None, viewpoints=None) the rig's crop box, less the clamp and what it hides
    color_mask(rgb, color_min, color_max)            colour condition on packed 0x00RRGGBB
    statistical_outlier_mask(xyz, k, alpha)          Eq. 5: mean k-NN distance <= mu + alpha sigma
    mls_smooth(xyz, k, order, radius=0)              Eq. 6 (core.cloud.mls): project each point onto its
                                                     weighted local plane (order 1) or quadric (order 2)
    voxel_downsample(cloud, size)                    one point (the centroid) per occupied voxel
    nearest_neighbours(cloud, k) -> (distances, index) k nearest of each point, self included: in the image
                                                     (a pixel window per camera) when the cloud has pixel
                                                     coordinates, else by a KD-tree
    filter_cloud(cloud, config) -> Cloud             the configured chain, in the paper's order
"""

from __future__ import annotations

from dataclasses import replace

import numba
import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.cloud.mls import mls_smooth
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
