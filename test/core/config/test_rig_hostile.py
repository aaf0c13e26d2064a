"""The rig configuration under hostile or careless input (issue 11): values outside physical ranges, non-finite
numbers, huge values and files, YAML alias bombs, identifiers YAML 1.1 would misread, binary files, typos."""

from __future__ import annotations

import copy
import tracemalloc

import pytest
import yaml

from ntcr_recon.core.config.rig import ConfigError, load_rig_config, load_robot_geometry, rig_config_from_mapping
from ntcr_recon.core.robot.geometry import TubeGeometry


@pytest.fixture(scope="module")
def sim_mapping(repo_root):
    document = yaml.safe_load((repo_root / "config" / "sim_rig.yaml").read_text())
    return document["/**"]["ros__parameters"]


def edited(mapping: dict, dotted: str, value) -> dict:
    """A deep copy of `mapping` with the value at `dotted` (section.key) replaced."""
    result = copy.deepcopy(mapping)
    *parents, leaf = dotted.split(".")
    node = result
    for part in parents:
        node = node.setdefault(part, {})
    node[leaf] = value
    return result


def write_rig(path, parameters: dict):
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
    return path


@pytest.mark.parametrize(("dotted", "value", "message"), [
    ("robot.outer_diameter", 1e6, r"robot\.outer_diameter must lie in \[0\.0005, 0\.02\] m, got 1000000\.0"),
    ("robot.outer_diameter", 1e-300, r"robot\.outer_diameter must lie in \[0\.0005, 0\.02\] m"),
    ("robot.outer_diameter", 0.3e-3, r"robot\.outer_diameter must lie in"),
    ("robot.outer_diameter", 25e-3, r"robot\.outer_diameter must lie in"),
    ("robot.proximal_length", 1e300, r"robot\.proximal_length must lie in \[0, 1\) m"),
    ("robot.distal_length", 1.0, r"robot\.distal_length must lie in \[0, 1\) m"),
    ("robot.notch_count", 1000, r"robot\.notch_count must lie in \[1, 500\], got 1000"),
    ("robot.notch_count", 10**6, r"robot\.notch_count must lie in \[1, 500\]"),
    ("robot.notch_count", 400, r"robot: length 1\.2\d* m .* exceeds 1 m"),  # 400 notches at 3 mm: a 1.2 m robot
    ("mesh.poisson_depth", 30, r"mesh\.poisson_depth must lie in \[1, 12\], got 30"),
    ("metrics.pdc_voxel", 1e-12, r"metrics\.pdc_voxel must lie in \[1e-05, 0\.1\] m"),
    ("filters.voxel_size", 1e-9, r"filters\.voxel_size must lie in 0 \(off\) or \[1e-05, 0\.1\] m"),
    ("cam_a.width", 10**9, r"cam_a\.width must lie in \[1, 4096\] px"),
    ("cam_a.translation", [0.0, 1e12, 0.0], r"cam_a\.translation must lie in \[-10, 10\] m"),
    ("relocation.max_iterations", 10**7, r"relocation\.max_iterations must lie in"),
    ("relocation.method", "magic", r"relocation\.method must be 'centerline' or 'icp'"),
])
def test_values_outside_physical_ranges_are_refused_naming_the_key(sim_mapping, dotted, value, message):
    with pytest.raises(ConfigError, match=message):
        rig_config_from_mapping(edited(sim_mapping, dotted, value))


@pytest.mark.parametrize(("dotted", "value", "message"), [
    ("robot.notch_count", float("inf"), r"robot\.notch_count must be of type int, got inf"),
    ("robot.notch_count", float("nan"), r"robot\.notch_count must be of type int, got nan"),
    ("mesh.max_points", float("-inf"), r"mesh\.max_points must be of type int"),
    ("cam_a.width", float("inf"), r"cam_a\.width must be of type int"),
    ("robot.outer_diameter", float("nan"), r"robot\.outer_diameter must be a finite number, got nan"),
    ("robot.notch_width", float("inf"), r"robot\.notch_width must be a finite number, got inf"),
    ("robot.outer_diameter", 10**400, r"robot\.outer_diameter must be a finite number"),  # float() overflows
    ("cam_a.rotation", [0.0, 0.0, float("nan"), 1.0], r"cam_a\.rotation must be a finite number"),
])
def test_non_finite_numbers_are_refused_with_a_message(sim_mapping, dotted, value, message):
    with pytest.raises(ConfigError, match=message):
        rig_config_from_mapping(edited(sim_mapping, dotted, value))


def test_non_finite_numbers_in_a_file_are_refused_naming_the_key(tmp_path, sim_mapping):
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": sim_mapping}}).replace(
        "notch_count: 16", "notch_count: .inf"))
    with pytest.raises(ConfigError, match=r"rig\.yaml: robot\.notch_count must be of type int, got inf"):
        load_rig_config(path)


def test_a_robot_built_in_code_is_held_to_the_same_ranges():
    with pytest.raises(ValueError, match=r"robot\.outer_diameter must lie in"):
        TubeGeometry(outer_diameter=1e6, inner_diameter=1e-3).validate()
    with pytest.raises(ValueError, match=r"robot\.notch_count must lie in \[1, 500\]"):
        TubeGeometry.from_mapping({"notch_count": 10**6})


@pytest.mark.parametrize("dotted", ["cam_a.serial_number", "robot.notch_width", "mesh.method", "cam_a.frame_id"])
def test_a_refused_value_is_printed_as_a_short_excerpt(sim_mapping, dotted):
    huge = "8" * 50_000_000  # 50 MB; a YAML alias bomb once printed 2 GB
    with pytest.raises(ConfigError) as refused:
        rig_config_from_mapping(edited(sim_mapping, dotted, huge))
    message = str(refused.value)
    assert dotted in message and len(message) < 300
    assert "(50000000 characters)" in message


def test_an_unknown_key_of_any_size_is_named_by_an_excerpt(sim_mapping):
    mapping = copy.deepcopy(sim_mapping)
    mapping["filters"]["x" * 10_000_000] = 1
    with pytest.raises(ConfigError, match=r"unknown key filters\.'x{10,}") as refused:
        rig_config_from_mapping(mapping)
    assert len(str(refused.value)) < 600


def test_a_yaml_alias_bomb_is_refused_with_bounded_memory(tmp_path):
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 10)]  # 9^10 strings expanded
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("/**:\n  ros__parameters:\n    base_frame: ntcr_base\n" + "".join(
        f"    {line}\n" for line in lines))
    tracemalloc.start()
    try:
        with pytest.raises(ConfigError, match=r"bomb\.yaml: line 4: YAML anchor &a0 is refused"):
            load_rig_config(bomb)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 5_000_000  # refused before expanding: the expansion would take gigabytes


def test_a_yaml_alias_of_a_value_is_refused(tmp_path, sim_mapping):
    text = yaml.safe_dump({"/**": {"ros__parameters": sim_mapping}}, sort_keys=False)
    text = text.replace("camera_timeout: 0.5", "camera_timeout: *slop").replace("slop: 0.015", "slop: &slop 0.015")
    path = tmp_path / "alias.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"YAML anchor &slop is refused"):
        load_rig_config(path)


@pytest.mark.parametrize("serial", ["0123456", "12:34:56", "0x1F", "1e3", "230322270001", "0o17", "true", "1_000"])
def test_serial_numbers_and_frame_names_are_read_as_written(tmp_path, sim_mapping, serial):
    # YAML 1.1 reads 0123456 as octal 42798 and 12:34:56 as base 60 (45296): the wrong camera would be opened
    text = yaml.safe_dump({"/**": {"ros__parameters": sim_mapping}}, sort_keys=False)
    text = text.replace("serial_number: ''", f"serial_number: {serial}", 1)
    text = text.replace("frame_id: cam_b_optical_frame", f"frame_id: {serial}")
    text = text.replace("base_frame: ntcr_base", f"base_frame: {serial}")
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    config = load_rig_config(path)
    assert config.cameras["cam_a"].serial_number == serial
    assert config.cameras["cam_b"].frame_id == serial
    assert config.base_frame == serial


def test_camera_names_are_read_as_written(tmp_path, sim_mapping):
    mapping = {key: value for key, value in copy.deepcopy(sim_mapping).items() if key != "cam_b"}
    mapping["camera_names"] = ["0123"]
    mapping["0123"] = mapping.pop("cam_a")
    path = write_rig(tmp_path / "rig.yaml", mapping)
    path.write_text(path.read_text().replace("- '0123'", "- 0123").replace("'0123':", "0123:"))
    assert "- 0123\n" in path.read_text()
    assert load_rig_config(path).camera_names == ("0123",)


def test_numbers_stay_numbers(tmp_path, sim_mapping):
    config = load_rig_config(write_rig(tmp_path / "rig.yaml", sim_mapping))
    assert config.robot.notch_count == 16 and config.cameras["cam_a"].depth_unit == pytest.approx(1e-4)


@pytest.mark.parametrize(("content", "message"), [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", r"is not UTF-8 text \(byte 0x89 at offset 0\)"),
    (b"base_frame: caf\xe9\n", r"is not UTF-8 text \(byte 0xe9 at offset 15\)"),
    (b"base_frame: a\x00b\n", r"not valid YAML: unacceptable character #x0000"),
    (b"- cam_a\n- cam_b\n", r"must be a mapping of keys, got a list"),
    (b"just a line of text\n", r"must be a mapping of keys, got a str"),
    (b"", r"must be a mapping of keys, got an empty file"),
    (b"/**:\n  ros__parameters: [1, 2]\n", r"ros__parameters must be a mapping of keys"),
    (b"[" * 100_000, r"nested too deeply|not valid YAML"),
    (b"a: 1\na: 2\n", r"line 2: key 'a' appears twice"),
    (b"notch_count: " + b"9" * 5000 + b"\n", r"cannot read the value of notch_count"),
])
def test_files_that_are_no_configuration_get_a_clear_message(tmp_path, content, message):
    path = tmp_path / "rig.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message):
        load_rig_config(path)
    with pytest.raises(ConfigError, match=message):
        load_robot_geometry(path)


def test_a_file_too_large_for_a_configuration_is_refused_before_parsing(tmp_path):
    path = tmp_path / "huge.yaml"
    path.write_text("base_frame: '" + "x" * (2 << 20) + "'\n")
    with pytest.raises(ConfigError, match=r"huge\.yaml is larger than 1024 KiB"):
        load_rig_config(path)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda m: m.update(filter=m.pop("filters")), r"unknown key filter; did you mean 'filters'\?"),
    (lambda m: m.update(robt=m.pop("robot")), r"unknown key robt; did you mean 'robot'\?"),
    (lambda m: m.update(cam_c={"width": 2}), r"unknown key cam_c; did you mean 'cam_[ab]'\?"),
    (lambda m: m["relocation"].update(gate_radius=1.0),
     r"unknown key relocation\.gate_radius; did you mean 'gate_radius_fraction'\?"),
    (lambda m: m["cam_a"].update(serial="1"), r"unknown key cam_a\.serial; did you mean 'serial_number'\?"),
    (lambda m: m["robot"].update(notch_cout=16), r"unknown key robot\.notch_cout; did you mean 'notch_count'\?"),
    (lambda m: m["mesh"].update(zzz=1), r"unknown key mesh\.zzz \(known: density_quantile, max_points"),
])
def test_unknown_keys_at_any_level_are_refused_with_the_nearest_known_key(sim_mapping, edit, message):
    mapping = copy.deepcopy(sim_mapping)
    edit(mapping)
    with pytest.raises(ConfigError, match=message):
        rig_config_from_mapping(mapping)


def test_a_typo_in_a_file_is_refused_naming_the_file(tmp_path, sim_mapping):
    mapping = copy.deepcopy(sim_mapping)
    mapping["filter"] = mapping.pop("filters")
    with pytest.raises(ConfigError, match=r"rig\.yaml: unknown key filter; did you mean 'filters'\?"):
        load_rig_config(write_rig(tmp_path / "rig.yaml", mapping))
