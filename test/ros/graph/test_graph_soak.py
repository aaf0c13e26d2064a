"""Soak: the whole graph (`ntcr-recon run`) fed at the recorded 30 Hz for at least 60 s of bag time (bags/bend45
looping). Each node's resident size at the start and the end is printed and must stay flat; the output rates
are printed; the graph keeps no backlog (what a stage cannot take is dropped by its keep-last QoS, so the lag
of the relocated output behind the bag's clock stays bounded instead of growing)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2
from support import REPO
from support.ros_graph import RosGraph
from support.stage_probe import COLLECT_RELIABLE

from ntcr_recon.io.pointcloud import stamp_to_ns

BAG = REPO / "bags" / "bend45"
RUN = Path(sys.executable).parent / "ntcr-recon"
BAG_SECONDS = 60.0
WARM_UP_S = 5.0


def resident_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for {pid}")


def node_processes(run_pid: int) -> dict[str, int]:
    """Child pid -> node name (from its `-r __node:=<name>` argument)."""
    pids = [int(p) for p in subprocess.run(["pgrep", "-P", str(run_pid)], capture_output=True,
                                           text=True).stdout.split()]
    names = {}
    for pid in pids:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        names[next(a.decode().split(":=")[1] for a in argv if a.startswith(b"__node:="))] = pid
    return names


def test_graph_at_30_hz_for_60_s_of_bag_time_keeps_memory_flat_and_no_backlog(tmp_path):
    with RosGraph() as graph:
        clock = []      # bag time (ns) as the first camera_node publishes it
        relocated = []  # (bag time when received, output stamp)
        fusion_counts = []
        graph.node.create_subscription(Clock, "/clock", lambda m: clock.append(stamp_to_ns(m.clock)),
                                       QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        graph.node.create_subscription(
            PointCloud2, "/ntcr/relocated/points",
            lambda m: relocated.append((clock[-1] if clock else 0, stamp_to_ns(m.header.stamp))), COLLECT_RELIABLE)
        reports = {}  # newest /diagnostics values of every node
        graph.node.create_subscription(
            DiagnosticArray, "/diagnostics",
            lambda m: fusion_counts.extend({"stamp": stamp_to_ns(m.header.stamp), **{kv.key: kv.value for kv in
                                            s.values}} for s in m.status if s.name == "ntcr_recon: fusion"),
            COLLECT_RELIABLE)
        graph.node.create_subscription(
            DiagnosticArray, "/diagnostics",
            lambda m: reports.update({s.name: {kv.key: kv.value for kv in s.values} for s in m.status}),
            COLLECT_RELIABLE)
        log_path = tmp_path / "run.log"
        with log_path.open("w") as log:
            process = subprocess.Popen([str(RUN), "run", "--config", str(BAG / "rig.yaml"), "--bag", str(BAG),
                                        "--loop", "--rate", "1.0", "--use-sim-time", "--param", "mesh_node:rate:=1.0"],
                                       env=graph.env, stdout=log, stderr=subprocess.STDOUT)
            try:
                assert graph.spin_until(lambda: relocated, 60), log_path.read_text()
                graph.spin_until(lambda: False, WARM_UP_S)
                nodes = node_processes(process.pid)
                rss_start = {name: resident_mb(pid) for name, pid in nodes.items()}
                clock_start, outputs_start = clock[-1], len(relocated)
                counts_start = fusion_counts[-1] if fusion_counts else {}
                wall_start = time.monotonic()
                samples = []  # resident sizes once a second of wall time: a leak shows as a trend

                def done() -> bool:
                    if time.monotonic() - wall_start >= len(samples):
                        samples.append({name: resident_mb(pid) for name, pid in nodes.items()})
                    return (clock[-1] - clock_start) * 1e-9 >= BAG_SECONDS

                assert graph.spin_until(done, 120), log_path.read_text()
                wall = time.monotonic() - wall_start
                rss_end = {name: resident_mb(pid) for name, pid in nodes.items()}
                bag_time = (clock[-1] - clock_start) * 1e-9
                counts_end = fusion_counts[-1]
            finally:
                process.send_signal(signal.SIGINT)
                exit_code = process.wait(timeout=30)
    assert exit_code == 0, log_path.read_text()

    print(f"\nsoak: {bag_time:.1f} s of bag time in {wall:.1f} s of wall time (30 Hz recorded, replayed at rate 1)")
    half = len(samples) // 2
    peak_first = {name: max(sample[name] for sample in samples[:half]) for name in nodes}
    peak_second = {name: max(sample[name] for sample in samples[half:]) for name in nodes}
    for name in nodes:
        print(f"  {name:16s} resident {rss_start[name]:7.1f} MB at start, {rss_end[name]:7.1f} MB at end "
              f"({rss_end[name] - rss_start[name]:+.1f} MB); peak {peak_first[name]:.1f} MB in the first half, "
              f"{peak_second[name]:.1f} MB in the second")
    pairs = int(counts_end["pairs"]) - int(counts_start.get("pairs", 0))
    unpaired = int(counts_end["unpaired"]) - int(counts_start.get("unpaired", 0))
    superseded = int(counts_end["superseded"]) - int(counts_start.get("superseded", 0))
    outputs = relocated[outputs_start:]
    lags = np.array([(received - stamp) * 1e-9 for received, stamp in outputs])
    quarter = max(len(lags) // 4, 1)
    print(f"  fused pairs {pairs / bag_time:.1f} Hz (frames whose partner was lost: {unpaired}, pairs superseded by "
          f"a newer one: {superseded}), relocated output "
          f"{len(outputs) / bag_time:.1f} Hz; lag behind the bag clock: first quarter median "
          f"{np.median(lags[:quarter]):.3f} s, last quarter median {np.median(lags[-quarter:]):.3f} s, "
          f"max {lags.max():.3f} s")

    # use_sim_time: fusion_node's clock (its diagnostics' stamps, its 1 s timer) is the bag's, not the wall's.
    diagnostic_stamps = [int(c["stamp"]) for c in fusion_counts[-5:]]
    assert all(clock_start <= stamp <= clock[-1] + 2e9 for stamp in diagnostic_stamps), diagnostic_stamps
    for name in nodes:
        # Flat: bounded buffers fill and empty (a few frames of ~1 MB), but the second half never needs
        # more than the first did; a leak of even one cloud a second (~0.5 MB) would add ~15 MB.
        assert peak_second[name] <= peak_first[name] + 8.0, name
        assert rss_end[name] - rss_start[name] < 30.0, name
    assert len(outputs) >= bag_time  # at least 1 Hz of reconstructed robot
    # Every node says how it is doing: rates, drops, processing time (ros/node_stats.py).
    expected_reports = {"ntcr_recon: camera cam_a", "ntcr_recon: camera cam_b", "ntcr_recon: fusion",
                        "ntcr_recon: filter", "ntcr_recon: relocation", "ntcr_recon: mesh"}
    assert expected_reports <= set(reports), sorted(reports)
    for name in expected_reports:
        assert {"input_hz", "output_hz", "dropped", "processing_ms.p50"} <= set(reports[name]), (name, reports[name])
        assert int(reports[name]["outputs"]) > 0, (name, reports[name])
    stamps = [stamp for _, stamp in outputs]
    assert all(np.diff(stamps) > 0)  # newest first: no stale backlog replayed
    # Bounded lag: what the stages could not take was dropped, not queued.
    assert np.median(lags[-quarter:]) < np.median(lags[:quarter]) + 0.5 and lags.max() < 3.0
