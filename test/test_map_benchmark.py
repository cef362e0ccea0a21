"""regor-bench --maps and --map-scaling end to end on a real sequence cut to two queries."""
import csv
import json

import numpy as np
import pytest
from conftest import DATA, require_shared_data

from regor_ros.bench.cli import main
from regor_ros.bench.datasets import NARROW_STEP_DEG, imu_up, narrow_view, tiled

SEQUENCE = "avia_hku2_loop"   # the loop's way back (revisit/): queries metres from the map's poses
QUERIES = ["scan_000180", "scan_000200"]  # one Regor registers, one it does not alone (measured)
SOURCE = DATA / "revisit" / SEQUENCE


def short_sequence(root):
    """The real sequence with only QUERIES, as a maps folder of its own."""
    require_shared_data("the map benchmark tests")
    source = SOURCE
    folder = root / "maps" / SEQUENCE
    (folder / "queries").mkdir(parents=True)
    for name in ("map.npy", "map_trajectory.txt", "odometry.txt", "scans"):
        (folder / name).symlink_to(source / name)
    listing = [q for q in json.loads((source / "queries.json").read_text()) if q["id"] in QUERIES]
    (folder / "queries.json").write_text(json.dumps(listing))
    for query in QUERIES:
        (folder / "queries" / query).symlink_to(source / "queries" / query)
    return folder


def test_maps_mode_registers_every_query_alone_and_fused_and_writes_its_reports(tmp_path):
    folder = short_sequence(tmp_path)
    assert main(["--maps", str(folder.parent), "--methods", "regor,kiss-matcher", "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "maps.csv")))
    assert [(r["method"], r["query"].split("/")[1], r["input"]) for r in rows] == \
        [(m, q, i) for m in ("regor", "kiss-matcher") for q in QUERIES for i in ("single", "sequence")]
    regor = {(r["query"].split("/")[1], r["input"]): r for r in rows if r["method"] == "regor"}
    assert regor["scan_000180", "single"]["success"] == "True" and regor["scan_000180", "single"]["accepted"] == "True"
    assert regor["scan_000200", "single"]["accepted"] == "False"        # wrong alone: not published
    fused = regor["scan_000200", "sequence"]                             # found with the scans before it
    assert fused["success"] == "True" and fused["accepted"] == "True" and fused["scans"] == "5"
    assert float(regor["scan_000180", "single"]["map_seconds"]) > 0
    assert int(regor["scan_000180", "single"]["map_keypoints"]) > 10000
    # the gate's figures whatever the verdict, both sides: the map is seen from the pose
    assert float(regor["scan_000180", "single"]["map_seen"]) > 0.9
    right, wrong = regor["scan_000180", "single"], regor["scan_000200", "single"]
    assert wrong["failed_check"] and wrong["reason"] and not right["failed_check"]   # said why it was withheld
    assert 0 < float(right["seconds_matching"]) < float(right["seconds"])
    assert all(0.1 < float(r["peak_memory_gb"]) < 5 for r in rows)
    assert {r["set"] for r in rows} == {"same"}   # one sequence: no other map to cross with
    report = (tmp_path / "out" / "maps.md").read_text()
    assert "| regor | single | 2 | 1 | 1 / 0 |" in report and "| regor | sequence | 2 | 2 | 2 / 0 |" in report
    assert "median seconds per stage" in report
    assert 0 < float(regor["scan_000180", "single"]["error_sigmas"]) < 4.1   # the error against the covariance
    assert "regor's covariance against the truth: 3 of 3 published correct poses" in report
    assert (tmp_path / "out" / "maps.png").stat().st_size > 1000


def test_the_cross_map_set_registers_each_sequence_against_the_other_maps(tmp_path):
    """Two copies of one sequence under different names: each one's queries against the other's map."""
    folder = short_sequence(tmp_path)
    twin = folder.parent / "copy_of_it"
    twin.symlink_to(folder, target_is_directory=True)
    assert main(["--maps", str(folder.parent), "--methods", "regor", "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "maps.csv")))
    cross = [r for r in rows if r["set"] == "cross"]
    assert len(cross) == 2 * 2 * 2 and all(r["success"] == "False" for r in cross)
    assert "## Cross-map" in (tmp_path / "out" / "maps.md").read_text()


def test_map_scaling_tiles_the_map_and_scores_against_any_copy(tmp_path):
    folder = short_sequence(tmp_path)
    assert main(["--map-scaling", str(folder), "--tiles", "1", "2", "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "map_scaling.csv")))
    assert [int(r["tiles"]) for r in rows] == [1, 2]
    assert int(rows[1]["map_points"]) == 2 * int(rows[0]["map_points"])
    assert int(rows[0]["queries"]) == 2 and int(rows[0]["correct"]) >= 1 and int(rows[1]["correct"]) >= 1
    # the queries ran against the map loaded from its cache (a warm start); a bigger map, a bigger cache
    assert float(rows[1]["cache_mb"]) > float(rows[0]["cache_mb"]) > 0
    # each start's peak is measured in a process of its own
    assert all(0.1 < float(r["cold_peak_memory_gb"]) < 5 and 0.1 < float(r["peak_memory_gb"]) < 5 for r in rows)


def test_tiles_are_turned_copies_far_apart():
    cloud = np.random.default_rng(0).uniform(-10, 10, (100, 3))
    big, poses = tiled(cloud, 3)
    assert big.shape == (300, 3) and len(poses) == 3
    for k, pose in enumerate(poses):
        np.testing.assert_allclose(big[100 * k:100 * (k + 1)], cloud @ pose[:3, :3].T + pose[:3, 3])
    assert np.linalg.norm(poses[1][:3, 3] - poses[0][:3, 3]) >= 400.0


def test_the_stress_set_enlarges_each_map_with_the_other_places_and_thins_the_scans(tmp_path):
    """The Avia sequence's map with the MulRan map beside it (the true place still inside): its
    queries single, thinned and fused against the enlarged map; no cross-map set."""
    folder = short_sequence(tmp_path)
    other = folder.parent / "scaloam_mulran_kaist03"
    other.symlink_to(DATA / "maps" / "scaloam_mulran_kaist03", target_is_directory=True)
    assert main(["--maps", str(folder.parent), "--stress", "--pairs", "avia", "--methods", "regor",
                 "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "stress.csv")))
    assert {r["set"] for r in rows} == {"same"}
    assert [(r["query"].split("/")[1], r["input"]) for r in rows] == \
        [(q, i) for q in QUERIES for i in ("single", "thinned", "sequence")]
    own = int(np.load(SOURCE / "map.npy", mmap_mode="r").shape[0])
    assert int(rows[0]["map_points"]) > 2 * own   # the other place's map is in it
    assert not any(r["accepted"] == "True" and r["success"] == "False" for r in rows), rows
    assert "Stress (--stress)" in (tmp_path / "out" / "stress.md").read_text()


def test_a_narrow_view_keeps_the_nearest_return_per_bin_inside_its_field():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(20000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    near, far = 5.0 * directions, 9.0 * directions          # every direction hit twice: a near and a far return
    view = narrow_view(np.vstack([far, near]), 90.0)
    distance = np.linalg.norm(view, axis=1)
    assert np.allclose(distance, 5.0)                        # the nearest return of each bin
    azimuth = np.degrees(np.arctan2(view[:, 1], view[:, 0]))
    elevation = np.degrees(np.arcsin(view[:, 2] / distance))
    assert np.all(np.abs(azimuth - 90.0) < 35.0) and np.all(np.abs(elevation) < 35.0)
    bins = np.floor((np.column_stack([azimuth - 90.0, elevation]) + 35.0) / NARROW_STEP_DEG)   # from the field's corner
    assert len(np.unique(bins, axis=0)) == len(view)         # one return per bin
    assert len(narrow_view(near[near[:, 1] < 0], 90.0)) == 0  # the sensor faces away from them


def test_the_narrow_set_registers_the_views_that_return_enough(tmp_path):
    """The Avia's scans are narrow already: seen facing sideways or back they return nothing."""
    folder = short_sequence(tmp_path)
    assert main(["--maps", str(folder.parent), "--narrow", "--methods", "regor",
                 "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "narrow.csv")))
    assert [(r["query"].split("/")[1], r["input"]) for r in rows] == [(q, "narrow 000") for q in QUERIES]
    assert not any(r["accepted"] == "True" and r["success"] == "False" for r in rows), rows
    assert "Narrow (--narrow)" in (tmp_path / "out" / "narrow.md").read_text()


def test_sequences_of_one_place_are_no_cross_map_queries():
    from regor_ros.bench.datasets import one_place
    assert one_place("fastlio_avia_hku2", "avia_hku2_loop")   # one walk, one frame: a true pose exists there
    assert not one_place("fastlio_avia_hku2", "scaloam_mulran_kaist03")
    assert not one_place("eth_gazebo_summer_winter", "avia_hku2_loop")


def test_verify_mode_checks_right_and_wrong_poses_against_the_peers_checks(tmp_path):
    folder = short_sequence(tmp_path)
    out = tmp_path / "out"
    assert main(["--verify", str(DATA / "pairs"), "--pairs", "redkitchen_5_6", "--maps", str(folder.parent),
                 "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "verify.csv")))
    cases = {(r["set"], r["case"], r["input"]) for r in rows}
    assert cases == {("pairs", "3dmatch_redkitchen_5_6_ds", "pair"),
                     *((SEQUENCE, query, which) for query in QUERIES for which in ("single", "sequence"))}
    poses = [r["pose"] for r in rows if r["case"] == "scan_000180" and r["input"] == "single"]
    assert poses[:2] == ["true", "nudged"] and "slide" in poses and "kiss-matcher" in poses
    assert all(r["verified"] == "False" for r in rows if r["right"] == "False")   # no wrong pose verified
    found = [r for r in rows if r["pose"] in ("true", "nudged") and r["case"] != "scan_000200"]
    assert found and all(r["verified"] == "True" for r in found)   # 200 alone: register withholds it too
    assert all(0 <= float(r["icp_fitness"]) <= 1 for r in rows)
    report = (out / "verify.md").read_text()
    assert "| outdoor | ICP fitness |" in report and "| indoor | verify() |" in report


def test_an_imus_up_is_the_truths_tilted_by_the_stated_angle_the_same_for_a_query_every_run():
    from regor_ros.core import random_rigid_motion
    truth, map_up = random_rigid_motion(7), np.array([0.0, 0.0, 1.0])
    exact = truth[:3, :3].T @ map_up
    up = imu_up(truth, map_up, 3.0, "loop/scan_000200")
    assert np.degrees(np.arccos(np.clip(up @ exact, -1.0, 1.0))) == pytest.approx(3.0)
    assert np.array_equal(up, imu_up(truth, map_up, 3.0, "loop/scan_000200"))
    assert not np.allclose(up, imu_up(truth, map_up, 3.0, "loop/scan_000201"))
