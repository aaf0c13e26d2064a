"""Filters (paper Sec. II-B), each optional and configured in the `filters` section.

Public API (all vectorised; masks are boolean arrays over the points):
    crop_box_mask(xyz, box_min, box_max)             spatial condition
    color_mask(rgb, color_min, color_max)            colour condition on packed 0x00RRGGBB
    statistical_outlier_mask(xyz, k, alpha)          Eq. 5: mean k-NN distance <= mu + alpha sigma
    mls_smooth(xyz, k, order, radius=0)              Eq. 6: project each point onto its weighted local
                                                     plane (order 1) or quadric (order 2)
    voxel_downsample(cloud, size)                    one point (the centroid) per occupied voxel
    filter_cloud(cloud, config) -> Cloud             the configured chain, in the paper's order
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.cloud import Cloud
from ntcr_recon.ros.pointcloud import unpack_rgb


def crop_box_mask(xyz: np.ndarray, box_min, box_max) -> np.ndarray:
    """Points inside the axis-aligned box [box_min, box_max] (inclusive)."""
    return np.all((xyz >= np.asarray(box_min)) & (xyz <= np.asarray(box_max)), axis=1)


def color_mask(rgb: np.ndarray, color_min, color_max) -> np.ndarray:
    """Points whose 8-bit R, G and B each lie within [color_min, color_max]."""
    channels = unpack_rgb(rgb)
    return np.all((channels >= np.asarray(color_min)) & (channels <= np.asarray(color_max)), axis=1)


def statistical_outlier_mask(xyz: np.ndarray, neighbors: int, alpha: float,
                             tree: cKDTree | None = None) -> np.ndarray:
    """Eq. 5: keep points whose mean distance to their k nearest neighbours is <= mu + alpha * sigma."""
    if len(xyz) <= neighbors:
        return np.ones(len(xyz), dtype=bool)
    tree = cKDTree(xyz) if tree is None else tree
    distances, _ = tree.query(xyz, k=neighbors + 1)
    mean_distance = distances[:, 1:].mean(axis=1)
    threshold = mean_distance.mean() + alpha * mean_distance.std()
    return mean_distance <= threshold


def mls_smooth(xyz: np.ndarray, neighbors: int, order: int = 2, radius: float = 0.0,
               tree: cKDTree | None = None) -> np.ndarray:
    """Moving least squares (Eq. 6): each point projected onto a polynomial fitted to its neighbourhood.

    The neighbourhood is the k nearest points (and, with radius > 0, only those within radius); the weight
    w = exp(-d^2 / h^2) decreases with distance, h being the distance to the farthest neighbour. A local frame
    comes from the weighted covariance (normal = least eigenvector); order 1 projects onto that plane,
    order 2 fits the height h(a, b) = c0 + c1 a + c2 b + c3 a^2 + c4 ab + c5 b^2 by weighted least squares
    and moves the point to h at its own (a, b). Points with too few neighbours are left where they are.
    """
    count = len(xyz)
    minimum = 3 * order + 1
    if count < minimum + 1:
        return xyz.copy()
    k = min(neighbors, count)
    tree = cKDTree(xyz) if tree is None else tree
    distances, index = tree.query(xyz, k=k)
    scale = np.maximum(distances[:, -1:], 1e-12)
    weights = np.exp(-((distances / scale) ** 2))
    if radius > 0:
        weights[distances > radius] = 0.0
    enough = np.count_nonzero(weights > 0, axis=1) >= minimum
    neighbourhood = xyz[index]                                   # (N, k, 3)
    weight_sum = weights.sum(axis=1, keepdims=True)
    centroid = np.einsum("nk,nkd->nd", weights, neighbourhood) / weight_sum
    offsets = neighbourhood - centroid[:, None, :]
    covariance = np.einsum("nk,nki,nkj->nij", weights, offsets, offsets)
    _, vectors = np.linalg.eigh(covariance)                      # ascending eigenvalues
    normal, axis_a, axis_b = vectors[:, :, 0], vectors[:, :, 2], vectors[:, :, 1]
    own = xyz - centroid
    own_height = np.einsum("nd,nd->n", own, normal)
    if order == 1:
        smoothed = xyz - own_height[:, None] * normal
    else:
        a = np.einsum("nkd,nd->nk", offsets, axis_a) / scale
        b = np.einsum("nkd,nd->nk", offsets, axis_b) / scale
        h = np.einsum("nkd,nd->nk", offsets, normal)
        basis = np.stack([np.ones_like(a), a, b, a * a, a * b, b * b], axis=2)   # (N, k, 6)
        normal_matrix = np.einsum("nk,nki,nkj->nij", weights, basis, basis)
        normal_matrix += 1e-9 * np.eye(6)
        rhs = np.einsum("nk,nki,nk->ni", weights, basis, h)
        coefficients = np.linalg.solve(normal_matrix, rhs[:, :, None])[:, :, 0]
        a0 = np.einsum("nd,nd->n", own, axis_a) / scale[:, 0]
        b0 = np.einsum("nd,nd->n", own, axis_b) / scale[:, 0]
        own_basis = np.stack([np.ones_like(a0), a0, b0, a0 * a0, a0 * b0, b0 * b0], axis=1)
        surface_height = np.einsum("ni,ni->n", own_basis, coefficients)
        smoothed = xyz + (surface_height - own_height)[:, None] * normal
    return np.where(enough[:, None], smoothed, xyz)


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


def filter_cloud(cloud: Cloud, config) -> Cloud:
    """The configured filter chain: crop box, colour condition, SOR (Eq. 5), MLS (Eq. 6), voxel grid."""
    f = config.filters
    box_min, box_max = config.crop_box()
    cloud = cloud.subset(crop_box_mask(cloud.xyz, box_min, box_max))
    if f.color_filter and cloud.rgb is not None:
        cloud = cloud.subset(color_mask(cloud.rgb, f.color_min, f.color_max))
    tree = None
    if f.sor and len(cloud) > f.sor_neighbors:
        tree = cKDTree(cloud.xyz)
        keep = statistical_outlier_mask(cloud.xyz, f.sor_neighbors, f.sor_alpha, tree)
        if not keep.all():
            cloud, tree = cloud.subset(keep), None
    if f.mls and len(cloud) > f.mls_neighbors:
        radius = f.mls_radius_px * cloud.pixel_footprint
        cloud = cloud.with_points(mls_smooth(cloud.xyz, f.mls_neighbors, f.mls_order, radius, tree))
    if f.voxel_size > 0:
        cloud = voxel_downsample(cloud, f.voxel_size)
    return cloud
