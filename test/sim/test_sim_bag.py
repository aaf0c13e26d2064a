"""A bag written by the simulator reads back, with rosbags and with the mcap reader, as it was written."""

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from ntcr_recon import cli
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.io.pointcloud import cloud_from_msg
from ntcr_recon.io.staging import StagingError
from ntcr_recon.sim.bag import TOPIC_KINDS, BagContents, topic_name, write_rig_bag
from ntcr_recon.sim.camera import D405Intrinsics
from ntcr_recon.sim.scene import RigProps
from ntcr_recon.sim.simulate import Simulation
from ntcr_recon.sim.truth import load_truth

FRAMES = 2


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    shape = TubeShape.from_bend_angle(TubeGeometry(), math.radians(30))
    simulation = Simulation(shape, scene_name="unit", frame_count=FRAMES, seed=7, with_points=True,
                            namespace="/rig", camera_names=("left_cam", "right_cam"))
    path = simulation.write_bag(tmp_path_factory.mktemp("bags") / "unit", progress=False)
    expected = list(simulation.frames())  # deterministic: the same frames again
    return simulation, path, expected


def expected_topics(simulation):
    return {topic_name("/rig", camera, kind): msgtype for camera in simulation.camera_names
            for kind, (_, msgtype) in TOPIC_KINDS.items()}


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_rosbags_reads_topics_types_counts_stamps_and_bytes(written):
    simulation, path, expected = written
    by_topic: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == expected_topics(simulation)
        for connection, _, raw in reader.messages():
            by_topic.setdefault(connection.topic, []).append(reader.deserialize(raw, connection.msgtype))
    assert all(len(messages) == FRAMES for messages in by_topic.values())
    for frame_index in range(FRAMES):
        for frame in expected[frame_index * 2:frame_index * 2 + 2]:
            name = frame.camera.name
            depth = by_topic[topic_name("/rig", name, "depth")][frame_index]
            color = by_topic[topic_name("/rig", name, "color")][frame_index]
            info = by_topic[topic_name("/rig", name, "depth_info")][frame_index]
            assert depth.encoding == "16UC1" and color.encoding == "rgb8"
            assert stamp_ns(depth) == stamp_ns(color) == stamp_ns(info) == frame.stamp_ns
            assert depth.header.frame_id == f"{name}_optical_frame"
            assert bytes(depth.data) == frame.depth_raw.tobytes()
            assert bytes(color.data) == frame.color.tobytes()
            np.testing.assert_allclose(np.asarray(info.k).reshape(3, 3), simulation.intrinsics.matrix())
            xyz, rgb = cloud_from_msg(by_topic[topic_name("/rig", name, "points")][frame_index])
            valid = frame.depth_raw > 0
            assert len(xyz) == valid.sum() and rgb is not None
            np.testing.assert_allclose(np.sort(xyz[:, 2]), np.sort(frame.depth_raw[valid] * 1e-4), atol=1e-6)
    # the two cameras are not synchronised: a few milliseconds apart, 30 fps each
    left = [stamp_ns(m) for m in by_topic[topic_name("/rig", "left_cam", "depth")]]
    right = [stamp_ns(m) for m in by_topic[topic_name("/rig", "right_cam", "depth")]]
    assert all(2e6 < r - lo < 6e6 for lo, r in zip(left, right, strict=True))
    assert 32e6 < left[1] - left[0] < 35e6


def test_mcap_reader_sees_the_same_messages(written):
    simulation, path, expected = written
    typestore = get_typestore(Stores.ROS2_JAZZY)
    mcap_files = list(path.glob("*.mcap"))
    assert len(mcap_files) == 1
    with mcap_files[0].open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        counts: dict[str, int] = {}
        depth_bytes = {}
        for schema, channel, message in reader.iter_messages():
            assert schema.name == expected_topics(simulation)[channel.topic]
            assert channel.message_encoding == "cdr"
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic.endswith("depth/image_rect_raw"):
                msg = typestore.deserialize_cdr(message.data, schema.name)
                assert message.log_time >= stamp_ns(msg)
                depth_bytes[(channel.topic, stamp_ns(msg))] = bytes(msg.data)
    assert counts == dict.fromkeys(expected_topics(simulation), FRAMES)
    for frame in expected:
        key = (topic_name("/rig", frame.camera.name, "depth"), frame.stamp_ns)
        assert depth_bytes[key] == frame.depth_raw.tobytes()


def test_ground_truth_and_rig_configuration_beside_the_bag(written):
    simulation, path, _ = written
    shape, document = load_truth(path)
    np.testing.assert_allclose(shape.notch_bend, simulation.shape.notch_bend)
    assert document["scene"] == "unit" and document["seed"] == 7
    centerline = np.asarray(document["centerline_m"])
    assert np.diff(document["centerline_s_m"]).max() <= 0.1e-3
    np.testing.assert_allclose(centerline[-1], document["tip"]["position_m"], atol=1e-12)
    assert len(document["notches"]) == 16
    config = load_rig_config(path / "rig.yaml")
    assert config.camera_names == ("left_cam", "right_cam")
    assert config.topics.namespace == "/rig"
    assert config.robot == TubeGeometry.from_mapping(document["robot"])
    for name, camera in config.cameras.items():
        truth_camera = document["cameras"][name]
        np.testing.assert_allclose(camera.translation, truth_camera["translation"])
        np.testing.assert_allclose(camera.rotation, truth_camera["rotation"])
        assert camera.depth_unit == truth_camera["depth_unit"] == 1e-4
    json.loads((path / "ground_truth.json").read_text())  # plain JSON
    assert config.filters.clamp_radius == 0.0  # bent 30 deg: the crop box starts at the base plane


def test_the_rig_of_a_robot_curled_below_its_base_plane_gives_its_post():
    """Bent 270 deg, the robot reaches below its base plane: the rig written beside the bag gives the post's
    radius (and a millimetre), so that the crop box reaches there; bent 90 deg it does not."""
    radii = {}
    for bend in (90, 270):
        simulation = Simulation(TubeShape.from_bend_angle(TubeGeometry(), math.radians(bend)), frame_count=1)
        filters = simulation.rig_parameters()["/**"]["ros__parameters"].get("filters", {})
        radii[bend] = filters.get("clamp_radius", 0.0)
    assert radii == {90: 0.0, 270: pytest.approx(RigProps().post_radius + 1e-3)}


def test_simulate_command_refuses_bad_input_clearly(tmp_path, capsys):
    assert cli.main(["simulate", str(tmp_path / "too_far"), "--bend-deg", "500", "--no-progress"]) == 2
    assert "theta_max" in capsys.readouterr().err
    assert not (tmp_path / "too_far").exists()
    (tmp_path / "taken").mkdir()
    assert cli.main(["simulate", str(tmp_path / "taken"), "--frames", "1", "--no-progress"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "x"), "--notch-side", "sideways", "--no-progress"]) == 2
    assert "notch side" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [tmp_path / "taken"]  # nothing half-written left behind


def test_simulate_renders_the_robot_of_a_description_file(tmp_path, capsys):
    """--robot takes a mapping of geometry fields or a rig configuration's robot section; the bag's rig.yaml
    and ground truth then describe that robot, and a bad description is refused naming its field."""
    thin = {"outer_diameter": 2.5e-3, "inner_diameter": 1.8e-3, "notch_count": 10, "notch_width": 1.0e-3,
            "notch_pitch": 2.2e-3, "notch_side": math.radians(20.0)}
    (tmp_path / "thin.yaml").write_text(json.dumps(thin))  # JSON is YAML
    assert cli.main(["simulate", str(tmp_path / "thin"), "--robot", str(tmp_path / "thin.yaml"), "--frames", "1",
                     "--bend-deg", "30", "--no-progress"]) == 0
    robot = load_rig_config(tmp_path / "thin" / "rig.yaml").robot
    for field, value in thin.items():  # notch_side too: from the file, as no --notch-side was given
        assert getattr(robot, field) == pytest.approx(value), field
    shape, _ = load_truth(tmp_path / "thin")
    assert len(shape.notch_bend) == 10 and math.degrees(shape.notch_bend.sum()) == pytest.approx(30.0)
    # a rig configuration works too (its robot section); --notch-side overrides the file's
    assert cli.main(["simulate", str(tmp_path / "again"), "--robot", str(tmp_path / "thin" / "rig.yaml"),
                     "--notch-side", "facing", "--frames", "1", "--no-progress"]) == 0
    again = load_rig_config(tmp_path / "again" / "rig.yaml").robot
    assert again.outer_diameter == 2.5e-3 and again.notch_side == pytest.approx(-math.pi / 2)
    capsys.readouterr()
    (tmp_path / "bad.yaml").write_text("outer_diameter: -0.001\n")
    assert cli.main(["simulate", str(tmp_path / "bad_robot"), "--robot", str(tmp_path / "bad.yaml"),
                     "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "bad.yaml" in error and "robot.outer_diameter" in error
    (tmp_path / "unknown.yaml").write_text("outer_diameter: 0.003\nwall_colour: 3\n")
    assert cli.main(["simulate", str(tmp_path / "bad_robot"), "--robot", str(tmp_path / "unknown.yaml"),
                     "--no-progress"]) == 2
    assert "robot.wall_colour" in capsys.readouterr().err
    assert not (tmp_path / "bad_robot").exists()


def test_simulate_warns_when_the_robot_is_nearer_than_the_d405_sees(tmp_path, capsys):
    assert cli.main(["simulate", str(tmp_path / "near"), "--camera-distance", "0.07", "--frames", "1",
                     "--no-progress"]) == 0
    assert "minimum depth" in capsys.readouterr().err
    assert cli.main(["simulate", str(tmp_path / "far"), "--camera-distance", "0.08", "--frames", "1",
                     "--no-progress"]) == 0
    assert "minimum depth" not in capsys.readouterr().err
    # from 90 mm, bent 90 deg towards cam_a, the distal part comes within 60 mm of it
    assert cli.main(["simulate", str(tmp_path / "bent"), "--bend-deg", "90", "--notch-side", "facing", "--frames",
                     "1", "--no-progress"]) == 0
    error = capsys.readouterr().err
    print(error)
    assert "comes within 59.9 mm of cam_a (at 51.1 mm along it)" in error and "minimum depth (70 mm)" in error


def test_render_command_draws_a_png(written, tmp_path):
    from PIL import Image

    _, path, _ = written
    out = tmp_path / "render.png"
    assert cli.main(["render", str(path), "--out", str(out)]) == 0
    with Image.open(out) as image:
        assert image.format == "PNG"
        assert image.width > 800 and image.height > 400
        pixels = np.asarray(image.convert("RGB"))
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 100  # a drawing, not a blank canvas


def test_a_bag_is_never_written_over_the_current_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(StagingError, match="current or the root directory"):
        write_rig_bag(".", BagContents("/rig", D405Intrinsics(), []), {}, overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]
    assert cli.main(["simulate", ".", "--overwrite", "--frames", "1", "--no-progress"]) == 2
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


def test_an_overwritten_bag_is_replaced_whole_or_kept(tmp_path):
    """--overwrite swaps the new bag in by one rename; a failure while writing leaves the old bag as it was,
    and the staging of a run killed earlier is cleaned up by the next."""
    target = tmp_path / "scene"
    target.mkdir()
    (target / "old.mcap").write_bytes(b"old")
    stale = tmp_path / ".scene.partial-999999999-x"  # no such process: a killed run's leftovers
    stale.mkdir()

    def broken_frames():
        raise RuntimeError("renderer failed")
        yield

    contents = BagContents("/rig", D405Intrinsics(), broken_frames())
    with pytest.raises(RuntimeError, match="renderer failed"):
        write_rig_bag(target, contents, {}, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]
    assert sorted(p.name for p in target.iterdir()) == ["old.mcap"]
    write_rig_bag(target, BagContents("/rig", D405Intrinsics(), []), {"note.txt": "new"}, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]
    assert (target / "note.txt").read_text() == "new" and not (target / "old.mcap").exists()
    assert (target / "metadata.yaml").is_file()
