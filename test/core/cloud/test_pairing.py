"""core.cloud.pairing.FramePairer without ROS: pairs by stamp within the slop, a lost partner counted (or released
alone on request), a silent camera judged by the other cameras' stamps and its own rate, bounded buffers, a
jump back of the stamps restarting the pairing."""

from __future__ import annotations

import pytest

from ntcr_recon.core.cloud.pairing import FramePairer

PERIOD = 33_333_333  # 30 Hz
SLOP = 10_000_000
TIMEOUT = 300_000_000


def pairer(**options) -> FramePairer:
    return FramePairer(("cam_a", "cam_b"), SLOP, TIMEOUT, **options)


def test_frames_within_the_slop_are_released_as_a_pair_when_the_second_arrives():
    p = pairer()
    assert p.add("cam_a", 1000 * PERIOD, "a0").release is None  # cam_b may still send its frame
    step = p.add("cam_b", 1000 * PERIOD + 4_000_000, "b0")
    assert step.release is not None and step.release.reason == "pair"
    assert step.release.items == {"cam_a": "a0", "cam_b": "b0"} and step.release.missing == ()
    assert step.release.stamp_ns == 1000 * PERIOD
    assert p.counts["pairs"] == 1


def test_a_frame_whose_partner_was_lost_is_counted_not_released_unless_asked():
    for publish_unpaired in (False, True):
        p = pairer(publish_unpaired=publish_unpaired)
        p.add("cam_a", 0, "a0")
        p.add("cam_a", PERIOD, "a1")
        step = p.add("cam_b", PERIOD, "b1")  # cam_b's frame 0 never came, and cam_b has moved on
        assert step.release.items == {"cam_a": "a1", "cam_b": "b1"}
        if publish_unpaired:  # released too, but superseded by the newer pair of the same step
            assert p.counts["superseded"] == 1 and p.counts["unpaired"] == 0
        else:
            assert p.counts["unpaired"] == 1 and p.counts["superseded"] == 0


def test_a_silent_camera_is_judged_by_the_other_cameras_stamps_and_the_other_goes_alone():
    p = pairer()
    for i in range(5):
        p.add("cam_a", i * PERIOD, f"a{i}")
        p.add("cam_b", i * PERIOD, f"b{i}")
    assert p.counts["pairs"] == 5 and not p.silent
    releases, silent_at = [], None
    for i in range(5, 30):  # cam_b stops; cam_a goes on
        step = p.add("cam_a", i * PERIOD, f"a{i}")
        if step.newly_silent:
            silent_at = i
            assert step.newly_silent == ["cam_b"]
        if step.release is not None:
            releases.append(step.release)
    # Silent once cam_a's stamps are more than the timeout plus one of cam_b's periods past cam_b's last frame,
    # however long the machine took to deliver them (no wall clock in this test at all).
    assert silent_at == 4 + (TIMEOUT + PERIOD) // PERIOD + 1
    assert releases and all(r.missing == ("cam_b",) and r.reason == "silent: cam_b" for r in releases)
    assert p.lag_s("cam_b") == pytest.approx(25 * PERIOD * 1e-9)
    step = p.add("cam_b", 30 * PERIOD, "b30")
    assert step.back == ["cam_b"] and not p.silent


def test_a_late_frame_still_pairs_while_its_camera_is_within_the_timeout():
    p = pairer()
    for i in range(5):  # cam_a runs ahead by five frames (150 ms < timeout): nothing is released alone
        assert p.add("cam_a", i * PERIOD, f"a{i}").release is None
    step = p.add("cam_b", 4 * PERIOD, "b4")
    assert step.release.items == {"cam_a": "a4", "cam_b": "b4"}
    assert p.counts["unpaired"] == 4 and p.counts["alone"] == 0 and not p.silent


def test_buffers_are_bounded_and_the_oldest_frame_goes_first():
    p = pairer(queue_size=3)
    for i in range(8):
        p.add("cam_a", i * PERIOD, f"a{i}")
    assert p.counts["queue_overflow"] == 5
    step = p.add("cam_b", 7 * PERIOD, "b7")
    assert step.release.items["cam_a"] == "a7"


def test_stamps_jumping_back_restart_the_pairing():
    p = pairer()
    p.add("cam_a", 100 * PERIOD, "a")
    step = p.add("cam_a", 10 * PERIOD, "again")
    assert step.restarted_after_jump_s == pytest.approx(90 * PERIOD * 1e-9)
    assert p.add("cam_b", 10 * PERIOD, "b").release.items == {"cam_a": "again", "cam_b": "b"}


def test_an_unknown_camera_is_refused_by_name():
    with pytest.raises(ValueError, match="'cam_z'"):
        pairer().add("cam_z", 0, None)


def test_what_was_in_force_at_a_stamp_whatever_order_it_came_in():
    from ntcr_recon.core.cloud.pairing import InForce

    infos = InForce(history=3)
    assert infos.at(10) is None and not infos
    infos.add(20, "b")               # came after data stamped 10: the nearest later one is in force there
    assert infos.at(10) == (20, "b") and infos.any_after(10) and not infos.any_after(20)
    infos.add(10, "a")               # written after the later one, as a recording may
    assert infos.at(10) == (10, "a") and infos.at(15) == (10, "a") and infos.at(25) == (20, "b")
    infos.add(30, "c")
    infos.add(40, "d")               # bounded: the first to come goes first (20 here)
    assert infos.at(25) == (10, "a") and infos.at(45) == (40, "d")


def test_the_item_stamped_nearest_a_stamp_within_a_slop():
    from ntcr_recon.core.cloud.pairing import InForce

    images = InForce(history=3)
    assert images.nearest(10, 5) is None
    images.add(10, "a")
    images.add(22, "b")              # a pair's stamp is its earliest frame's: the other camera's comes later
    assert images.nearest(20, 5) == (22, "b") and images.nearest(14, 5) == (10, "a")
    assert images.nearest(18, 5) == (22, "b")
    assert images.nearest(40, 5) is None  # none within the slop: no item rather than a stale one
