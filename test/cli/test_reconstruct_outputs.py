"""`ntcr-recon reconstruct`'s output directory, whole or not at all (issue 11): built beside the target, swapped
in by one rename, the old result whole after a failure in the final moves, staging left by a killed run
removed by the next one, `--out ""` refused."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ntcr_recon.cli import main as cli_main
from ntcr_recon.cli.reconstruct import OUTPUT_FILES
from ntcr_recon.io import staging
from ntcr_recon.io.staging import StagingError, remove_stale_staging, staged_directory


def _old_result(target: Path) -> Path:
    target.mkdir()
    (target / "result.json").write_text("old")
    (target / "mesh.ply").write_text("old mesh")
    return target


def _assert_old_result_whole(target: Path) -> None:
    assert sorted(p.name for p in target.iterdir()) == ["mesh.ply", "result.json"]
    assert (target / "result.json").read_text() == "old" and (target / "mesh.ply").read_text() == "old mesh"
    assert [p.name for p in target.parent.iterdir()] == [target.name]  # no staging left beside it


def test_the_new_directory_replaces_the_old_one_whole(tmp_path):
    target = _old_result(tmp_path / "res")
    with staged_directory(target) as new:
        assert new.parent == target.parent  # same file system: the swap is a rename
        (new / "result.json").write_text("new")
        _assert_old_result_whole_but_staging(target, new)
    assert [p.name for p in target.iterdir()] == ["result.json"]  # the old mesh.ply is not mixed in
    assert (target / "result.json").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["res"]


def _assert_old_result_whole_but_staging(target: Path, new: Path) -> None:
    assert (target / "result.json").read_text() == "old"
    assert sorted(p.name for p in target.parent.iterdir()) == sorted([target.name, new.name])


@pytest.mark.parametrize("atomic_exchange", [True, False], ids=["renameat2-exchange", "rename-aside"])
def test_a_failure_during_the_final_moves_leaves_the_old_result_whole(tmp_path, monkeypatch, atomic_exchange):
    target = _old_result(tmp_path / "res")
    if atomic_exchange:
        def exchange_failing(first, second):
            raise OSError(5, "simulated I/O error during the swap")
        monkeypatch.setattr(staging, "_exchange", exchange_failing)
    else:  # no exchange on this system: the old result aside, the new one in -- which fails
        monkeypatch.setattr(staging, "_exchange", lambda first, second: False)
        rename = os.rename

        def rename_failing_for_the_new_one(source, destination):
            if Path(source).name.startswith(".res.partial-") and Path(destination) == target:
                raise OSError(5, "simulated I/O error during the swap")
            rename(source, destination)
        monkeypatch.setattr(staging.os, "rename", rename_failing_for_the_new_one)
    with pytest.raises(OSError, match="simulated"), staged_directory(target) as new:
        for name in OUTPUT_FILES:
            (new / name).write_text("new")
    _assert_old_result_whole(target)


def test_the_fallback_swap_replaces_the_old_result_whole(tmp_path, monkeypatch):
    monkeypatch.setattr(staging, "_exchange", lambda first, second: False)
    target = _old_result(tmp_path / "res")
    with staged_directory(target) as new:
        (new / "result.json").write_text("new")
    assert [p.name for p in target.iterdir()] == ["result.json"]
    assert [p.name for p in tmp_path.iterdir()] == ["res"]


def test_stale_staging_of_dead_runs_is_removed_and_a_running_ones_kept(tmp_path):
    target = tmp_path / "res"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    dead_pid = int(dead.stdout)
    stale = [tmp_path / f".res.partial-{dead_pid}-x1y2", tmp_path / ".res.partial-abc12345",
             tmp_path / f".res.previous-{dead_pid}-q"]
    running = tmp_path / f".res.partial-{os.getppid()}-zz"  # a live process's (this test's parent)
    other = tmp_path / f".other.partial-{dead_pid}-x"       # another target's
    for path in (*stale, running, other):
        path.mkdir()
        (path / "mesh.ply").write_text("partial")
    assert sorted(remove_stale_staging(target)) == sorted(stale)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([running.name, other.name])


@pytest.mark.parametrize("out", ["", " ", ".", "/"])
def test_an_output_that_is_empty_or_the_current_or_root_directory_is_refused(bags_dir, tmp_path, monkeypatch,
                                                                               capsys, out):
    monkeypatch.chdir(tmp_path)
    code = cli_main(["reconstruct", str(bags_dir / "straight"), "--out", out, "--no-progress"])
    assert code == 2
    (message,) = capsys.readouterr().err.strip().splitlines()
    assert message.startswith("ntcr-recon reconstruct: error: --out:")
    assert "empty" in message or "current or the root directory" in message
    assert list(tmp_path.iterdir()) == []  # nothing written into the current directory


def test_a_mount_point_is_refused_before_the_computation(tmp_path, monkeypatch):
    target = tmp_path / "mounted"
    target.mkdir()
    monkeypatch.setattr(staging.os.path, "ismount", lambda path: Path(path) == target)
    with pytest.raises(StagingError, match="mount point"), staged_directory(target):
        pytest.fail("the computation must not start")


def test_a_killed_run_leaves_the_old_result_and_the_next_run_cleans_up(bags_dir, tmp_path):
    bag = bags_dir / "straight"
    out = _old_result(tmp_path / "res")
    command = [sys.executable, "-m", "ntcr_recon.cli", "reconstruct", str(bag), "--out", str(out), "--no-progress"]
    run = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # killed while it computes: its staging directory exists from the start until the swap
        while run.poll() is None and not list(tmp_path.glob(".res.partial-*")):
            time.sleep(0.05)
        run.send_signal(signal.SIGKILL)
    finally:
        run.wait()
    assert run.returncode == -signal.SIGKILL
    _assert_old_result_whole_but_staging(out, next(tmp_path.glob(".res.partial-*")))
    result = subprocess.run([*command, "--max-frames", "1"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    assert [p.name for p in tmp_path.iterdir()] == ["res"]  # the killed run's staging is gone


def test_an_output_directory_holding_other_files_is_refused_unless_overwrite(bags_dir, tmp_path, capsys):
    """--out is replaced whole: a directory holding files no reconstruction writes (the user's own) is refused,
    naming them, and kept as it was; --overwrite replaces it."""
    out = tmp_path / "data"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    command = ["reconstruct", str(bags_dir / "straight"), "--out", str(out), "--no-progress", "--max-frames", "1"]
    assert cli_main(command) == 2
    message = capsys.readouterr().err
    assert "--out:" in message and "notes.txt" in message and "--overwrite" in message
    assert (out / "notes.txt").read_text() == "mine"
    assert [p.name for p in tmp_path.iterdir()] == ["data"]
    assert cli_main([*command, "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)


def _drawn_rows(image, columns: slice) -> float:
    """The share of the image's height between the topmost and lowest point drawn (tab:blue) in `columns`."""
    pixels = np.asarray(image.convert("RGB"))[:, columns].astype(int)
    blue = np.abs(pixels - [31, 119, 180]).sum(axis=2) < 60
    rows = np.flatnonzero(blue.any(axis=1))
    return (rows[-1] - rows[0]) / pixels.shape[0] if len(rows) else 0.0


def test_the_side_views_frame_the_robot_not_the_raw_clouds_far_points(tmp_path):
    """The raw cloud holds the clamp, the table and a backdrop up to 15 cm off: framed on them the robot would be a
    few pixels; framed on the relocated robot it fills most of the panel's height."""
    from PIL import Image

    from ntcr_recon.io import figures

    along = np.linspace(0.0, 0.05, 2000)
    robot = np.stack([0.002 * np.sin(40 * along), np.zeros_like(along), along], axis=1)
    far = np.array([[-0.15, 0.0, -0.15], [0.15, 0.0, 0.15], [0.15, 0.0, -0.15]])
    path = tmp_path / "side_views.png"
    figures.side_views(path, np.concatenate([robot, far]), robot, None, np.array([[1.0, 0, 0], [0, 0, 1.0]]),
                       axis_labels=("x (mm)", "z (mm)"))
    with Image.open(path) as image:
        third = image.width // 3
        assert _drawn_rows(image, slice(third, 2 * third)) > 0.6  # the relocated panel
        assert _drawn_rows(image, slice(0, third)) > 0.6  # the raw panel: the same frame, its far points beyond it
