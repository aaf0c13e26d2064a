"""mesh_node: `<ns>/relocated/points` + `<ns>/centerline` of the same stamp -> the core's mesh, at `rate`.

The mesher is the rig configuration's `mesh.method` (core.reconstruction.mesh.mesh_relocation, the offline
command's mesh stage: `tube`, the relocated outer wall on the tube's own grid, or `poisson`, Eq. 7-8);
relocation_node's cloud carries what it reads (normals, surface parts, tube coordinates), the Path the centreline.

Meshing costs more than a frame period, so the node keeps only the newest relocated cloud and meshes it at
`rate` Hz (node clock: with `use_sim_time` the replayed bag's clock), skipping a tick when nothing new came.
Publishes, transient-local so RViz or a late subscriber gets the last mesh at once:
  `<ns>/mesh`      visualization_msgs/Marker TRIANGLE_LIST (base frame)
  `<ns>/mesh/raw`  shape_msgs/Mesh (vertices + triangles, base frame)
PLY on request: set the parameter `save_ply_path` (`ros2 param set /mesh_node save_ply_path /tmp/m.ply`) and
the newest mesh is written there (whole or not at all, by io.files.write_mesh; .stl works too); with no
mesh yet, the first one is. With `output_dir`
every new mesh is also written to `<output_dir>/mesh.ply`.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path as PathLib

import numpy as np
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from visualization_msgs.msg import Marker

from ntcr_recon.core.reconstruction.mesh import mesh_relocation
from ntcr_recon.io.files import write_mesh
from ntcr_recon.io.pointcloud import stamp_to_ns
from ntcr_recon.ros import cdr
from ntcr_recon.ros.messages import check_point_count, decode, relocation_from_msgs, stage_cloud_and_normals
from ntcr_recon.ros.node_stats import NodeStats
from ntcr_recon.ros.node_support import (
    LATCHED_QOS,
    STAGE_INPUT_QOS,
    ParameterError,
    RigNode,
    describe,
    guarded,
    max_points_parameter,
    run_node,
)
from ntcr_recon.ros.result_messages import mesh_marker_bytes, mesh_msg_bytes
from ntcr_recon.ros.topics import stage_topic

CENTERLINES_KEPT = 4  # the centrelines last received (not those of the highest stamps: see _on_centerline)
STAMP_JUMP_NS = 1_000_000_000  # a centreline stamped this much before the previous one: the clock jumped back

PARAMETERS = {
    "rate": (1.0, describe("meshes per second (of the node's clock)", minimum=0.01, maximum=30.0)),
    "save_ply_path": ("", describe("setting it writes the newest mesh to this PLY file")),
    "output_dir": ("", describe("when set, every new mesh is also written to <output_dir>/mesh.ply")),
    "max_points": max_points_parameter(),
}


class MeshNode(RigNode):
    def __init__(self, node_name: str = "mesh_node") -> None:
        self._timer = None
        self._mesh = None  # (core.reconstruction.mesh.Mesh, stamp) of the newest mesh
        self._pending_save: Path | None = None
        self._params = {"save_ply_path": ""}
        # open3d (the Poisson mesher, the mesh writer) loads in seconds: at start-up, not in the first tick.
        # Its OpenMP threads sleep between solves rather than spin: on a 2-core rig a spinning thread takes
        # a core from the chain's nodes (read when OpenMP starts, so before the import).
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        import open3d  # noqa: F401

        super().__init__(node_name, PARAMETERS)
        self.stats = NodeStats(self, "ntcr_recon: mesh")
        self._newest = None  # the newest relocated cloud message not yet meshed
        self._centerlines: dict[int, bytes] = {}  # the last few centrelines received, by stamp, serialized
        self._last_centerline_ns: int | None = None
        self.meshes = 0
        self._marker = self.create_publisher(Marker, stage_topic(self.rig.topics, "mesh"), LATCHED_QOS)
        self._raw = self.create_publisher(Mesh, stage_topic(self.rig.topics, "mesh/raw"), LATCHED_QOS)
        self._newest_raw: bytes | None = None
        self.create_subscription(PointCloud2, stage_topic(self.rig.topics, "relocated/points"), self._on_cloud,
                                 STAGE_INPUT_QOS, raw=True)
        self.create_subscription(Path, stage_topic(self.rig.topics, "centerline"), self._on_centerline,
                                 STAGE_INPUT_QOS, raw=True)
        self.get_logger().info(f"meshing relocated clouds at {self._params['rate']} Hz")

    def configure(self, rig, params: dict) -> None:
        save, output = params["save_ply_path"], params["output_dir"]
        if save and not PathLib(save).expanduser().parent.is_dir():
            raise ParameterError(f"parameter 'save_ply_path': the folder of {save!r} does not exist")
        if save and PathLib(save).suffix.lower() not in (".ply", ".stl"):
            raise ParameterError(f"parameter 'save_ply_path' must end in .ply (or .stl), got {save!r}")
        if output and not PathLib(output).expanduser().is_dir():
            raise ParameterError(f"parameter 'output_dir': {output!r} is not an existing folder")
        save_requested = params["save_ply_path"] and params["save_ply_path"] != self._params["save_ply_path"]
        rate_changed = self._timer is None or params["rate"] != self._params["rate"]
        self.rig, self._params = rig, params
        if save_requested:
            self._pending_save = PathLib(params["save_ply_path"]).expanduser()
            self._save_pending()
        if rate_changed:
            if self._timer is not None:
                self.destroy_timer(self._timer)
            self._timer = self.create_timer(1.0 / params["rate"], self._tick)

    # Both inputs arrive at the relocation's rate (~30 Hz) but only the newest is meshed, at `rate` (~1 Hz): they
    # are kept serialized and decoded when a tick uses them (a Path of 120 PoseStamped objects and a cloud's
    # conversion at 30 Hz cost more than the meshing itself).
    @guarded
    def _on_cloud(self, raw: bytes) -> None:
        self.stats.received()
        # sized here, not at the tick: a cloud replaced by the next before the tick was never looked at, an
        # oversized one then neither logged nor counted (issue 66)
        check_point_count(raw, self._params["max_points"])
        self._newest_raw = raw

    @guarded
    def _on_centerline(self, raw: bytes) -> None:
        """Kept in the order they arrive, the oldest arrival leaving first: kept by highest stamp, four clouds
        stamped in the future (a wrong clock, a replay looping, sim time starting) held the node's only places
        for good and no later cloud found its centreline (issue 66). A jump back of the stamps starts afresh,
        as fusion's pairing does; a jump forward ages out after CENTERLINES_KEPT arrivals."""
        stamp = cdr.header_stamp_ns(raw)
        previous, self._last_centerline_ns = self._last_centerline_ns, stamp
        if previous is not None and stamp < previous - STAMP_JUMP_NS:
            self.get_logger().warning(f"centreline stamps jumped back by {(previous - stamp) / 1e9:.3f} s: "
                                      "matching clouds to centrelines starts afresh")
            self._centerlines.clear()
        self._centerlines.pop(stamp, None)  # a repeated stamp counts as the newest arrival
        self._centerlines[stamp] = raw
        while len(self._centerlines) > CENTERLINES_KEPT:
            del self._centerlines[next(iter(self._centerlines))]

    def _take_newest(self) -> None:
        """Decode and check the newest cloud (a bad one is logged by cause, counted and dropped)."""
        raw, self._newest_raw = self._newest_raw, None
        try:
            msg = decode(raw, PointCloud2, "relocated cloud")  # its size was checked as it came (_on_cloud)
            _, normals = stage_cloud_and_normals(msg, self.rig.base_frame, self.rig)  # refuse a bad cloud by name
            if normals is None:
                raise ValueError("relocated cloud has no normal_x/normal_y/normal_z fields (is it relocation_node's?)")
        except ValueError as error:
            self.stats.dropped(getattr(error, "reason", "invalid"), str(error))
            return
        self._newest = msg

    @guarded  # a defect met while meshing is dropped and counted: the timer must not take the node down
    def _tick(self) -> None:
        if self._newest_raw is not None:
            self._take_newest()
        if self._newest is None:
            return
        stamp = stamp_to_ns(self._newest.header.stamp)
        centerline = self._centerlines.get(stamp)
        if centerline is None:
            return  # its centreline is on the way (published right after the cloud)
        msg, self._newest = self._newest, None  # consumed first: a bad pair is not retried every tick
        centerline = decode(centerline, Path, "centreline")
        started = time.perf_counter()
        try:
            relocation = relocation_from_msgs(msg, centerline, self.rig.base_frame, self.rig)
            mesh = mesh_relocation(relocation, self.rig)
        except (ValueError, RuntimeError) as error:
            self.stats.dropped("no_mesh", f"no mesh from the relocated cloud at {stamp} ns: {error}")
            return
        vertices, triangles = np.asarray(mesh.vertices, float), np.asarray(mesh.triangles, np.int64)
        self._mesh = (mesh, stamp)
        # serialized from the arrays: a Point object per corner cost tens of ms a mesh
        self._marker.publish(mesh_marker_bytes(vertices, triangles, self.rig.base_frame, stamp))
        self._raw.publish(mesh_msg_bytes(vertices, triangles))
        self.meshes += 1
        self.stats.published(stamp, started)
        if self._params["output_dir"]:
            self._write(PathLib(self._params["output_dir"]).expanduser() / "mesh.ply")
        self._save_pending()

    def _save_pending(self) -> None:
        if self._pending_save is not None and self._mesh is not None:
            path, self._pending_save = self._pending_save, None
            self._write(path)

    def _write(self, path: PathLib) -> None:
        mesh, stamp = self._mesh
        try:
            write_mesh(path, mesh)
        except (OSError, ValueError) as error:
            self.get_logger().error(f"could not write the mesh to {path}: {error}")
            return
        self.get_logger().info(f"wrote the mesh of {stamp} ns ({len(mesh.vertices)} vertices, "
                               f"{len(mesh.triangles)} triangles) to {path}")


def main(args: list[str] | None = None) -> int:
    return run_node(MeshNode, args)


if __name__ == "__main__":
    sys.exit(main())
