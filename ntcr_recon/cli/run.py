"""`ntcr-recon run --config RIG.yaml [--bag BAG | --file CAM=PATH ...]`: the arguments of the graph runner.

Only the command line lives here; starting and supervising the node processes is ros/graph.py's job.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="rig configuration (ROS 2 parameter file)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--bag", type=Path, help="replay this rosbag2 bag through camera_node's bag source "
                                                 "(default: live cameras through the realsense source)")
    source.add_argument("--file", action="append", default=[], metavar="CAM=PATH",
                        help="play a librealsense recording for camera CAM (file source); once per camera")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="bag replay speed relative to the recorded rate, 0 = as fast as possible (default 1)")
    parser.add_argument("--loop", action="store_true", help="replay the bag or recordings again and again")
    parser.add_argument("--use-sim-time", action="store_true",
                        help="the bag's / recordings' stamps drive the graph's clock (/clock from the first "
                             "camera_node)")
    parser.add_argument("--output", type=Path, help="folder where the graph leaves the newest mesh.ply (mesh_node) "
                                                    "and relocated.ply (relocation_node)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: run until "
                                                                     "Ctrl-C)")
    parser.add_argument("--no-mesh", action="store_true", help="leave out mesh_node")
    parser.add_argument("--param", action="append", default=[], metavar="NODE:NAME:=VALUE",
                        help="extra parameter for one node (e.g. mesh_node:rate:=0.5); repeatable")
    parser.add_argument("--single-process", action="store_true",
                        help="host every node in one process on one executor (default: a process per node)")
    parser.add_argument("--no-respawn", action="store_true",
                        help="stop the graph when a node dies (default: start it again after a backoff)")


def main(args: argparse.Namespace) -> int:
    from ntcr_recon.ros import graph  # imported when `run` runs, so the other subcommands never load ros/

    return graph.main(args)
