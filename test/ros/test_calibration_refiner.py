"""relocation_node's calibration refine, without a graph: a finished refinement as its /diagnostics status, and the
rig file written with it (test/ros/graph/test_node_refine.py runs it in the node)."""

from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus

from ntcr_recon.core.calibration.refine import RefinedPose
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.ros.calibration_refiner import REFINED_CODE, OnlineRefiner

RIG = Path(__file__).resolve().parents[2] / "bags" / "bend45" / "rig.yaml"


class _Log:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(("info", text))

    def warning(self, text):
        self.lines.append(("warning", text))


def _finished(refiner: OnlineRefiner, outcome) -> DiagnosticStatus:
    status = refiner.report(outcome)
    assert refiner.poll() is None  # none running
    return status


def _refined(config, change) -> RefinedPose:
    pose = config.cameras["cam_b"].extrinsic.copy()
    pose[:3, 3] += [0.0, 0.0, 1e-3]
    return RefinedPose("cam_b", "cam_a", pose, np.asarray(change, float), np.full(6, 0.1), {"cam_a": 0.02}, 4)


def _values(status: DiagnosticStatus) -> dict:
    return {kv.key: kv.value for kv in status.values}


def test_a_refinement_beyond_its_resolution_is_a_warn_with_the_refined_pose(tmp_path):
    config = load_rig_config(RIG)
    refiner = OnlineRefiner(config, _Log(), "relocation_node")
    status = _finished(refiner, _refined(config, [1.0, 0, 0, 0, 0, 1.0]))
    values = _values(status)
    assert status.level == DiagnosticStatus.WARN and values["code"] == REFINED_CODE
    assert status.name == "relocation_node: calibration refine" and values["significant"] == "true"
    assert values["turn_deg.x"] == "1.0000" and values["shift_mm.z"] == "1.0000" and values["frames"] == "4"
    written, said = refiner.write(str(RIG), str(tmp_path / "rig.yaml"))
    assert written and "rig.yaml" in said
    np.testing.assert_allclose(load_rig_config(tmp_path / "rig.yaml").cameras["cam_b"].extrinsic,
                               refiner.latest.extrinsic, atol=1e-9)


def test_a_refinement_within_its_resolution_is_ok():
    config = load_rig_config(RIG)
    status = _finished(OnlineRefiner(config, _Log(), "relocation_node"), _refined(config, [0.2, 0, 0, 0, 0.1, 0]))
    assert status.level == DiagnosticStatus.OK and _values(status)["code"] == ""


def test_frames_that_cannot_give_a_refinement_are_stale_and_keep_the_last_one(tmp_path):
    config = load_rig_config(RIG)
    log = _Log()
    refiner = OnlineRefiner(config, log, "relocation_node")
    written, said = refiner.write(str(RIG), "")
    assert not written and "no refinement" in said
    _finished(refiner, _refined(config, [1.0, 0, 0, 0, 0, 0]))
    status = _finished(refiner, "the recordings do not determine cam_b's turn about z (free)")
    assert status.level == DiagnosticStatus.STALE and "turn about z" in status.message
    assert refiner.latest is not None and log.lines[-1][0] == "warning"
    assert refiner.write("", "")[0] is False
    written, said = refiner.write(str(RIG), str(tmp_path / "missing" / "rig.yaml"))
    assert not written and "could not write" in said
