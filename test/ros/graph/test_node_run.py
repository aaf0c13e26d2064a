"""run_node (ros/node_support.py): a take interrupted by Ctrl-C (a SIGINT, or the context's shutdown) is a clean
stop, while the same error with the context still up is a bug that is reported;
nodes spin on the EventsExecutor where rclpy has it."""

from __future__ import annotations

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import os, signal, sys, threading, time
    import rclpy
    from rclpy.node import Node
    from ntcr_recon.ros.node_support import make_executor, run_node

    SHUT_DOWN = sys.argv[1] == "shutdown"

    class Interrupted(Node):
        def __init__(self):
            super().__init__("interrupted")
            self.create_timer(0.1, self.tick)
            print(type(make_executor()).__name__, flush=True)

        def tick(self):
            if sys.argv[1] == "sigint":  # a real Ctrl-C: the node's own SIGINT handler runs before the raise
                os.kill(os.getpid(), signal.SIGINT)
            if SHUT_DOWN:  # what Ctrl-C does: the context goes down while a take is under way
                threading.Thread(target=lambda: (time.sleep(0.2), rclpy.shutdown())).start()
            # what rclpy raises from take_message when the subscription's handle went away under it
            raise RuntimeError("Unable to convert call argument '0' to Python object")

    sys.exit(run_node(Interrupted))
""")


def run(mode: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=60)


def test_a_take_interrupted_by_the_shutdown_is_a_clean_stop():
    result = run("shutdown")
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr, result.stderr


def test_a_take_interrupted_by_a_real_sigint_is_a_clean_stop():
    # review: with SignalHandlerOptions.NO a Ctrl-C never shuts the context down, so the interrupted take was
    # reported as a bug after a real Ctrl-C; the stop it asked for now makes it a clean stop
    result = run("sigint")
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr, result.stderr


def test_the_same_error_without_a_shutdown_is_reported():
    result = run("no-shutdown")
    assert result.returncode != 0
    assert "Unable to convert call argument" in result.stderr


def test_nodes_spin_on_the_events_executor():
    assert run("shutdown").stdout.split()[0] == "EventsExecutor"
