"""No silent degraded result from `ntcr-recon reconstruct` (issue 11): one camera only, a camera that
contributes nothing or little (wrong depth_unit, wrong pose), depth coarser than its unit, a big-endian
flag, no point left after relocation. Each is a warning in result.json and on stderr, or a clear refusal."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from support.bag_edit import depth_edit, depth_values, rewrite_bag, with_depth_values

from ntcr_recon.cli import main as cli_main
from ntcr_recon.core.quality.findings import CODES

FRAMES = "2"  # frame pairs per run: enough to show each fault, quick


def _reconstruct(bag, out, capsys, *extra):
    code = cli_main(["reconstruct", str(bag), "--out", str(out), "--no-progress", "--max-frames", FRAMES,
                     *map(str, extra)])
    stderr = capsys.readouterr().err
    result = json.loads((out / "result.json").read_text()) if code == 0 else None
    return code, result, stderr


def _warned(result, stderr, code, **figures) -> list[dict]:
    """The warnings of `code` whose figures are `figures` (a value or a pytest.approx); each is also printed on
    stderr as `<severity>: [<CODE>] <message>`, with the severity core.quality.findings gives the code."""
    found = [w for w in result["warnings"] if w["code"] == code and all(w.get(k) == v for k, v in figures.items())]
    assert found, result["warnings"]
    for warning in found:
        assert warning["severity"] == CODES[code].severity
        assert f"{warning['severity']}: [{code}] {warning['message']}" in stderr
    return found


def _rig(bags_dir, tmp_path, edit):
    document = yaml.safe_load((bags_dir / "straight" / "rig.yaml").read_text())
    edit(document["/**"]["ros__parameters"])
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def test_frames_from_one_camera_only_are_reported(bags_dir, tmp_path, capsys):
    code, result, stderr = _reconstruct(bags_dir / "straight", tmp_path / "out", capsys,
                                        "--topic", "cam_b.depth=/nowhere")
    assert code == 0
    _warned(result, stderr, "CAMERA_NO_FRAMES", camera="cam_b", rests_on=["cam_a"])
    assert result["status"] == "error"


def test_a_camera_with_the_wrong_depth_unit_is_reported_with_the_unit_that_fits(bags_dir, tmp_path, capsys):
    config = _rig(bags_dir, tmp_path, lambda p: p["cam_b"].update(depth_unit=0.001))  # realsense-ros's unit
    code, result, stderr = _reconstruct(bags_dir / "straight", tmp_path / "out", capsys, "--config", config)
    assert code == 0
    _warned(result, stderr, "CAMERA_NO_POINTS", camera="cam_b", depth_unit_that_fits=pytest.approx(0.0001))


def test_a_camera_with_a_wrong_pose_is_reported(bags_dir, tmp_path, capsys):
    def shift(parameters):
        parameters["cam_b"]["translation"][0] += 0.02  # 2 cm off: its points land beside the robot
    config = _rig(bags_dir, tmp_path, shift)
    code, result, stderr = _reconstruct(bags_dir / "straight", tmp_path / "out", capsys, "--config", config)
    assert code == 0
    _warned(result, stderr, "CAMERA_FEW_POINTS", camera="cam_b", leans_on="cam_a")


def test_depth_coarser_than_its_unit_is_reported(bags_dir, tmp_path, capsys):
    # a 1 mm recording (realsense-ros) rescaled to the D405's 0.1 mm unit: every value a multiple of 10
    coarse = depth_edit("cam_a", lambda m: with_depth_values(m, np.round(depth_values(m) / 10) * 10))
    bag = rewrite_bag(bags_dir / "straight", tmp_path / "coarse", edit=coarse)
    code, result, stderr = _reconstruct(bag, tmp_path / "out", capsys)
    assert code == 0
    _warned(result, stderr, "DEPTH_COARSER_THAN_UNIT", camera="cam_a", step_units=10,
            depth_step_mm=pytest.approx(1.0))


def test_big_endian_depth_is_read_byte_swapped_and_reported(bags_dir, tmp_path, capsys):
    swapped = depth_edit("cam_a", lambda m: with_depth_values(m, depth_values(m), big_endian=True))
    bag = rewrite_bag(bags_dir / "straight", tmp_path / "swapped", edit=swapped)
    code, result, stderr = _reconstruct(bag, tmp_path / "out", capsys)
    assert code == 0
    big_endian = _warned(result, stderr, "DEPTH_BIG_ENDIAN", camera="cam_a")
    code, plain, _ = _reconstruct(bags_dir / "straight", tmp_path / "plain_out", capsys)
    assert plain["centerline_m"] == result["centerline_m"] and plain["notches"] == result["notches"]
    # nothing else wrong: the rest is what the self-check says of the very same data read plainly (in result.json's
    # order, errors first: the flag's warning among the other warnings)
    assert len(result["warnings"]) == len(big_endian) + len(plain["warnings"])
    assert [w for w in result["warnings"] if w not in big_endian] == plain["warnings"]


def test_a_wrong_big_endian_flag_is_reported_or_refused(bags_dir, tmp_path, capsys):
    def flag(m):
        return dataclasses.replace(m, is_bigendian=1)  # little-endian data flagged big-endian

    bag = rewrite_bag(bags_dir / "straight", tmp_path / "one", edit=depth_edit("cam_a", flag))
    code, result, stderr = _reconstruct(bag, tmp_path / "out", capsys)
    assert code == 0
    _warned(result, stderr, "DEPTH_BIG_ENDIAN", camera="cam_a")
    _warned(result, stderr, "CAMERA_FEW_POINTS", camera="cam_a", leans_on="cam_b")

    # Both cameras: nothing of the robot is left. Before: "open3d could not write mesh.ply"; now a refusal
    # that names the flag, and no output.
    def both(topic, msg):
        return flag(msg) if topic.endswith("depth/image_rect_raw") else msg

    bag = rewrite_bag(bags_dir / "straight", tmp_path / "both", edit=both)
    code, _, stderr = _reconstruct(bag, tmp_path / "both_out", capsys)
    assert code == 2
    (message,) = stderr.strip().splitlines()
    assert message.startswith("ntcr-recon reconstruct: error:") and "flagged big-endian" in message
    assert "open3d" not in message
    assert not (tmp_path / "both_out").exists()


def test_no_point_after_relocation_is_refused(bags_dir, tmp_path, capsys, monkeypatch):
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    relocate = Reconstructor.relocate

    def relocate_losing_every_point(self, cloud, warm_start=True):
        relocation = relocate(self, cloud, warm_start)
        return dataclasses.replace(relocation, relocated=relocation.relocated.subset(np.arange(0)))

    monkeypatch.setattr(Reconstructor, "relocate", relocate_losing_every_point)
    code, _, stderr = _reconstruct(bags_dir / "straight", tmp_path / "out", capsys)
    assert code == 2
    assert "relocation kept none of the" in stderr and "nothing to mesh" in stderr
    assert not (tmp_path / "out").exists()


def test_a_robot_that_moved_during_the_recording_is_reconstructed_in_one_pose_and_said_so(bags_dir, tmp_path, capsys):
    """Four frame pairs of the straight robot, then four of it bent 45 deg: combining all eight would blend the two
    poses into one it never held. The result combines the last four (of two stretches as long, the latest),
    measured against the bent robot's truth, and a warning names the frames left out; the straight recording alone
    combines all its frames, and says nothing."""
    bag = rewrite_bag([bags_dir / "straight", bags_dir / "bend45"], tmp_path / "moved", crop=True)
    code = cli_main(["reconstruct", str(bag), "--out", str(tmp_path / "out"), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = result["ground_truth"]
    assert result["frames"] == 8 and result["frames_combined"] == {"first": 5, "last": 8, "count": 4}
    assert truth["tip_error_mm"] < 0.15 and truth["centerline_rmse_mm"] < 0.08
    _warned(result, stderr, "ROBOT_MOVED", combined=[5, 8])
    code, still, _ = _reconstruct(bags_dir / "straight", tmp_path / "still", capsys)
    assert code == 0 and still["frames_combined"] == {"first": 1, "last": 2, "count": 2}
    assert "ROBOT_MOVED" not in {w["code"] for w in still["warnings"]}
    with capsys.disabled():
        print(f"\nmoved: frames {result['frames_combined']} combined, tip {truth['tip_error_mm']:.3f} mm off the "
              f"bent robot's, centreline {truth['centerline_rmse_mm']:.3f}, {truth['notches_detected']} notches")


def test_a_frame_pair_without_the_robot_is_left_out_and_said_so(bags_dir, tmp_path, capsys):
    """The second of four frame pairs returns no depth in either camera (the robot covered): the other three are
    reconstructed, and a warning names the pair left out and why; a recording where every pair fails is refused
    with the first one's cause."""
    def blanking(frame: int | None):  # each camera's depth image `frame` (0-based; None: every one) made empty
        seen = {}

        def blank(topic, msg):
            if topic.endswith("depth/image_rect_raw"):
                seen[topic] = seen.get(topic, -1) + 1
                if frame is None or seen[topic] == frame:
                    return with_depth_values(msg, np.zeros_like(depth_values(msg)))
            return msg
        return blank

    bag = rewrite_bag(bags_dir / "straight", tmp_path / "covered", crop=True, edit=blanking(1))
    code = cli_main(["reconstruct", str(bag), "--out", str(tmp_path / "out"), "--no-progress"])
    stderr = capsys.readouterr().err
    assert code == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["frames"] == 4 and result["frames_combined"] == {"first": 1, "last": 4, "count": 3}
    assert result["ground_truth"]["notches_detected"] == 16
    (left_out,) = _warned(result, stderr, "FRAMES_LEFT_OUT", pairs=1, of=4)
    assert "frame pair 2" in left_out["message"]  # which pair, and why: no figure carries it (cli/reconstruct.py)
    bag = rewrite_bag(bags_dir / "straight", tmp_path / "all_covered", crop=True, edit=blanking(None))
    code, _, stderr = _reconstruct(bag, tmp_path / "none", capsys)
    assert code == 2
    (message,) = stderr.strip().splitlines()
    assert "frame pair 1" in message and "(and so did the other frame pair)" in message


def test_no_camera_contributing_is_refused_without_saying_either_carries_the_result(bags_dir, tmp_path, capsys):
    def millimetres(parameters):
        for camera in ("cam_a", "cam_b"):
            parameters[camera].update(depth_unit=0.001)
    config = _rig(bags_dir, tmp_path, millimetres)
    code, _, stderr = _reconstruct(bags_dir / "straight", tmp_path / "out", capsys, "--config", config)
    assert code == 2
    assert "cam_a contributed no points" in stderr and "cam_b contributed no points" in stderr
    assert "nor did any other camera" in stderr and "rests on" not in stderr
