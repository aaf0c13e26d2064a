"""The rig configuration loader: defaults, round trips through flat parameters, and refusals that name the key."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from ntcr_recon.core.cloud.filters import crop_mask
from ntcr_recon.core.config.document import document_rig_config
from ntcr_recon.core.config.parameters import config_to_mapping, flatten_parameters, rig_parameter_keys
from ntcr_recon.core.config.rig import ConfigError, load_rig_config, rig_config_from_mapping
from ntcr_recon.core.robot.geometry import TubeGeometry


@pytest.fixture(scope="module")
def sim_mapping(repo_root):
    document = yaml.safe_load((repo_root / "config" / "sim_rig.yaml").read_text())
    return document["/**"]["ros__parameters"]


def test_sim_and_template_configs_load(repo_root):
    sim = load_rig_config(repo_root / "config" / "sim_rig.yaml")
    template = load_rig_config(repo_root / "config" / "rig_template.yaml")
    assert sim.camera_names == ("cam_a", "cam_b")
    assert sim.robot.outer_radius == pytest.approx(1.75e-3)
    # a live D405 keeps 0.1 mm depth units (camera_node sets them): 1 mm would lose most of the tube
    assert template.cameras["cam_a"].depth_unit == template.cameras["cam_b"].depth_unit == pytest.approx(1e-4)
    # the extrinsic maps the optical axis of cam_a (looking along +y) into the base frame
    assert sim.cameras["cam_a"].extrinsic[:3, 2] == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
    assert sim.topics.camera_topic("cam_b", "depth") == "/ntcr/cam_b/depth/image_rect_raw"


def test_flat_parameters_round_trip(sim_mapping):
    config = rig_config_from_mapping(sim_mapping)
    flat = flatten_parameters(config)
    assert flat["relocation.gate_radius_fraction"] == config.relocation.gate_radius_fraction
    assert flat["robot.base_position"] == [0.0, 0.0, 0.0]
    assert all(not isinstance(v, (dict, tuple)) for v in flat.values())
    assert rig_config_from_mapping(flat) == config
    assert rig_config_from_mapping(config_to_mapping(config)) == config


def test_stage_sections_are_optional(sim_mapping):
    minimal = {k: v for k, v in sim_mapping.items() if k not in ("fusion", "filters", "relocation", "mesh",
                                                                   "metrics", "topics")}
    config = rig_config_from_mapping(minimal)
    assert config.filters.mls and config.filters.sor


def test_auto_crop_box_starts_at_the_base(sim_mapping):
    config = rig_config_from_mapping(sim_mapping)
    box_min, box_max = config.crop_box()
    reach = config.robot.length + config.robot.outer_diameter
    assert box_min == pytest.approx([-reach, -reach, 0.0])
    assert box_max == pytest.approx([reach, reach, reach])
    tilted = copy.deepcopy(sim_mapping)
    tilted["robot"]["base_orientation"] = [1.0, 0.0, 0.0, 0.0]  # robot pointing down -z
    box_min, box_max = rig_config_from_mapping(tilted).crop_box()
    assert box_max[2] == pytest.approx(0.0) and box_min[2] == pytest.approx(-reach)


@pytest.mark.parametrize("pointing_down", [False, True])
def test_with_a_clamp_radius_the_crop_reaches_below_the_base_plane_and_keeps_the_clamp_out(sim_mapping,
                                                                                           pointing_down):
    """A robot bent past 90 deg goes on below its base plane, where the clamp stands: the box reaches there,
    and a cylinder of the clamp's radius about the base's axis below the plane is cut out of it, with what it
    hides from the camera that saw a point."""
    mapping = copy.deepcopy(sim_mapping)
    mapping["filters"]["clamp_radius"] = 0.005
    mapping["robot"]["base_position"] = [0.01, 0.0, 0.0]
    if pointing_down:  # the base turned half a turn about x: its axis, and the clamp below it, are flipped
        mapping["robot"]["base_orientation"] = [1.0, 0.0, 0.0, 0.0]
    config = rig_config_from_mapping(mapping)
    reach = config.robot.length + config.robot.outer_diameter
    assert config.crop_box()[0][2] == pytest.approx(-reach) and config.crop_box()[1][2] == pytest.approx(reach)
    below = 1.0 if pointing_down else -1.0  # the side of the base plane the clamp is on, along base z
    points = np.array([[0.01, 0.0, 0.02 * below],            # on the clamp's axis, below the base: out
                       [0.01 + 0.0049, 0.0, 0.001 * below],  # just inside the clamp's radius: out
                       [0.01 + 0.0051, 0.0, 0.001 * below],  # just outside it: a robot bent back down, in
                       [0.01, 0.0, -0.001 * below],          # above the base, on the axis: the robot, in
                       [0.01, 0.0, 0.08 * below]])           # beyond the robot's reach: out
    assert crop_mask(points, config).tolist() == [False, False, True, True, False]
    # a camera 90 mm off along base -y, 25 mm above the base plane: what the clamp hides from it, a stereo
    # matcher's pixels flying off the clamp's edge, is out; beside the clamp and above the plane is in
    rotation, base = config.robot.base_rotation, np.array([0.01, 0.0, 0.0])
    camera = base + rotation @ [0.0, -0.09, 0.025]
    seen = base + np.array([[0.0, 0.02, -0.01],     # behind the clamp, below the plane: hidden
                            [0.0, 0.02, 0.01],      # behind it, above the plane: the line of sight passes over
                            [0.02, 0.0, -0.005],    # beside it
                            [0.0, -0.01, -0.005]]) @ rotation.T  # in front of it
    assert crop_mask(seen, config, viewpoints=camera).tolist() == [False, True, True, True]
    assert crop_mask(seen, config).tolist() == [True, True, True, True]
    mapping["filters"]["clamp_radius"] = 0.0  # no clamp given: the box stops at the base plane
    assert crop_mask(points, rig_config_from_mapping(mapping)).tolist() == [False, False, False, True, False]


@pytest.mark.parametrize(("edit", "message"), [
    (lambda m: m.pop("robot"), "missing key 'robot'"),
    (lambda m: m["cam_a"].pop("translation"), "missing key cam_a.translation"),
    (lambda m: m["robot"].update(outer_diameter=-0.001), "robot.outer_diameter must be > 0"),
    (lambda m: m["robot"].update(notch_depth=0.004), "robot.notch_depth"),
    (lambda m: m["filters"].update(sor_alpha=-1.0), "filters.sor_alpha must be > 0"),
    (lambda m: m["filters"].update(mls_order=3), "filters.mls_order must be 1 or 2"),
    (lambda m: m["filters"].update(crop_box_auto=False, crop_box_min=[0.01, 0.0, 0.0],
                                   crop_box_max=[0.0, 0.1, 0.1]), "excludes everything"),
    (lambda m: m["filters"].update(crop_box_auto=False, crop_box_min=[0.01, 0.01, 0.01],
                                   crop_box_max=[0.1, 0.1, 0.1]), "would exclude the robot"),
    (lambda m: m["relocation"].update(gate_radius=1.0), "unknown key relocation.gate_radius"),
    (lambda m: m["cam_b"].update(rotation=[0.0, 0.0, 0.0, 2.0]), "cam_b.translation/rotation"),
    (lambda m: m["mesh"].update(poisson_depth="deep"), "mesh.poisson_depth must be of type int"),
    (lambda m: m.update(camera_names=[]), "camera_names must be a non-empty list"),
])
def test_bad_values_are_refused_naming_the_key(sim_mapping, edit, message):
    mapping = copy.deepcopy(sim_mapping)
    edit(mapping)
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        rig_config_from_mapping(mapping)


def test_unreadable_files_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read rig configuration"):
        load_rig_config(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("/**: {ros__parameters: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_rig_config(broken)
    negative = tmp_path / "negative.yaml"
    document = {"/**": {"ros__parameters": {"base_frame": "b", "camera_names": ["c"],
                                            "c": {"translation": [0, 0, 0], "rotation": [0, 0, 0, 1],
                                                  "depth_unit": 0.0001},
                                            "robot": {"outer_diameter": -1.0}}}}
    negative.write_text(yaml.safe_dump(document))
    with pytest.raises(ConfigError, match=r"negative\.yaml: robot\.outer_diameter"):
        load_rig_config(negative)


def test_digit_only_serial_number_is_read_as_text(sim_mapping):
    # YAML (and `-p cam_a.serial_number:=...`) turn an unquoted D405 serial into an integer
    mapping = copy.deepcopy(sim_mapping)
    mapping["cam_a"]["serial_number"] = 230322270001
    assert rig_config_from_mapping(mapping).cameras["cam_a"].serial_number == "230322270001"
    mapping["cam_a"]["frame_id"] = 5
    with pytest.raises(ConfigError, match="cam_a.frame_id"):
        rig_config_from_mapping(mapping)


def test_sim_rig_yaml_is_the_schema_documentation_of_its_values(repo_root):
    """config/sim_rig.yaml is written from the schema (`python -m ntcr_recon.core.config.document config/sim_rig.yaml`):
    every key, each with its description, unit and range as the loader applies them."""
    path = repo_root / "config" / "sim_rig.yaml"
    text = path.read_text()
    expected = document_rig_config(load_rig_config(path), text[: text.index("/**:")])
    assert text == expected, "regenerate: python -m ntcr_recon.core.config.document config/sim_rig.yaml"
    assert "      # outer diameter of the tube; [0.0005, 0.02] m\n      outer_diameter: 0.0035\n" in text
    assert "      # octree depth of the Poisson solve (memory grows 8x a level); [1, 12]\n" in text


def test_sim_rig_yaml_lists_exactly_the_schema_keys(sim_mapping):
    listed = set(flatten_parameters(sim_mapping))
    schema = {"camera_names", *rig_parameter_keys(sim_mapping["camera_names"])}
    assert listed == schema
    assert {"relocation.method", "relocation.reference_mesh"} <= schema


def test_every_key_has_a_description_and_every_number_a_range():
    quaternions = {"cam_a.rotation", "robot.base_orientation"}  # bounded by their unit norm instead
    for dotted, key in rig_parameter_keys(["cam_a"]).items():
        assert key.setting.description, dotted
        if key.scalar in (int, float) and dotted not in quaternions:
            assert key.setting.range_text(), dotted


def test_the_schema_defaults_are_a_valid_configuration(sim_mapping):
    minimal = {"camera_names": ["cam_a"], "cam_a": {"translation": [0.0, -0.09, 0.02],
                                                    "rotation": [-0.5, -0.5, -0.5, 0.5], "depth_unit": 1e-4},
               "robot": {}}
    config = rig_config_from_mapping(minimal)
    assert config.base_frame == "ntcr_base" and config.robot == TubeGeometry()
    assert config.relocation.method == "centerline" and config.relocation.reference_mesh == ""
    assert config.cameras["cam_a"].frame_id == "cam_a_optical_frame"
