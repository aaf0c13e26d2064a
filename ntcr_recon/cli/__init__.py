"""The `ntcr-recon` command: every subcommand listed here, each in its own module of this package
(`cli/<subcommand>.py`, exposing `add_arguments(parser)` and `main(args) -> int`). A subcommand's module is
imported only when it runs, so `ntcr-recon --help` is quick and a subcommand's heavy imports (open3d,
rclpy) cost only its own users.

Ctrl-C ends a subcommand at once with one line, "ntcr-recon <subcommand>: interrupted", and exit status 130,
wherever it comes: not a KeyboardInterrupt raised into the middle of a native call (a KD-tree query on a
thread pool crashed the process with a segfault, an open3d import half done failed with ImportError), but a
handler that ends the process there. Nothing is lost by it: outputs are built in a staging directory and
swapped in by one rename (io.staging, which holds Ctrl-C back for that instant), so --out keeps its old
contents, and the staging directory is removed. `run` installs its own handler, which
stops the graph's nodes in order."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading

# subcommand (= its module, ntcr_recon.cli.<subcommand>) -> one-line help
SUBCOMMANDS = {
    "simulate": "render a synthetic dual-D405 scene into a rosbag2 bag",
    "render": "draw a bag's depth frame and raw fused cloud as a PNG",
    "reconstruct": "turn a bag into a mesh, a relocated cloud, metrics and figures",
    "calibrate": "estimate both cameras' poses from bags of the robot, straight and bent, into a rig file",
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


INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command Ctrl-C ended
# Set once Ctrl-C came: the interrupt thread ends the process. What the main thread meets meanwhile (its staging
# directory removed under it: a file not found) is neither reported nor its exit status (main holds it).
INTERRUPTING = threading.Event()


def exit_on_interrupt(command: str) -> None:
    """From now on Ctrl-C ends the process with one line and exit status 130, at once: SIGINT is blocked in
    every thread (those started later inherit the mask) and a thread of its own waits for it, so it is neither
    raised into a native call nor held back until one returns. The thread waits for io.staging's swap of a
    result to end first."""
    from ntcr_recon.io.staging import SWAP_LOCK, remove_active_staging

    def wait() -> None:
        signal.sigwait({signal.SIGINT})
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - the process ends here; this thread writes to fd 2
        INTERRUPTING.set()
        SWAP_LOCK.acquire()  # never released: the process ends here
        remove_active_staging()  # what this run had written so far; --out keeps what it held
        os.write(2, f"\nntcr-recon {command}: interrupted\n".encode())
        os._exit(INTERRUPTED)

    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    threading.Thread(target=wait, name="ntcr-interrupt", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    """The console script (argv None: the process's own command line, Ctrl-C handled as above; `run` keeps its
    own handler, which stops the graph's nodes in order) or a call with `argv` (Ctrl-C left to the caller)."""
    process = argv is None
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((arg for arg in argv if not arg.startswith("-")), None)
    if not (process and chosen in SUBCOMMANDS and chosen != "run"):
        return _main(argv)
    try:
        exit_on_interrupt(chosen)
        return _main(argv)
    except KeyboardInterrupt:  # one that came before the handling above was in place
        print(f"ntcr-recon {chosen}: interrupted", file=sys.stderr)
        return INTERRUPTED
    finally:
        if INTERRUPTING.is_set():  # the interrupt thread ends the process with 130; no other status may
            threading.Event().wait()


def _main(argv: list[str]) -> int:
    parser, parsers = build_parser()
    # Only the chosen subcommand's module is imported to add its arguments.
    chosen = next((arg for arg in argv if not arg.startswith("-")), None)
    module = None
    if chosen in SUBCOMMANDS:
        module = importlib.import_module(f"{__name__}.{chosen}")
        module.add_arguments(parsers[chosen])
    args = parser.parse_args(argv)
    return int(module.main(args) or 0)
