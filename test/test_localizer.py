"""The node's work without ROS (ros/localizer.py): the worker registers the newest pair and reports
it, a relocalize call waits for the next source, a map is loaded one way whoever asks and the map
in use stays when a new one fails, a hint in another frame is dropped. On the bundled real pair."""
import logging
import threading
import time

import numpy as np
import pytest
from conftest import REPO, samplings

from regor_ros.core import RegistrationError, RegorConfig, SearchRegion, rotation_error_deg, translation_error
from regor_ros.ros.localizer import Localizer
from regor_ros.ros.parameters import make_settings
from regor_ros.ros.source_context import Hint

DEMO = REPO / "demo"
SOURCE, TARGET = np.load(DEMO / "src.npy"), np.load(DEMO / "tgt.npy")
TRUTH = np.loadtxt(DEMO / "gt.txt")
SECOND = 10**9   # [ns]: stamps are exact integers
WAIT_S = 300.0   # a registration takes about a second; the bound only stops a hung test


class Recorder:
    """The node's side: what the localizer reports."""

    def __init__(self):
        self.outcomes, self.maps, self.checks = [], [], []

    def wait_for_outcomes(self, count: int):
        deadline = time.monotonic() + WAIT_S
        while len(self.outcomes) < count and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(self.outcomes) >= count, "no registration reported"
        return self.outcomes[count - 1]


def started(**settings):
    recorder = Recorder()
    localizer = Localizer(RegorConfig.preset("indoor"), make_settings(settings), logging.getLogger("localizer"),
                          recorder.outcomes.append, lambda prepared, frame: recorder.maps.append((prepared, frame)),
                          recorder.checks.append)
    localizer.configure()
    localizer.set_active(True)
    return localizer, recorder


def test_the_worker_registers_the_newest_pair_and_reports_the_pose():
    localizer, recorder = started()
    try:
        localizer.store("target", "map", SECOND, TARGET)
        localizer.store("source", "camera", SECOND, SOURCE)
        outcome = recorder.wait_for_outcomes(1)
    finally:
        localizer.stop(5.0)
    assert outcome.result.accepted and outcome.pose is not None and outcome.target_frame == "map"
    T, covariance = outcome.pose.transform, outcome.pose.covariance
    assert rotation_error_deg(T, TRUTH) < 5 and translation_error(T, TRUTH) < 0.1
    assert covariance.shape == (6, 6)
    assert outcome.status["source_frame"] == "camera" and outcome.status["registrations"] == 1
    assert outcome.answer.startswith("pose published (carried by its feature matches")


def test_on_demand_a_relocalize_call_waits_for_the_next_source():
    localizer, recorder = started(registration="on_demand")
    try:
        localizer.store("target", "map", SECOND, TARGET)
        localizer.store("source", "camera", SECOND, SOURCE)
        time.sleep(0.5)
        assert not recorder.outcomes   # on demand: nothing registered without a call
        answers = []
        call = threading.Thread(target=lambda: answers.append(localizer.relocalize()))
        call.start()
        time.sleep(0.5)
        localizer.store("source", "camera", 2 * SECOND, SOURCE)   # the scan after the call
        call.join(WAIT_S)
    finally:
        localizer.stop(5.0)
    assert answers and answers[0].accepted and answers[0].text.startswith("pose published")
    assert len(recorder.outcomes) == 1


def test_a_hint_in_another_frame_is_dropped_with_a_warning(caplog):
    localizer, recorder = started()
    try:
        localizer.context.set_hint(Hint("odom", SearchRegion.checked((0.0, 0.0, 0.0), 1.0)))
        localizer.store("target", "map", SECOND, TARGET)
        localizer.store("source", "camera", SECOND, SOURCE)
        outcome = recorder.wait_for_outcomes(1)
    finally:
        localizer.stop(5.0)
    assert outcome.status["search_region"] is None and localizer.report.stats["bad_inputs"] == 1
    assert "initial_guess dropped: it is in 'odom', the target cloud in 'map'" in caplog.text


def test_a_map_is_loaded_one_way_and_the_map_in_use_stays_when_a_new_one_fails(tmp_path):
    localizer, recorder = started(mode="map")
    try:
        with pytest.raises(FileNotFoundError):
            localizer.maps.use_url(str(tmp_path / "missing.npy"))
        assert localizer.maps.prepared is None
        map_file = tmp_path / "room.npy"
        np.save(map_file, TARGET)
        localizer.maps.use_url(f"file://{map_file}")
        in_use = localizer.maps.prepared
        assert in_use is not None and localizer.shared.settings.map_file == str(map_file)
        assert localizer.report.health.map_from_file and len(recorder.maps) == 1   # active: the map goes out
        junk = tmp_path / "junk.npy"
        junk.write_bytes(np.random.default_rng(0).bytes(4096))
        with pytest.raises(RegistrationError):
            localizer.maps.use_url(str(junk))
        assert localizer.maps.prepared is in_use and localizer.shared.settings.map_file == str(map_file)
        localizer.store("source", "camera", SECOND, SOURCE)   # registered against the map file
        outcome = recorder.wait_for_outcomes(1)
    finally:
        localizer.stop(5.0)
    assert outcome.target_frame == localizer.shared.settings.map_frame
    assert outcome.status["map_keypoints"] == len(in_use)


def test_a_scan_waits_for_the_odometry_that_places_it_and_no_longer_than_odometry_wait():
    """A lidar-inertial odometry publishes a scan's pose after the scan: the worker waits for it
    and fuses; when it never comes (the odometry stopped) the worker waits odometry_wait and
    registers the scan alone, saying why."""
    localizer, recorder = started(accumulate_scans=2, odometry_wait=3.0)
    try:
        localizer.store("target", "map", SECOND, TARGET)
        localizer.context.add_odometry(1.0, np.eye(4))
        localizer.store("source", "camera", SECOND, SOURCE)        # its odometry is there: no wait
        first = recorder.wait_for_outcomes(1)
        localizer.store("target", "map", 2 * SECOND, TARGET)
        localizer.store("source", "camera", 2 * SECOND, SOURCE)    # the odometry stopped
        stopped = recorder.wait_for_outcomes(2)
        localizer.store("target", "map", 3 * SECOND, TARGET)
        localizer.store("source", "camera", 3 * SECOND, SOURCE)
        time.sleep(0.2)
        localizer.context.add_odometry(3.0, np.eye(4))            # logged after its scan
        late = recorder.wait_for_outcomes(3)
    finally:
        localizer.stop(5.0)
    assert first.status["accumulation"]["alone"] == "no earlier scan to fuse"
    alone = stopped.status["accumulation"]
    assert alone["alone"] == "no odometry at or after the scan's stamp" and alone["waited_for_odometry_s"] >= 3.0
    assert "the newest is 1.000 s before it" in alone["reason"]
    fused = late.status["accumulation"]
    assert fused["scans_fused"] == 2 and "alone" not in fused and 0 < fused["waited_for_odometry_s"] < 3.0
    assert late.status["registered_alone_because"] == {"no earlier scan to fuse": 1,
                                                       "no odometry at or after the scan's stamp": 1}
    assert late.status["registrations_fused"] == 1 and late.status["registrations_alone"] == 2
    assert late.result.accepted


def test_an_imu_without_the_maps_up_is_said_to_leave_the_prior_off():
    from regor_ros.ros.parameters import unused_settings
    with_imu = make_settings({"imu_topic": "/imu/data", "mode": "map"})
    said = unused_settings(RegorConfig.preset("outdoor"), with_imu)
    assert len(said) == 1 and "gravity.target_up is unknown" in said[0] and "'0 0 1'" in said[0]
    assert unused_settings(RegorConfig.preset("outdoor").replace({"gravity.target_up": "0 0 1"}), with_imu) == []
    assert unused_settings(RegorConfig.preset("outdoor"), make_settings({})) == []


def test_without_odometry_the_first_registration_gathers_the_scans_at_rest_and_fuses_them():
    """A robot switched on at rest, no odometry: the worker waits for accumulate_scans scans (up to
    rest_wait), sees from the scans that the sensor did not move, and registers them fused. A scan
    after the sensor moved is registered alone, saying so."""
    localizer, recorder = started(accumulate_scans=3, rest_wait=60.0)
    try:
        localizer.store("target", "map", SECOND, TARGET)
        said = []
        for k, frame in enumerate(samplings(SOURCE, 3)):
            localizer.store("source", "camera", SECOND + k * SECOND // 10, frame)
            time.sleep(0.2)   # the worker could take each: it waits for the rest
            said.append(localizer.report.health.gathering)   # what /diagnostics says meanwhile
        fused = recorder.wait_for_outcomes(1)
        localizer.store("target", "map", 2 * SECOND, TARGET)
        localizer.store("source", "camera", 2 * SECOND, SOURCE + np.array([0.5, 0.0, 0.0]))
        moved = recorder.wait_for_outcomes(2)
    finally:
        localizer.stop(5.0)
    assert fused.status["accumulation"] == {"scans_fused": 3, "without_odometry": 0, "at_rest": True,
                                            "more_to_fuse": 0, "waited_for_odometry_s": fused.status[
                                                "accumulation"]["waited_for_odometry_s"]}
    assert said[:2] == [f"no odometry: gathering scans at rest before the first registration, {k} of 3"
                        for k in (1, 2)], said
    assert fused.status["registrations_fused_at_rest"] == 1 and fused.source.stamp_ns == SECOND + 2 * SECOND // 10
    assert fused.result.accepted and rotation_error_deg(fused.result.transform, TRUTH) < 5
    assert translation_error(fused.result.transform, TRUTH) < 0.1
    alone = moved.status["accumulation"]
    assert alone["alone"] == "no odometry received" and "the scans show motion" in alone["reason"], alone


def test_the_wait_for_scans_at_rest_is_bounded_by_rest_wait():
    localizer, recorder = started(accumulate_scans=3, rest_wait=1.0)
    try:
        localizer.store("target", "map", SECOND, TARGET)
        start = time.monotonic()
        localizer.store("source", "camera", SECOND, SOURCE)
        alone = recorder.wait_for_outcomes(1)
        waited = time.monotonic() - start
    finally:
        localizer.stop(5.0)
    assert waited >= 1.0 and alone.result.accepted
    assert alone.status["accumulation"]["alone"] == "no odometry received"
