"""regor-replay on rosbag2 recordings written here from shared sequences as a robot records them
(tools/robot_recording.py): MCAP and sqlite3, odometry logged before, with and after its scans (a
lidar-inertial odometry logs a scan's pose after the scan), faster wheel odometry, a gap, an
odometry that stops, an IMU at its own rate; and the inputs it refuses in one line."""
import csv

import numpy as np
import pytest
from conftest import DATA, require_shared_data

from regor_ros.bench.robot_recording import RecordedSequence, Recording, load_recorded_sequence, write_recording
from regor_ros.tools.replay import main

WINTER = DATA / "xseason" / "eth_gazebo_summer_winter"
AVIA = DATA / "maps" / "fastlio_avia_hku2"
SCANS = 5   # the first winter scans


def winter(path, storage="mcap", **recording):
    require_shared_data("the replay tests")
    return write_recording(path, load_recorded_sequence(WINTER).part(0, SCANS), Recording(**recording), storage)


def avia(path, first=14, count=6, **recording):
    """Six consecutive Livox Avia scans ending with scan 39, which alone is not found in its map
    (test_node's accumulation test) and fused with the four before it is."""
    require_shared_data("the replay tests")
    return write_recording(path, load_recorded_sequence(AVIA).part(first, count), Recording(**recording))


def replay(bag, out, *extra, folder=WINTER):
    return main([str(bag), "--map", str(folder / "map.npy"), "--map-trajectory", str(folder / "map_trajectory.txt"),
                 "--scan-topic", "/points", "--preset", "outdoor", "--set", "map_cache=false", "--quiet",
                 "--out", str(out), *map(str, extra)])


def table(out):
    return list(csv.DictReader(open(out / "registrations.csv")))


def test_an_mcap_recording_is_replayed_with_odometry_and_scored_against_its_reference(tmp_path, capsys):
    bag = winter(tmp_path / "winter")
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", "--reference-topic", "/truth") == 0
    rows = table(tmp_path / "out")
    assert len(rows) == SCANS and all(r["accepted"] == "True" and r["agrees"] == "True" for r in rows), rows
    assert all(float(r["reference_translation_error_m"]) < 0.6 for r in rows)
    assert [int(r["scans_fused"]) for r in rows] == [1, 2, 3, 4, 5]
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert f"{SCANS} of {SCANS} published poses agree" in summary and "no odometry" not in summary
    assert "4 relocalizations fused 2-5 scans, 1 registered alone: 1 no earlier scan to fuse" in summary
    assert (tmp_path / "out" / "map.png").stat().st_size > 10_000
    assert summary in capsys.readouterr().out


def test_a_sqlite3_recording_without_odometry_every_two_tenths_of_a_second(tmp_path):
    bag = winter(tmp_path / "winter", "sqlite3", odometry=None)
    assert replay(bag, tmp_path / "out", "--every", 0.2, "--reference-topic", "/truth") == 0
    rows = table(tmp_path / "out")
    assert [round(float(r["stamp"]), 1) for r in rows] == [100.0, 100.2, 100.4]
    assert all(r["registered_alone_because"] == "no odometry received" for r in rows[1:])
    assert "no odometry: every scan was registered alone" in (tmp_path / "out" / "summary.md").read_text()


def test_the_reference_from_a_tum_file_scores_as_the_topic_does(tmp_path):
    from regor_ros.io.map_file import write_trajectory
    require_shared_data("the replay tests")
    sequence = load_recorded_sequence(WINTER).part(0, SCANS)
    bag = winter(tmp_path / "winter")
    write_trajectory(tmp_path / "truth.txt", sequence.truth, sequence.stamps)
    assert replay(bag, tmp_path / "file", "--odom-topic", "/odom", "--reference-file", tmp_path / "truth.txt") == 0
    assert replay(bag, tmp_path / "topic", "--odom-topic", "/odom", "--reference-topic", "/truth") == 0
    by_file, by_topic = table(tmp_path / "file"), table(tmp_path / "topic")
    assert [r["agrees"] for r in by_file] == [r["agrees"] for r in by_topic] == ["True"] * SCANS
    assert [r["reference_translation_error_m"][:8] for r in by_file] == \
        [r["reference_translation_error_m"][:8] for r in by_topic]


def test_odometry_logged_before_with_or_after_its_scans_gives_the_same_poses(tmp_path):
    """Stamps decide: a LIO logs each scan's odometry tens of milliseconds after the scan. Replayed
    in log order that scan would have no odometry yet and be registered alone; it is fused."""
    poses = {}
    for order in ("before", "with", "after"):
        bag = avia(tmp_path / order, odometry=order)
        assert replay(bag, tmp_path / f"out_{order}", "--odom-topic", "/odom", "--reference-topic", "/truth",
                      folder=AVIA) == 0
        rows = table(tmp_path / f"out_{order}")
        assert [int(r["scans_fused"]) for r in rows] == [1, 2, 3, 4, 5, 5], (order, rows)
        assert rows[-1]["accepted"] == "True" and rows[-1]["agrees"] == "True", rows[-1]
        poses[order] = [(r["accepted"], r["x"], r["y"], r["qw"]) for r in rows]
    assert poses["before"] == poses["with"] == poses["after"]


def test_wheel_odometry_at_50_hz_places_the_10_hz_scans_between_its_messages(tmp_path):
    bag = avia(tmp_path / "wheel", odometry="after", odometry_rate=50.0)
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", "--reference-topic", "/truth", folder=AVIA) == 0
    rows = table(tmp_path / "out")
    assert [int(r["scans_fused"]) for r in rows[1:]] == [2, 3, 4, 5, 5] and rows[-1]["agrees"] == "True", rows


def test_a_gap_in_the_odometry_and_an_odometry_that_stops_are_said(tmp_path):
    require_shared_data("the replay tests")
    sequence = load_recorded_sequence(AVIA).part(14, 6)
    since = sequence.stamps - sequence.stamps[0]
    gap = avia(tmp_path / "gap", odometry="after", odometry_rate=50.0,
               odometry_gap=(since[3] - 0.15, since[3] + 0.15))
    assert replay(gap, tmp_path / "out_gap", "--odom-topic", "/odom", folder=AVIA) == 0
    rows = table(tmp_path / "out_gap")
    assert rows[3]["registered_alone_because"] == "a gap in the odometry at the scan's stamp", rows[3]
    assert "a gap in the odometry" in rows[3]["reason"] or rows[3]["accepted"] == "True"
    assert rows[4]["scans_fused"] != "1"   # the scans around the gap are fused again, the one in it skipped
    stops = avia(tmp_path / "stops", odometry="after", odometry_stops=since[2] + 0.01)
    assert replay(stops, tmp_path / "out_stops", "--odom-topic", "/odom", folder=AVIA) == 0
    rows = table(tmp_path / "out_stops")
    assert [r["registered_alone_because"] for r in rows[3:]] == ["no odometry at or after the scan's stamp"] * 3
    summary = (tmp_path / "out_stops" / "summary.md").read_text()
    assert "3 no odometry at or after the scan's stamp" in summary, summary


def test_the_imu_in_the_recording_gives_each_scan_its_up(tmp_path):
    """A 200 Hz IMU reporting no orientation, its up 2 deg off the truth's: the gravity prior takes
    the mean acceleration before each scan, the map's up given."""
    bag = avia(tmp_path / "imu", odometry=None, imu_rate=200.0, imu_tilt_deg=2.0)
    assert replay(bag, tmp_path / "out", "--imu-topic", "/imu", "--set", "gravity.target_up=0 0 1",
                  "--reference-topic", "/truth", folder=AVIA) == 0
    rows = table(tmp_path / "out")
    assert all(r["source_up_from"] == "mean IMU acceleration of 201 messages" for r in rows), rows
    assert all(r["agrees"] == "True" for r in rows if r["accepted"] == "True")
    assert "721 IMU messages" in (tmp_path / "out" / "summary.md").read_text()


@pytest.mark.parametrize("case, says", [
    ("missing topic", "--scan-topic '/velodyne_points' is not in the bag (its topics: /odom, /points, /truth)"),
    ("no xyz", "cannot be read: no z field"),
    ("truncated", "cannot be read as a rosbag2"),
    ("no metadata", "a folder without metadata.yaml, not a rosbag2; give one of its recordings instead: winter.mcap"),
])
def test_what_cannot_be_replayed_is_said_in_one_line_and_nothing_is_written(tmp_path, capsys, case, says):
    bag = tmp_path / "winter"
    winter(bag, cloud_fields="xyw" if case == "no xyz" else "xyz")
    if case == "truncated":
        recording = next(bag.glob("*.mcap"))
        recording.write_bytes(recording.read_bytes()[:2000])
    if case == "no metadata":
        (bag / "metadata.yaml").unlink()
    topic = ["--scan-topic", "/velodyne_points"] if case == "missing topic" else []
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", *topic) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("case, says", [
    ("no bag", "winter: no such file or folder"),
    ("empty map", "map.npy: no points (an empty array)"),
    ("reference csv", "a CSV needs the columns stamp, x, y, z, qx, qy, qz, qw (missing: qw)"),
])
def test_what_a_clone_without_the_shared_data_refuses_in_one_line(tmp_path, capsys, case, says):
    """Bad inputs a user meets first, with no recording of the shared data needed."""
    np.save(tmp_path / "map.npy", np.zeros((0, 3), np.float32) if case == "empty map" else
            np.random.default_rng(0).normal(size=(100, 3)).astype(np.float32))
    (tmp_path / "ref.csv").write_text("stamp,x,y,z,qx,qy,qz\n1,0,0,0,0,0,0\n")
    bag = tmp_path / "winter"
    if case != "no bag":   # one scan of random points
        scan = np.random.default_rng(1).normal(size=(500, 3)).astype(np.float32)
        write_recording(bag, RecordedSequence(np.array([100.0]), [scan], np.eye(4)[None], np.eye(4)[None]),
                        Recording(odometry=None))
    extra = ["--reference-file", tmp_path / "ref.csv"] if case == "reference csv" else []
    code = main([str(bag), "--map", str(tmp_path / "map.npy"), "--scan-topic", "/points", "--quiet",
                 "--out", str(tmp_path / "out"), *map(str, extra)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and says in err and "\n" not in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


def test_the_watchdog_on_a_recording_says_when_the_stack_is_lost_and_relocalizes(tmp_path):
    """The stack's pose is right for two scans, then 10 m off: suspect, then lost (lost_after=2),
    and the scan that finds it lost is registered (the relocalization)."""
    bag = winter(tmp_path / "winter", tracked_shift=(0.0, 0.0, 10.0, 10.0, 10.0))
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", "--tracked-topic", "/amcl_pose",
                  "--every", 1000, "--set", "lost_after=2") == 0
    checks = list(csv.DictReader(open(tmp_path / "out" / "watchdog.csv")))
    assert [c["watchdog"] for c in checks] == ["verified", "verified", "suspect", "lost", "suspect"], checks
    rows = table(tmp_path / "out")
    assert [round(float(r["stamp"]), 1) for r in rows] == [100.0, 100.3]   # the first scan, and the relocalization
    assert all(r["accepted"] == "True" for r in rows)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "5 checks of the stack's pose: 2 verified, 2 suspect, 1 lost" in summary
