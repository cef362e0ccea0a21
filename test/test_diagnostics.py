"""The /diagnostics status for each state of the node (levels and messages a monitor shows)."""
import dataclasses
import time

from diagnostic_msgs.msg import DiagnosticStatus

from regor_ros.core import Figures, Summary
from regor_ros.core.gate.visibility import VisibilityFigures
from regor_ros.ros.diagnostics import Health, diagnostic_status, seconds_since_process_start

SUMMARY = Summary(accepted=False, reason="only 12 feature matches agree with the pose",
                  failed_check="min_feature_inliers", carried_by="", singled_out=False, ambiguity=None,
                  figures=Figures(num_inliers=300, fitness=0.2, surface_agreement=1.0, log10_false_alarms=-1.0,
                                  independent_agreeing=10, feature_inliers=12, free_space_source=0.01,
                                  opposite_sides=0.0),
                  visibility=VisibilityFigures(0.01, None, 0.0), timings={"total": 1.5})
PUBLISHED = dataclasses.replace(SUMMARY, accepted=True, reason="", failed_check="")


def status(**state):
    return diagnostic_status(Health(**{"lifecycle": "active", **state}), "/register_node")


def test_each_state_has_its_level_and_reason():
    waiting = status()
    assert waiting.level == DiagnosticStatus.WARN and "source_cloud and target_cloud" in waiting.message
    preparing = status(counters={"source_clouds": 1, "target_clouds": 1}, preparing_map=True)
    assert preparing.level == DiagnosticStatus.WARN and "map" in preparing.message
    withheld = status(counters={"source_clouds": 2, "target_clouds": 1}, last_summary=SUMMARY)
    assert withheld.level == DiagnosticStatus.WARN and "12 feature matches" in withheld.message
    gathering = status(counters={"source_clouds": 1, "target_clouds": 1},
                       gathering="no odometry: gathering scans at rest before the first registration, 1 of 5")
    assert gathering.level == DiagnosticStatus.WARN and gathering.message.endswith("1 of 5")
    published = status(counters={"source_clouds": 2, "target_clouds": 1}, last_summary=PUBLISHED)
    assert published.level == DiagnosticStatus.OK
    malformed = status(counters={"source_clouds": 3, "target_clouds": 1}, last_summary=SUMMARY,
                       last_bad_input="no x field")
    assert malformed.level == DiagnosticStatus.WARN and "no x field" in malformed.message
    failed = status(counters={"source_clouds": 3, "target_clouds": 1}, last_error="source: the cloud is empty")
    assert failed.level == DiagnosticStatus.ERROR and "empty" in failed.message
    values = {kv.key: kv.value for kv in withheld.values}
    assert values["last verdict"] == "rejected" and values["seconds total"] == "1.5"
    assert values["source_clouds"] == "2"
    assert values["inliers"] == "300" and values["worst free space"] == "0.01"


def test_map_mode_reports_the_prepared_map():
    prepared = status(counters={"source_clouds": 1, "target_clouds": 1}, last_summary=PUBLISHED,
                      map_info={"map_points": 207000, "map_keypoints": 42687, "map_preparation_seconds": 1.6})
    values = {kv.key: kv.value for kv in prepared.values}
    assert values["map_keypoints"] == "42687" and values["map_preparation_seconds"] == "1.6"


def test_time_to_ready_counts_from_the_process_start():
    """This test process imported pytest, numpy and rclpy before it got here: its age is more than
    the time since this test began, and it grows."""
    began = time.monotonic()
    age = seconds_since_process_start()
    assert age is not None and age > time.monotonic() - began
    time.sleep(0.05)
    assert seconds_since_process_start() > age
    ready = status(ready_after_s=3.25)
    assert {kv.key: kv.value for kv in ready.values}["ready after seconds"] == "3.25"


def test_lifecycle_states_and_a_map_file_say_what_the_node_is_doing():
    failed = status(lifecycle="configure failed: map_file not usable: /maps/x.pcd: no such file")
    assert failed.level == DiagnosticStatus.ERROR and "no such file" in failed.message
    waiting = status(lifecycle="unconfigured")
    assert waiting.level == DiagnosticStatus.WARN and "unconfigured" in waiting.message
    from_file = status(map_from_file=True)
    assert "source_cloud" in from_file.message and "target_cloud" not in from_file.message


def test_the_watchdog_is_a_second_status_with_its_level():
    """OK verified (the correction reported), WARN suspect, ERROR lost, STALE not checked."""
    from builtin_interfaces.msg import Time

    from regor_ros.ros.diagnostics import WATCHDOG_NAME, diagnostic_array
    from regor_ros.ros.watchdog import Check
    health = Health(lifecycle="active", counters={"source_clouds": 1}, map_from_file=True)
    assert [s.name for s in diagnostic_array(health, "/register_node", Time()).status] != [WATCHDOG_NAME]
    levels = {}
    for state, reason in (("verified", ""), ("suspect", "surfaces pass through each other"),
                          ("lost", "surfaces pass through each other"), ("unchecked", "no pose has arrived")):
        checked = state != "unchecked"
        health.watchdog = Check(state, reason, 10.0, 10.0 if checked else None, 3 if state == "lost" else 0,
                                (0.12, 0.4) if checked else None)
        statuses = diagnostic_array(health, "/register_node", Time()).status
        assert len(statuses) == 2 and statuses[1].name == WATCHDOG_NAME
        levels[state] = statuses[1]
    assert [levels[s].level for s in ("verified", "suspect", "lost", "unchecked")] == \
        [DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE]
    assert "relocalizing" in levels["lost"].message and "no pose has arrived" in levels["unchecked"].message
    assert {kv.key: kv.value for kv in levels["verified"].values}["correction m"] == "0.12"
