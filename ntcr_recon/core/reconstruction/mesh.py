"""Meshing (paper Eq. 7-8): the relocated outer wall on the tube's own grid (`tube_mesh`, the default), or
open3d's screened Poisson surface reconstruction with low-density vertices trimmed (`poisson_mesh`).
`mesh_relocation(relocation, config)` is the mesh stage: the mesher the rig configuration's `mesh.method` names
(the Reconstructor and mesh_node call it). Writing meshes to files: `ntcr_recon.io.files`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray

    def __len__(self) -> int:
        return len(self.triangles)


def mesh_relocation(relocation, config) -> Mesh:
    """The configured mesher on a relocation (core.reconstruction.relocate.RelocationResult): `tube` (the relocated
    outer wall meshed on the tube's own grid) or `poisson` (open3d's screened Poisson, the paper's Eq. 7-8); config
    a RigConfig."""
    if config.mesh.method == "tube":
        return tube_mesh(relocation, config.robot)
    return poisson_mesh(relocation.relocated.xyz, relocation.normals, config.mesh)


def poisson_mesh(points: np.ndarray, normals: np.ndarray, config) -> Mesh:
    """Screened Poisson reconstruction of an oriented cloud, trimmed where the solver had little support.

    The cloud is first voxel-thinned to about `config.max_points` (a Poisson solve costs with its points,
    not with the surface's area), then solved at octree `config.poisson_depth`; vertices whose density
    lies in the lowest `config.density_quantile` (the surface Poisson invents to close holes) are removed.
    """
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # its octree warnings are not ours
    if len(points) < 16:
        raise ValueError(f"a mesh needs at least 16 points, got {len(points)}")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, float)))
    cloud.normals = o3d.utility.Vector3dVector(np.asarray(normals, float))
    if len(points) > config.max_points:
        extent = np.ptp(points, axis=0)
        area = 2.0 * (extent[0] * extent[1] + extent[1] * extent[2] + extent[0] * extent[2])
        cloud = cloud.voxel_down_sample(float(np.sqrt(area / config.max_points)) / 2.0)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        cloud, depth=config.poisson_depth, linear_fit=True)
    density = np.asarray(density)
    if config.density_quantile > 0 and len(density):
        mesh.remove_vertices_by_mask(density < np.quantile(density, config.density_quantile))
    mesh.remove_unreferenced_vertices()
    mesh.compute_vertex_normals()
    return Mesh(np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).copy(),
                np.asarray(mesh.vertex_normals).copy())


def tube_mesh(relocation, geometry, closing_cells: int = 1) -> Mesh:
    """Mesh the relocated outer wall on the tube's (arc length, angle) grid.

    Relocated points lie on the reference surface, so the surface is known exactly where points are: a grid
    of cells about two pixel footprints square on the outer wall, a cell kept where a relocated outer-wall
    point falls, gaps of up to `closing_cells` closed (sampling holes; a notch is wider), and two triangles
    per square of four kept cells, placed on the reference surface. Open where nothing was seen (the
    notches, the cameras' blind sides).
    """
    from scipy.ndimage import binary_closing

    from ntcr_recon.core.robot.surface import PART_OUTER_WALL

    coords = relocation.relocated_coordinates
    if coords is None or relocation.part is None:
        raise ValueError("the relocation carries no tube coordinates to mesh")
    outer = relocation.part == PART_OUTER_WALL
    s, angle = coords.s[outer], np.arctan2(coords.y[outer], coords.x[outer])
    r_o = geometry.outer_radius
    footprint = geometry.pixel_footprint_or_default(relocation.relocated.pixel_footprint)
    length = relocation.centerline.length
    rows = max(int(np.ceil(length / (2.0 * footprint))), 2)
    columns = max(int(np.ceil(2.0 * np.pi * r_o / (2.0 * footprint))), 8)
    row = np.clip((s / length * rows).astype(np.intp), 0, rows - 1)
    column = ((angle + np.pi) / (2.0 * np.pi) * columns).astype(np.intp) % columns
    kept = np.zeros((rows, columns + 2 * closing_cells), dtype=bool)
    kept[row, column + closing_cells] = True
    # the angle wraps around: pad with the opposite columns so closing works across +-pi
    kept[:, :closing_cells] = kept[:, columns:columns + closing_cells]
    kept[:, columns + closing_cells:] = kept[:, closing_cells:2 * closing_cells]
    if closing_cells:
        kept = binary_closing(kept, structure=np.ones((2 * closing_cells + 1,) * 2, bool), border_value=0)
    kept = kept[:, closing_cells:columns + closing_cells]
    # vertices at the cell centres on the reference surface
    grid_row, grid_column = np.nonzero(kept)
    vertex_index = np.full(kept.shape, -1, dtype=np.int64)
    vertex_index[grid_row, grid_column] = np.arange(len(grid_row))
    vertex_s = (grid_row + 0.5) / rows * length
    vertex_angle = (grid_column + 0.5) / columns * 2.0 * np.pi - np.pi
    unit_x, unit_y = np.cos(vertex_angle), np.sin(vertex_angle)
    vertices = relocation.centerline.to_points(vertex_s, r_o * unit_x, r_o * unit_y)
    _, _, normal, binormal = relocation.centerline.frames_at(vertex_s)
    normals = unit_x[:, None] * normal + unit_y[:, None] * binormal
    # quads of four kept cells (wrapping in angle), two triangles each, wound outward
    a = vertex_index[:-1, :]
    b = vertex_index[:-1, np.r_[1:columns, 0]]
    c = vertex_index[1:, np.r_[1:columns, 0]]
    d = vertex_index[1:, :]
    whole = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    a, b, c, d = a[whole], b[whole], c[whole], d[whole]
    triangles = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
    return Mesh(vertices, triangles, normals)
