"""The `ntcr-recon` command. Each subcommand lives in its own module, imported only when it runs, so
`ntcr-recon --help` is quick and a subcommand's heavy imports (open3d, rclpy) cost only its own users."""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand -> (module exposing add_arguments(parser) and main(args) -> int, one-line help)
SUBCOMMANDS = {
    "simulate": ("ntcr_recon.sim.simulate_cli", "render a synthetic dual-D405 scene into a rosbag2 bag"),
    "render": ("ntcr_recon.sim.render_cli", "draw a bag's depth frame and raw fused cloud as a PNG"),
    "reconstruct": ("ntcr_recon.reconstruct", "turn a bag into a mesh, a relocated cloud, metrics and figures"),
    "run": ("ntcr_recon.ros.graph", "start the ROS 2 graph (every node in its own process)"),
}


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    parser = argparse.ArgumentParser(
        prog="ntcr-recon",
        description="3-D morphology of notched tubular continuum robots from two opposed D405 cameras.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    parsers = {name: subparsers.add_parser(name, help=help_text, description=help_text)
               for name, (_, help_text) in SUBCOMMANDS.items()}
    return parser, parsers


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser, parsers = build_parser()
    # Only the chosen subcommand's module is imported to add its arguments.
    chosen = next((arg for arg in argv if not arg.startswith("-")), None)
    module = None
    if chosen in SUBCOMMANDS:
        module = importlib.import_module(SUBCOMMANDS[chosen][0])
        module.add_arguments(parsers[chosen])
    args = parser.parse_args(argv)
    return int(module.main(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
