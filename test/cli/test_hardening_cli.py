"""Issue 66, the command line: what cannot fit is refused before it starts, a full disk or an --out that cannot
be written is named as --out, bad arguments are refused by name (exit 2), Ctrl-C is one line and exit 130."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support import BAGS

from ntcr_recon.cli import main
from ntcr_recon.io import files, staging

BAG = BAGS / "bend45"


def run(capsys, *argv: str) -> tuple[int, str]:
    try:
        code = main(list(argv))
    except SystemExit as stop:  # argparse refusing an argument
        code = stop.code
    return code, capsys.readouterr().err


def leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


# ---- simulate -------------------------------------------------------------------------------------------------

def test_simulate_refuses_a_million_frames_naming_the_size_and_the_free_space(capsys, tmp_path):
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), "--frames", "1000000", "--no-progress")
    assert code == 2
    assert "--frames 1000000" in err and "TB" in err and "free" in err
    assert not (tmp_path / "bag").exists()


def test_simulate_refuses_a_bag_larger_than_the_free_space(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "disk_usage", lambda _: shutil._ntuple_diskusage(10**9, 10**9 - 5 * 10**6, 5 * 10**6))
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), "--frames", "3", "--no-progress")
    assert code == 2 and "12.2 MB" in err and "5.0 MB free" in err
    assert list(tmp_path.iterdir()) == []


def test_simulate_refuses_intrinsics_it_cannot_render_before_allocating(capsys, tmp_path):
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), "--intrinsics", "40000,40000,20000,20000,20000,20000")
    assert code == 2 and "--intrinsics" in err and "4096" in err
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), "--intrinsics", "848,480,0,421,428,238")
    assert code == 2 and "focal" in err


@pytest.mark.parametrize("option, expected", [
    (["--depth-unit", "0"], "cam_a.depth_unit must be > 0"),  # wrote a bag whose rig.yaml no reader accepts
    (["--camera-distance", "1e6"], "cam_a.translation must lie in"),
    (["--color-noise", "inf"], "colour noise must be finite"),
    (["--seed", "-1"], "--seed -1"),
])
def test_simulate_refuses_what_the_rig_schema_refuses_before_rendering(capsys, tmp_path, option, expected):
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), *option, "--no-progress")
    assert code == 2 and expected in err
    assert list(tmp_path.iterdir()) == []


def test_simulate_into_a_full_disk_names_the_bag_and_leaves_nothing(capsys, tmp_path, monkeypatch):
    from ntcr_recon.sim import bag

    original, calls = bag.Writer.write, []

    def full(self, *args):
        calls.append(1)
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return original(self, *args)

    monkeypatch.setattr(bag.Writer, "write", full)
    code, err = run(capsys, "simulate", str(tmp_path / "bag"), "--frames", "2", "--no-progress")
    assert code == 2, err
    assert f"writing {tmp_path / 'bag'}" in err and "No space left on device" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# ---- reconstruct: arguments and --out ----------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["0", "-3"])
def test_reconstruct_refuses_max_frames_below_one(capsys, tmp_path, value):
    code, err = run(capsys, "reconstruct", str(BAG), "--out", str(tmp_path / "out"), "--max-frames", value)
    assert code == 2 and "--max-frames" in err and "at least 1" in err


@pytest.mark.parametrize("item, expected", [
    ("cam_z.depth=/x", "no camera 'cam_z'"),
    ("cam_a.dept=/x", "got 'dept'"),
    ("/ntcr/cam_z/depth/image_rect_raw=/x", "reads no topic /ntcr/cam_z/depth/image_rect_raw"),
])
def test_reconstruct_refuses_a_topic_remap_the_rig_has_no_place_for(capsys, tmp_path, item, expected):
    code, err = run(capsys, "reconstruct", str(BAG), "--out", str(tmp_path / "out"), "--topic", item,
                    "--no-progress")
    assert code == 2 and expected in err
    assert list(tmp_path.iterdir()) == []


def test_reconstruct_into_a_full_disk_names_out_and_leaves_it_as_it_was(capsys, tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").write_text("previous")
    original = files.write_atomically

    def full(path, write):
        def failing(temp):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a write() into a full disk: no file name
        original(path, failing)

    monkeypatch.setattr(files, "write_atomically", full)
    code, err = run(capsys, "reconstruct", str(BAG), "--out", str(out), "--max-frames", "1", "--no-progress")
    assert code == 2, err
    assert f"--out {out}" in err and "relocated.ply" in err and "no space left" in err and ".partial-" not in err
    assert [p.name for p in out.iterdir()] == ["result.json"] and (out / "result.json").read_text() == "previous"
    assert leftovers(tmp_path) == []


def test_an_out_whose_staging_cannot_be_made_is_named_as_out(capsys, tmp_path, monkeypatch):
    def read_only(**kwargs):
        path = Path(kwargs["dir"]) / (kwargs["prefix"] + "x")
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(staging.tempfile, "mkdtemp", read_only)
    code, err = run(capsys, "reconstruct", str(BAG), "--out", str(tmp_path / "out"), "--no-progress")
    assert code == 2 and f"{tmp_path / 'out'} cannot be written: Read-only file system" in err
    assert ".partial-" not in err


def test_a_bind_mount_point_is_seen_as_one(tmp_path):
    # os.path.ismount misses a bind mount of a folder of the same file system; the final rename then failed
    # after the whole computation
    target = tmp_path / "my out"
    target.mkdir()
    mountinfo = tmp_path / "mountinfo"
    escaped = str(target.resolve()).replace(" ", "\\040")
    mountinfo.write_text(f"36 35 98:0 /mnt1 {escaped} rw,noatime master:1 - ext3 /dev/root rw\n")
    assert staging.is_mount_point(target, mountinfo)
    assert not staging.is_mount_point(tmp_path, mountinfo)


# ---- Ctrl-C -----------------------------------------------------------------------------------------------------

def test_ctrl_c_during_reconstruct_is_one_line_and_exit_130_whenever_it_comes(tmp_path):
    # issue 66: a traceback every time, exit 139 (a segfault in a KD-tree query on a thread pool) in 2 of 10 runs
    # and an open3d ImportError in one
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").write_text("previous")
    command = [sys.executable, "-m", "ntcr_recon.cli", "reconstruct", str(BAG), "--out"]
    # Ctrl-C at shares of a whole run timed here first (3.3 s idle; once in CI a run ended before a fixed 3 s):
    # in the imports, the reading, the frames and the writing
    started = time.perf_counter()
    subprocess.run(command + [str(tmp_path / "whole")], capture_output=True, check=True, timeout=120)
    whole = time.perf_counter() - started
    interrupted = 0
    for moment in (0.4, *(share * whole for share in (0.2, 0.35, 0.5, 0.65, 0.8))):
        process = subprocess.Popen(command + [str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(moment)
        if process.poll() is not None:
            break  # done already: the machine got faster than the whole run measured
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=60)
        if process.returncode == 0:
            break
        assert process.returncode == 130, (moment, err)
        assert "Traceback" not in err and err.strip().splitlines()[-1] == "ntcr-recon reconstruct: interrupted"
        assert (out / "result.json").read_text() == "previous" and leftovers(tmp_path) == []
        interrupted += 1
    assert interrupted >= 4


def test_ctrl_c_while_the_command_meets_an_error_still_ends_with_one_line_and_130():
    # CI: Ctrl-C as the outputs were written; the interrupt thread removed the staging directory, the main thread
    # met a file not found there, reported it and exited 2 before the interrupt thread ended the process
    probe = (
        "import os, signal, sys\n"
        "from ntcr_recon import cli\n"
        "def failing(argv):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    assert cli.INTERRUPTING.wait(10)\n"
        "    print('ntcr-recon reconstruct: --out x: could not write: No such file or directory', file=sys.stderr)\n"
        "    return 2\n"
        "cli._main = failing\n"
        "sys.argv = ['ntcr-recon', 'reconstruct', 'x']\n"
        "sys.exit(cli.main())\n")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert result.returncode == 130, result.stderr
    assert result.stderr.strip().splitlines() == ["ntcr-recon reconstruct: interrupted"]
