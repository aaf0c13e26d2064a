"""Files written whole or not at all: a reader sees the old file or the new one, never a part.

Each writer writes a temporary file beside its target and renames it into place (one rename on one file
system). Used by the offline command, the nodes that save files and the figures.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ntcr_recon.core.cloud.points import unpack_rgb


def write_atomically(path, write) -> None:
    """Run write(temp_path) on a temporary file beside `path`, then move it into place."""
    path = Path(path)
    handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(handle)
    try:
        write(Path(temp))
        os.chmod(temp, 0o644)  # mkstemp's 0600 is for the temporary file, not the result
        os.replace(temp, path)
    except OSError as error:  # named by the file meant, not its temporary name (a full disk, a writer's refusal)
        Path(temp).unlink(missing_ok=True)
        if error.filename == str(path):
            raise
        raise OSError(error.errno, error.strerror or str(error), str(path)) from error
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise


def write_cloud_ply(path, xyz: np.ndarray, rgb: np.ndarray | None = None, normals: np.ndarray | None = None) -> None:
    """A binary PLY of float32 x y z (+ nx ny nz) (+ uchar red green blue), written atomically."""
    count = len(xyz)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    table = np.empty(count, dtype=fields)
    table["x"], table["y"], table["z"] = np.asarray(xyz, float).T
    if normals is not None:
        table["nx"], table["ny"], table["nz"] = np.asarray(normals, float).T
    if rgb is not None:
        colours = unpack_rgb(rgb)
        table["red"], table["green"], table["blue"] = colours.T
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property {types[kind]} {name}" for name, kind in fields] + ["end_header", ""]

    def write(temp: Path) -> None:
        with open(temp, "wb") as handle:
            handle.write("\n".join(header).encode("ascii"))
            handle.write(table.tobytes())

    write_atomically(Path(path), write)


def write_mesh(path, mesh) -> None:
    """A core.reconstruction.mesh.Mesh as PLY or STL (by the file's extension), written atomically."""
    import open3d as o3d

    path = Path(path)
    if path.suffix.lower() not in (".ply", ".stl"):
        raise ValueError(f"mesh file must end in .ply or .stl, got {path.name}")
    triangle_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                              o3d.utility.Vector3iVector(mesh.triangles))
    triangle_mesh.compute_triangle_normals()
    triangle_mesh.vertex_normals = o3d.utility.Vector3dVector(mesh.normals)

    def write(temp: Path) -> None:
        if not o3d.io.write_triangle_mesh(str(temp), triangle_mesh, write_ascii=False):
            raise OSError(f"open3d could not write {path.name}")

    write_atomically(path, write)
