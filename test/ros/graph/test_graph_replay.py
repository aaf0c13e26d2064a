"""End to end: the sample bag bend45 replayed through all five nodes by `ntcr-recon run` (each node its own
process, the bag's clock driving the graph). The relocated clouds and notches equal what the core pipeline
computes on the same frames, and what `ntcr-recon reconstruct` reports for the first frame; a mesh arrives
(transient-local: subscribed late) and is written to the output folder; Ctrl-C stops every process cleanly."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from scipy.spatial import cKDTree
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from std_msgs.msg import Float64MultiArray
from support import BAGS, tiny_rig
from support.ros_graph import RosGraph, frame_statuses
from support.stage_probe import COLLECT_RELIABLE, ply_face_count
from visualization_msgs.msg import Marker

from ntcr_recon.core.cloud.fusion import FramePair
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.core.reconstruction.reconstructor import Reconstructor
from ntcr_recon.io.camera_sources import BagSource
from ntcr_recon.io.pointcloud import stamp_to_ns
from ntcr_recon.ros.messages import stage_cloud_and_normals
from ntcr_recon.ros.node_support import LATCHED_QOS
from ntcr_recon.ros.result_messages import mesh_from_msg, notches_from_array

BAG = BAGS / "bend45"
RUN = Path(sys.executable).parent / "ntcr-recon"
OUTPUTS = 6  # relocated frames collected (the 4-frame bag loops)


def children_of(pid: int) -> list[int]:
    result = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    return [int(p) for p in result.stdout.split()]


@pytest.fixture(scope="module")
def reference():
    """The core on the bag's frame pairs (paired by the core's bag reader), each frame on its own, keyed by
    the stamp's offset within one pass of the bag (the replay loops)."""
    config = load_rig_config(BAG / "rig.yaml")
    pairs = tiny_rig.bag_frame_pairs(BAG, config)
    reconstructor = Reconstructor(config)
    results = {}
    # Each pair, and each of its frames alone: on 2 cores a camera node can fall behind by more than the
    # camera timeout, and fusion_node then publishes the other camera's frame alone, as it should.
    frames = list(pairs)
    frames += [FramePair(frame.stamp_ns, {name: frame}) for pair in pairs for name, frame in pair.frames.items()]
    for frames_of in frames:
        reconstructor.reset()  # no state from the previous frame (centreline, region of interest)
        filtered = reconstructor.filter(reconstructor.fuse(frames_of))
        cameras = tuple(sorted(config.camera_names.index(name) for name in frames_of.frames))
        results[frames_of.stamp_ns - pairs[0].stamp_ns, cameras] = reconstructor.relocate(filtered,
                                                                                           warm_start=False)
    loop_shift = BagSource(BAG, config.camera_names[0], config.topics).loop_shift_ns  # as camera_node loops
    return config, results, pairs[0].stamp_ns, loop_shift


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory):
    """`ntcr-recon reconstruct` on the bag's first frame pair: its result.json and relocated cloud."""
    out = tmp_path_factory.mktemp("reconstruct")
    subprocess.run([str(RUN), "reconstruct", str(BAG), "--max-frames", "1", "--out", str(out), "--no-progress"],
                   check=True, capture_output=True, timeout=120)
    return json.loads((out / "result.json").read_text()), read_ply_points(out / "relocated.ply")


def read_ply_points(path: Path) -> np.ndarray:
    """x, y, z of a binary little-endian PLY of float32 vertex properties (and uchar colours)."""
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    lines = header.decode("ascii").splitlines()
    count = int(next(line.split()[2] for line in lines if line.startswith("element vertex")))
    types = {"float": "<f4", "uchar": "u1"}
    properties = [(line.split()[2], types[line.split()[1]]) for line in lines if line.startswith("property")]
    vertices = np.frombuffer(body, dtype=np.dtype(properties), count=count)
    return np.stack([vertices[axis] for axis in "xyz"], axis=1).astype(float)


@pytest.fixture(scope="module")
def replay(reference, tmp_path_factory):
    output = tmp_path_factory.mktemp("replay")
    with RosGraph() as graph:
        out = {name: [] for name in ("relocated", "notches", "tip", "centerline", "mesh", "mesh_raw", "diagnostics")}
        graph.node.create_subscription(DiagnosticArray, "/diagnostics", out["diagnostics"].append, COLLECT_RELIABLE)
        graph.node.create_subscription(PathMsg, "/ntcr/centerline", out["centerline"].append, COLLECT_RELIABLE)
        graph.node.create_subscription(PoseStamped, "/ntcr/tip", out["tip"].append, COLLECT_RELIABLE)
        graph.node.create_subscription(PointCloud2, "/ntcr/relocated/points", out["relocated"].append,
                                       COLLECT_RELIABLE)
        graph.node.create_subscription(Float64MultiArray, "/ntcr/notches", out["notches"].append, COLLECT_RELIABLE)
        log_path = output / "run.log"
        with log_path.open("w") as log:
            # Relocation per frame (no warm start) so every output can be compared with the core exactly,
            # whichever frames the graph had to skip; a quarter of the recorded rate suits 2 cores.
            process = subprocess.Popen(
                [str(RUN), "run", "--config", str(BAG / "rig.yaml"), "--bag", str(BAG), "--loop", "--rate", "0.25",
                 "--use-sim-time", "--output", str(output), "--param", "relocation_node:warm_start:=false",
                 "--param", "mesh_node:rate:=5.0"], env=graph.env, stdout=log, stderr=subprocess.STDOUT)
            try:
                _, _, first, loop_shift = reference

                # OUTPUTS frames placed with their colour windows and one more, the bag's first pair among them
                # (not a camera's alone): a frame placed without a window is left out (placed_with_their_windows)
                def enough() -> bool:
                    collected = min(len(out["relocated"]), len(out["notches"]))
                    placed = placed_with_their_windows(out)
                    return collected >= OUTPUTS + 1 and len([i for i in placed if i < collected]) >= OUTPUTS and any(
                        (stamp_to_ns(m.header.stamp) - first) % loop_shift == 0 and both_cameras(m, reference[0])
                        for m in out["relocated"])

                assert graph.spin_until(enough, 90), log_path.read_text()
                # Subscribed late on purpose: transient-local QoS still hands over the newest mesh.
                graph.node.create_subscription(Marker, "/ntcr/mesh", out["mesh"].append, LATCHED_QOS)
                graph.node.create_subscription(Mesh, "/ntcr/mesh/raw", out["mesh_raw"].append, LATCHED_QOS)
                graph.spin_until(lambda: same_mesh(out) is not None and (output / "mesh.ply").exists(), 60)
                children = children_of(process.pid)
                process.send_signal(signal.SIGINT)
                exit_code = process.wait(timeout=30)
            finally:
                if process.poll() is None:
                    process.kill()
        yield out, output, exit_code, children, log_path.read_text()


def both_cameras(cloud_msg, config) -> bool:
    """Whether a relocated cloud holds every camera's points (a pair's, not a frame fusion published alone)."""
    cloud = stage_cloud_and_normals(cloud_msg, config.base_frame)[0]
    return len(np.unique(cloud.camera)) == len(config.camera_names)


def placed_with_their_windows(out: dict) -> list[int]:
    """The indices of the relocated frames relocation_node placed with the colour window of every camera in the
    cloud: the frame's own /diagnostics carry no COLOUR_VIEW_MISSING. One whose window came after its wait (a loaded
    machine, as the node's log also says), or before the node matched camera_node's publisher, is placed by depth
    alone in that view and is not the core's frame: the core read the windows."""
    codes = frame_codes(out["diagnostics"])
    return [i for i, m in enumerate(out["relocated"])
            if (stamp := stamp_to_ns(m.header.stamp)) in codes and "COLOUR_VIEW_MISSING" not in codes[stamp]]


def frame_codes(diagnostics: list) -> dict[int, set[str]]:
    """Per frame (its stamp, ns) the codes of relocation_node's result, from its /diagnostics."""
    statuses = frame_statuses(status for array in diagnostics for status in array.status)
    return {stamp: set(filter(None, values.get("codes", "").split(","))) for stamp, (_, values) in statuses.items()}


def compared_frames(replay) -> list[int]:
    """The first OUTPUTS of placed_with_their_windows."""
    kept = placed_with_their_windows(replay[0])
    assert len(kept) >= OUTPUTS, f"{len(replay[0]['relocated']) - len(kept)} frames placed without a window"
    return kept[:OUTPUTS]


def test_relocated_clouds_and_notches_match_the_core(reference, replay):
    config, by_offset, first, loop_span = reference
    out, *_ = replay
    # relocation_node publishes cloud and notches of a frame together, in order; both reliable.
    for index in compared_frames(replay):
        cloud_msg, notch_msg = out["relocated"][index], out["notches"][index]
        cloud, normals = stage_cloud_and_normals(cloud_msg, config.base_frame)
        cameras = tuple(int(c) for c in np.unique(cloud.camera))
        expected = by_offset[(stamp_to_ns(cloud_msg.header.stamp) - first) % loop_span, cameras]
        # Same core, same frames; the only difference is float32 on the wire between the stages (the stage
        # clouds' fields are float32, ntcr_recon/ros/messages.py).
        assert abs(len(cloud) - len(expected.relocated)) <= 0.005 * len(expected.relocated)
        distance = cKDTree(expected.relocated.xyz).query(cloud.xyz)[0]
        print(f"relocated {len(cloud)} points (core {len(expected.relocated)}), distance to the core's: median "
              f"{np.median(distance) * 1e6:.2f} um, 99th percentile {np.percentile(distance, 99) * 1e6:.2f} um")
        # Float32 rounding moves a few points a little more (an iterative fit amplifies 0.01 um: one of the bag's
        # frames, when the graph's timing hands it on, lands at a 1.3 um median); a different computation would
        # move them all (a pixel footprint is ~200 um here).
        assert np.median(distance) < 5e-6 and np.percentile(distance, 99) < 30e-6
        notches = notches_from_array(notch_msg)
        assert [n["index"] for n in notches] == [n.index for n in expected.notches]
        if len(cameras) == len(config.camera_names):
            assert len(notches) == config.robot.notch_count
        center_errors = [abs(a["center_s"] - b.center_s) for a, b in zip(notches, expected.notches, strict=True)]
        width_errors = [abs(a["width"] - b.width) for a, b in zip(notches, expected.notches, strict=True)]
        print(f"notches: centre within {max(center_errors) * 1e6:.2f} um, width within "
              f"{max(width_errors) * 1e6:.2f} um (medians {np.median(center_errors) * 1e6:.2f}, "
              f"{np.median(width_errors) * 1e6:.2f} um)")
        # The same computation gives the same notches, but notch positions are resolved on the coverage
        # profile's samples (an eighth of a pixel footprint, ~26 um here): the float32 rounding on the wire (a
        # few nm) can tip the comb, or one edge, to the neighbouring sample. So: within about one sample for the
        # centres and two for the widths over a frame's notches, and no notch beyond the width floor.
        assert np.median(center_errors) < 40e-6 and np.median(width_errors) < 75e-6
        assert max(center_errors) < 150e-6 and max(width_errors) < 150e-6


def test_the_tip_is_placed_with_the_edge_band_camera_node_measured(reference, replay):
    """relocation_node sees clouds only; camera_node measures each camera's edge band on the depth images and
    hands it on (`<ns>/<cam>/edge_band`), so the graph's tip is the core's, which read the same images."""
    config, by_offset, first, loop_span = reference
    out, *_ = replay
    tips = {stamp_to_ns(m.header.stamp): m.pose.position for m in out["tip"]}
    compared = 0
    for cloud_msg in (out["relocated"][index] for index in compared_frames(replay)):
        stamp = stamp_to_ns(cloud_msg.header.stamp)
        cloud, _ = stage_cloud_and_normals(cloud_msg, config.base_frame)
        expected = by_offset[(stamp - first) % loop_span, tuple(int(c) for c in np.unique(cloud.camera))]
        assert expected.quality["tip_refinement"].startswith("half-density end + edge band")
        got = np.array([tips[stamp].x, tips[stamp].y, tips[stamp].z])
        # the end is where a density profile sampled every eighth of a pixel footprint crosses half its plateau:
        # the float32 rounding on the wire can move a point into the neighbouring sample, and the crossing by
        # up to a sample (the notches' centres above: the same)
        sample = expected.quality["pixel_footprint_mm"] * 1e-3 / 8
        print(f"tip {np.linalg.norm(got - expected.tip) * 1e6:.2f} um from the core's (a profile sample: "
              f"{sample * 1e6:.0f} um)")
        assert np.linalg.norm(got - expected.tip) < sample
        compared += 1
    assert compared == OUTPUTS


def test_the_centreline_is_the_cores_placed_by_the_same_limbs(reference, replay):
    """The axis across each camera's view is placed by the tube's limbs in that camera's colour window, which
    camera_node publishes beside its cloud and relocation_node waits for: the graph's centreline is the core's,
    which read the same images. Placed by depth alone in a view (a window lost or late), it moves by about
    `centerline_limbs.moved_mm`, tens of um. Once in CI a frame taken for placed with its windows lay 0.37 of the
    move from the core's (7.9 um of 21.5): most likely one camera's window was missing while discovery reported its
    publisher unmatched, which relocation_node then neither waited for nor named per frame (it now waits for a
    camera whose windows came lately, and such a frame says COLOUR_VIEW_MISSING and is left out here). Nearer the
    limbs' placement than half way to depth's tells the one from the other."""
    config, by_offset, first, loop_span = reference
    out, *_, log = replay
    late = [line for line in log.splitlines() if "colour window" in line]
    paths = {stamp_to_ns(m.header.stamp): m for m in out["centerline"]}
    compared = 0
    for cloud_msg in (out["relocated"][index] for index in compared_frames(replay)):
        stamp = stamp_to_ns(cloud_msg.header.stamp)
        cloud, _ = stage_cloud_and_normals(cloud_msg, config.base_frame)
        expected = by_offset[(stamp - first) % loop_span, tuple(int(c) for c in np.unique(cloud.camera))]
        got = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in paths[stamp].poses])
        moved = expected.quality["centerline_limbs"]["moved_mm"] * 1e-3
        off = np.max(np.linalg.norm(got - expected.centerline.points, axis=1))
        print(f"centreline {off * 1e6:.2f} um from the core's at most (the limbs moved it {moved * 1e6:.1f} um)")
        assert len(got) == len(expected.centerline.points) and moved > 5e-6 and off < moved / 2, late
        compared += 1
    assert compared == OUTPUTS


def test_the_first_frame_matches_ntcr_recon_reconstruct(reference, reconstructed, replay):
    """What the command-line reconstruction of the same (single) frame reports: its notches and cloud."""
    config, _, first, loop_shift = reference
    result, points = reconstructed
    out, *_ = replay
    clouds = [stage_cloud_and_normals(m, config.base_frame)[0] for m in out["relocated"]]
    index = next(i for i in placed_with_their_windows(replay[0])
                 if (stamp_to_ns(out["relocated"][i].header.stamp) - first) % loop_shift == 0
                 and both_cameras(out["relocated"][i], config))
    cloud = clouds[index]
    distance = cKDTree(points).query(cloud.xyz)[0]
    print(f"frame 0 vs ntcr-recon reconstruct: {len(cloud)} / {len(points)} points, median distance "
          f"{np.median(distance) * 1e6:.2f} um")
    assert abs(len(cloud) - len(points)) <= 0.005 * len(points) and np.median(distance) < 2e-6
    notches = notches_from_array(out["notches"][index])
    assert len(notches) == len(result["notches"]) == result["notch_count_expected"]
    # as above: the same notches, up to the comb or an edge tipped to a neighbouring profile sample
    center_errors = [abs(got["center_s"] * 1e3 - want["center_s_mm"]) for got, want in zip(notches, result["notches"],
                                                                                         strict=True)]
    width_errors = [abs(got["width"] * 1e3 - want["width_mm"]) for got, want in zip(notches, result["notches"],
                                                                                  strict=True)]
    assert np.median(center_errors) < 0.04 and np.median(width_errors) < 0.075
    assert max(center_errors) < 0.15 and max(width_errors) < 0.15


def same_mesh(out: dict):
    """The newest marker and raw mesh received of one mesh (a marker lists its triangles' corners), or None.
    The two topics are latched apart: a new mesh may be published between the handovers to a late subscriber."""
    return next(((marker, raw) for marker in reversed(out["mesh"]) for raw in reversed(out["mesh_raw"])
                 if len(marker.points) == 3 * len(raw.triangles)), None)


def test_a_mesh_arrives_and_is_written(replay):
    out, output, *_ = replay
    assert out["mesh"] and out["mesh_raw"], replay[4]
    pair = same_mesh(out)
    assert pair is not None, (len(out["mesh"][-1].points), [len(m.triangles) for m in out["mesh_raw"]])
    marker, raw = pair
    assert marker.type == Marker.TRIANGLE_LIST and marker.header.frame_id == "ntcr_base"
    vertices, triangles = mesh_from_msg(raw)
    assert len(triangles) > 1000
    # The mesh spans the robot: ~50 mm from base to tip of a 45-degree bend, about the tube's diameter across.
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    assert 0.03 < extent.max() < 0.07
    assert ply_face_count(output / "mesh.ply") > 1000
    assert (output / "relocated.ply").stat().st_size > 4000 * 12  # the newest relocated cloud beside it



def test_ctrl_c_stops_every_node(replay):
    _, _, exit_code, children, log = replay
    assert exit_code == 0, log
    assert len(children) == 6  # two camera nodes and four stages
    assert not [pid for pid in children if Path(f"/proc/{pid}").exists()]
    assert "Traceback" not in log, log
