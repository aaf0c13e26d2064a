"""The `ntcr-recon` command: every subcommand listed here, each in its own module of this package
(`cli/<subcommand>.py`, exposing `add_arguments(parser)` and `main(args) -> int`). A subcommand's module is
imported only when it runs, so `ntcr-recon --help` is quick and a subcommand's heavy imports (open3d,
rclpy) cost only its own users."""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand (= its module, ntcr_recon.cli.<subcommand>) -> one-line help
SUBCOMMANDS = {
    "simulate": "render a synthetic dual-D405 scene into a rosbag2 bag",
    "render": "draw a bag's depth frame and raw fused cloud as a PNG",
    "reconstruct": "turn a bag into a mesh, a relocated cloud, metrics and figures",
    "run": "start the ROS 2 graph (a process per node, or all in one with --single-process)",
}


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    parser = argparse.ArgumentParser(
        prog="ntcr-recon",
        description="3-D morphology of notched tubular continuum robots from two opposed D405 cameras.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    parsers = {name: subparsers.add_parser(name, help=help_text, description=help_text)
               for name, help_text in SUBCOMMANDS.items()}
    return parser, parsers


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser, parsers = build_parser()
    # Only the chosen subcommand's module is imported to add its arguments.
    chosen = next((arg for arg in argv if not arg.startswith("-")), None)
    module = None
    if chosen in SUBCOMMANDS:
        module = importlib.import_module(f"{__name__}.{chosen}")
        module.add_arguments(parsers[chosen])
    args = parser.parse_args(argv)
    return int(module.main(args) or 0)
