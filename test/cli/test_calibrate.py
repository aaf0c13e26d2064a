"""`ntcr-recon calibrate` on bags the simulator writes (the robot straight and bent) from a rig file 2 deg and 2 mm
off per camera: the rig file it writes, its report and figure, and its refusals."""

import json

import matplotlib.image
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ntcr_recon.cli import main as cli_main
from ntcr_recon.cli.calibrate import report_paths
from ntcr_recon.core.base.transforms import invert_transform
from ntcr_recon.core.calibration.rig_fit import pivot_of
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.rig_file import write_poses


def _error(estimate, truth, pivot):
    change = estimate @ invert_transform(truth)
    return (np.degrees(np.linalg.norm(Rotation.from_matrix(change[:3, :3]).as_rotvec())),
            np.linalg.norm(change[:3, :3] @ pivot + change[:3, 3] - pivot) * 1e3)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    work = tmp_path_factory.mktemp("calibrate")
    for name, bend in (("straight", "0"), ("bent", "60")):
        assert cli_main(["simulate", str(work / name), "--bend-deg", bend, "--frames", "1", "--no-progress"]) == 0
    exact = load_rig_config(work / "bent" / "rig.yaml")
    rng = np.random.default_rng(2)
    rough = {}
    for name in exact.camera_names:
        pose = exact.cameras[name].extrinsic.copy()
        axis = rng.normal(size=3)
        pose[:3, :3] = Rotation.from_rotvec(np.radians(2.0) * axis / np.linalg.norm(axis)).as_matrix() @ pose[:3, :3]
        pose[:3, 3] += [1.2e-3, -1.2e-3, 1.2e-3]
        rough[name] = pose
    write_poses(work / "bent" / "rig.yaml", work / "rough.yaml", rough)
    return work, exact, rough


def test_the_calibrated_rig_file_is_the_rough_one_with_poses_nearer_the_truth(recorded):
    work, exact, rough = recorded
    out = work / "rig.yaml"
    assert cli_main(["calibrate", "--straight", str(work / "straight"), str(work / "bent"), "--config",
                     str(work / "rough.yaml"), "--out", str(out), "--no-progress"]) == 0
    calibrated = load_rig_config(out)
    pivot = pivot_of(exact.robot)
    for name in exact.camera_names:
        start = _error(rough[name], exact.cameras[name].extrinsic, pivot)
        turn, shift = _error(calibrated.cameras[name].extrinsic, exact.cameras[name].extrinsic, pivot)
        print(f"{name}: {start[0]:.2f} deg, {start[1]:.2f} mm off -> {turn:.3f} deg, {shift:.3f} mm")
        assert turn < 0.3 and shift < 0.3
    rough_lines, out_lines = (work / "rough.yaml").read_text().splitlines(), out.read_text().splitlines()
    assert sum(a != b for a, b in zip(rough_lines, out_lines, strict=True)) == 4  # two poses, nothing else
    report_file, figure_file = report_paths(out)
    report = json.loads(report_file.read_text())
    assert set(report["cameras"]) == {"cam_a", "cam_b"} and report["relative"]["camera"] == "cam_b"
    assert report["cameras"]["cam_a"]["moved"]["turn_deg"] > 1.5
    assert 0 < report["relative"]["uncertainty"]["turn_deg"]["z"] < 1.0
    assert [r["straight"] for r in report["recordings"]] == [True, False]
    assert report["warnings"] == []  # the notches open sideways to both cameras
    assert 55 < report["recordings"][1]["total_bend_deg"] < 65
    assert matplotlib.image.imread(figure_file).shape[2] in (3, 4)
    # written again only when asked
    again = ["calibrate", "--straight", str(work / "straight"), str(work / "bent"), "--config",
             str(work / "rough.yaml"), "--out", str(out), "--no-progress"]
    assert cli_main(again) == 2


def test_a_straight_robot_alone_is_refused_and_nothing_written(recorded, capsys):
    work, _, _ = recorded
    out = work / "straight_only.yaml"
    assert cli_main(["calibrate", "--straight", str(work / "straight"), "--config", str(work / "rough.yaml"),
                     "--out", str(out), "--no-progress"]) == 2
    assert "turn about z" in capsys.readouterr().err
    assert not out.exists() and not any(path.exists() for path in report_paths(out))
    assert cli_main(["calibrate", "--config", str(work / "rough.yaml"), "--out", str(out), "--no-progress"]) == 2


def test_a_target_mesh_is_read_in_its_unit_and_one_without_triangles_is_refused(recorded, tmp_path, capsys):
    import argparse

    import open3d as o3d

    from ntcr_recon.cli.calibrate import _target

    box = o3d.geometry.TriangleMesh.create_box(20.0, 10.0, 30.0)  # millimetres
    o3d.io.write_triangle_mesh(str(tmp_path / "block.ply"), box)
    target = _target(argparse.Namespace(target=tmp_path / "block.ply", target_unit="mm"))
    np.testing.assert_allclose(target.samples.max(axis=0), [0.02, 0.01, 0.03], atol=2e-4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(box.vertices)))
    o3d.io.write_point_cloud(str(tmp_path / "points.ply"), cloud)
    work, _, _ = recorded
    assert cli_main(["calibrate", str(work / "bent"), "--target", str(tmp_path / "points.ply"), "--config",
                     str(work / "rough.yaml"), "--out", str(tmp_path / "rig.yaml"), "--no-progress"]) == 2
    assert "has no triangles" in capsys.readouterr().err
