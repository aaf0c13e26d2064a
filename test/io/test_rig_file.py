"""The rig file with its cameras' poses replaced: everything else kept line for line, the poses read back."""

import numpy as np
import pytest
from support import REPO

from ntcr_recon.core.base.transforms import rigid_transform
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.rig_file import RigFileError, replace_poses, write_poses

TEMPLATE = REPO / "config" / "rig_template.yaml"


def test_only_the_pose_lines_change_and_their_comments_stay(tmp_path):
    poses = {"cam_a": rigid_transform([0.001, -0.0912, 0.0203], [-0.49, -0.51, -0.5, 0.5]),
             "cam_b": rigid_transform([-0.002, 0.0895, 0.021], [0.5, -0.5, 0.51, 0.49])}
    before = TEMPLATE.read_text().splitlines()
    after = replace_poses(TEMPLATE.read_text(), poses).splitlines()
    changed = [i for i, (a, b) in enumerate(zip(before, after, strict=True)) if a != b]
    assert len(changed) == 4
    for i in changed:
        key = before[i].split(":")[0]
        assert after[i].split(":")[0] == key and key.strip() in ("translation", "rotation")
        assert after[i].split("#")[1:] == before[i].split("#")[1:]  # the comment after the value
    target = tmp_path / "rig.yaml"
    template = tmp_path / "template.yaml"
    template.write_text(TEMPLATE.read_text().replace("'FILL'", "'123'"))
    write_poses(template, target, poses)
    config = load_rig_config(target)
    for name, pose in poses.items():
        np.testing.assert_allclose(config.cameras[name].extrinsic, pose, atol=1e-8)


def test_a_file_without_a_cameras_block_or_with_a_block_list_is_refused():
    with pytest.raises(RigFileError, match="no block 'cam_c:'"):
        replace_poses(TEMPLATE.read_text(), {"cam_c": np.eye(4)})
    block_list = TEMPLATE.read_text().replace("translation: [0.0, -0.09, 0.02]", "translation:\n        - 0.0")
    with pytest.raises(RigFileError, match="cam_a.translation is not written as a flow list"):
        replace_poses(block_list, {"cam_a": np.eye(4)})
