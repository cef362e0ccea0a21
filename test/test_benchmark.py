"""regor-bench end to end on two real pairs with two fast methods, and its summary arithmetic."""
import csv
import json

import numpy as np
import pytest
from conftest import DATA, PAIRS, require_shared_data

from regor_ros.bench.cli import main
from regor_ros.bench.pairs import summarise
from regor_ros.core import ORIGIN, RegorConfig, for_clouds_seen_from, prepare_cloud, register, rotation_error_deg

TWO = ["3dmatch_redkitchen_5_6_ds", "stanford_bunny_045_to_000"]


def pair_folder(root, names):
    require_shared_data("the benchmark tests")
    folder = root / "pairs"
    folder.mkdir()
    listing = [p for p in json.loads((PAIRS / "pairs.json").read_text()) if p["name"] in names]
    (folder / "pairs.json").write_text(json.dumps(listing))
    for name in names:
        (folder / name).symlink_to(PAIRS / name)
    return folder


@pytest.fixture
def two_pairs(tmp_path):
    return pair_folder(tmp_path, TWO)


def test_mismatched_mode_counts_accepted_poses_across_places(tmp_path, capsys):
    folder = pair_folder(tmp_path, ["3dmatch_redkitchen_5_6_ds", "3dmatch_hotel_umd_8_15_ds"])
    assert main([str(folder), "--mismatched", "--rotate", "2", "--methods", "regor,kiss-matcher",
                 "--out", str(tmp_path / "out")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "mismatched.csv")))
    # each source against the other place's target, and each target against its source
    assert {r["pair"] for r in rows} == {
        "3dmatch_redkitchen_5_6_ds -> 3dmatch_hotel_umd_8_15_ds",
        "3dmatch_hotel_umd_8_15_ds -> 3dmatch_redkitchen_5_6_ds",
        "3dmatch_redkitchen_5_6_ds (target) -> 3dmatch_hotel_umd_8_15_ds (source)",
        "3dmatch_hotel_umd_8_15_ds (target) -> 3dmatch_redkitchen_5_6_ds (source)"}
    assert len(rows) == 8 and not any(r["success"] == "True" for r in rows)
    # every accepted pose counts as published wrong
    report = (tmp_path / "out" / "mismatched.md").read_text()
    for method in ("regor", "kiss-matcher"):
        accepted = sum(r["accepted"] == "True" for r in rows if r["method"] == method)
        assert f"| all | {method} | 0.0 % | 0/4 |" in report
        assert report.split(f"| all | {method} |")[1].split("\n")[0].endswith(f"| 0 / {accepted} |")
    # Regor's stages are timed per run and their medians reported; the peer has no stages
    regor = [r for r in rows if r["method"] == "regor"]
    assert all(float(r["seconds_initial"]) > 0 and float(r["seconds_matching"]) > 0 for r in regor)
    # each run records how many registrations it took (acceptance.retries is 0 by default)
    assert all(r["attempts"] == "1" for r in regor) and not any(r["attempts"] for r in rows if r["method"] != "regor")
    stages = report.split("Median seconds per stage")[1].split("\n\n")[1].splitlines()
    assert stages[0] == "| kind | method | features | matching | initial | regeneration | estimation | verification |"
    assert [line.split(" | ")[:2] for line in stages[2:]] == [["| indoor", "regor"], ["| all", "regor"]]


def test_benchmark_command_writes_table_csv_and_plot(two_pairs, tmp_path, capsys):
    out = tmp_path / "results"
    assert main([str(two_pairs), "--methods", "sc2pcr++,o3d-fgr", "--rotate", "4", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "[2/2" in printed and "| all | sc2pcr++ |" in printed
    rows = list(csv.DictReader(open(out / "benchmark.csv")))
    assert len(rows) == 4 and {r["method"] for r in rows} == {"sc2pcr++", "o3d-fgr"}
    sc2 = [r for r in rows if r["method"] == "sc2pcr++"]
    assert all(r["success"] == "True" for r in sc2)
    assert all(float(r["seconds_total"]) >= float(r["seconds_registration"]) > 0 for r in rows)
    table = (out / "benchmark.md").read_text()
    assert "| object | sc2pcr++ | 100.0 % | 1/1 |" in table
    assert (out / "benchmark.png").read_bytes()[:4] == b"\x89PNG"


def test_unknown_method_is_refused(two_pairs, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main([str(two_pairs), "--methods", "icp"])
    # a peer the map benchmark cannot run is refused too, not silently dropped
    with pytest.raises(SystemExit):
        main(["--maps", str(tmp_path), "--methods", "regor,o3d-ransac"])
    assert "'o3d-ransac'" in capsys.readouterr().err


def row(seed, method, kind, success, accepted=""):
    return {"seed": seed, "pair": f"p{seed}", "kind": kind, "method": method, "success": success,
            "accepted": accepted, "rotation_error_deg": 2.0, "translation_error_m": 0.1,
            "seconds_registration": 1.0, "seconds_total": 2.0, "inliers_final": 30,
            "final_count": 60, "inliers_initial": 10, "initial_count": 100}


def test_summary_recall_spread_inr_and_false_accepts():
    rows = [row(1, "m", "indoor", True, True), row(1, "m", "indoor", False, True),
            row(2, "m", "indoor", True, False), row(2, "m", "indoor", True, True)]
    s = summarise(rows)[("m", "indoor")]
    assert s["recall"] == 0.75 and s["recall_spread"] == pytest.approx(0.25)
    assert s["ip"] == 0.5 and s["inr"] == pytest.approx(300.0) and s["fmr"] == 100.0
    assert s["accepted"] == 3 and s["false_accepts"] == 1
    assert s["re"] == 2.0 and s["te_cm"] == pytest.approx(10.0)


def test_a_random_motion_moves_the_source_viewpoint_with_the_source():
    from regor_ros.bench.datasets import Pair
    from regor_ros.core.geometry import transform_points
    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, (50, 3))
    pair = Pair(3, "p", "indoor", src, src, np.eye(4), np.array([0.5, 0.0, 1.0]), None)
    moved = pair.moved(2)
    M = np.linalg.inv(moved.T_gt)   # the truth is adjusted by the inverse motion
    np.testing.assert_allclose(moved.src, transform_points(M, src))
    np.testing.assert_allclose(moved.src_viewpoint, transform_points(M, pair.src_viewpoint[None])[0])
    assert moved.tgt_viewpoint is None and pair.moved(None) is pair


THREEDMATCH = DATA / "threedmatch"
UMD = "sun3d-hotel_umd-maryland_hotel3"


def threedmatch_folder(root):
    """Two real 3DMatch entries of one scene, and the first again with its truth moved by a metre
    and turned by 90 degrees: whatever Regor publishes for it is a gross wrong pose."""
    require_shared_data("the 3DMatch benchmark test")
    if not (THREEDMATCH / "pairs.json").is_file():
        pytest.fail(f"{THREEDMATCH} is missing from the shared data")
    entries = [e for e in json.loads((THREEDMATCH / "pairs.json").read_text()) if e["scene"] == UMD][:2]
    wrong = dict(entries[0], T=(np.array(entries[0]["T"]) @ np.array(
        [[0, -1, 0, 1.0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])).tolist(), bench="3DLoMatch")
    folder = root / "threedmatch"
    folder.mkdir()
    (folder / "pairs.json").write_text(json.dumps(entries + [wrong]))
    (folder / UMD).symlink_to(THREEDMATCH / UMD)
    return folder, entries


def test_threedmatch_benchmark_reports_recall_per_list_and_gross_wrong_poses(tmp_path, capsys):
    folder, entries = threedmatch_folder(tmp_path)
    out = tmp_path / "out"
    assert main(["--threedmatch", str(folder), "--methods", "regor", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "threedmatch.csv")))
    assert [r["bench"] for r in rows] == ["3DMatch", "3DMatch", "3DLoMatch"]
    assert rows[0]["pair"] == f"3dmatch_hotel_umd3_{entries[0]['j']}_{entries[0]['i']}"
    # the same clouds give the same pose; against the moved truth it is wrong, and gross
    assert rows[0]["rotation_error_deg"] != rows[2]["rotation_error_deg"]
    assert rows[0]["accepted"] == rows[2]["accepted"] and rows[2]["success"] == "False"
    assert float(rows[2]["rotation_error_deg"]) > 20.0
    report = (out / "threedmatch.md").read_text()
    correct = sum(r["success"] == "True" for r in rows[:2])
    published = sum(r["success"] == "True" and r["accepted"] == "True" for r in rows[:2])
    assert f"| 3DMatch | regor | {50.0 * correct:.1f} % | {correct} / 2 | {published} (" in report
    gross = 1 if rows[2]["accepted"] == "True" else 0
    assert f"| 3DLoMatch | regor | 0.0 % | 0 / 1 | 0 | {gross} ({gross}) |" in report
    assert "| hotel_umd | 3DMatch |" in report  # the place, as the other sets name it


def test_threedmatch_sample_is_fixed_and_a_bad_list_is_refused(tmp_path, capsys):
    from regor_ros.bench.datasets import load_list
    listing = [{"bench": "3DMatch", "scene": "s", "i": i, "j": i + 1, "T": np.eye(4).tolist()} for i in range(40)]
    (tmp_path / "pairs.json").write_text(json.dumps(listing))
    first = [e["name"] for e in load_list(tmp_path, 10, None)]
    assert first == [e["name"] for e in load_list(tmp_path, 10, None)] and len(set(first)) == 10
    assert [e["name"] for e in load_list(tmp_path, None, "s_6_5")] == ["3dmatch_s_6_5"]
    del listing[3]["T"]
    (tmp_path / "pairs.json").write_text(json.dumps(listing))
    with pytest.raises(SystemExit):
        main(["--threedmatch", str(tmp_path), "--out", str(tmp_path / "out")])
    assert "entry 3 lacks T" in capsys.readouterr().err


@pytest.mark.parametrize("mode", ["--threedmatch", "--maps", "--map-scaling"])
def test_an_argument_the_mode_would_not_read_is_refused(mode, tmp_path, capsys):
    """A second override after one --set is a positional folder to argparse; --threedmatch and the
    map modes read none, so it would be dropped without a word and the run made without it."""
    with pytest.raises(SystemExit):
        main([mode, str(tmp_path), "--set", "features.normals_toward_sensors=true",
              "estimation.visible_candidates=8", "--out", str(tmp_path / "out")])
    assert "each override needs its own --set" in capsys.readouterr().err


def test_a_seed_the_pairs_would_not_use_is_refused(tmp_path, capsys):
    """Pairs seed each registration with its motion's seed: a --set seed would be overwritten
    without a word, and a run meant as another draw would repeat the last one."""
    with pytest.raises(SystemExit):
        main([str(tmp_path), "--set", "seed=3", "--out", str(tmp_path / "out")])
    assert "--set seed has no effect" in capsys.readouterr().err


def test_the_lists_take_a_seed_and_say_which(tmp_path):
    """--set seed=N seeds the lists' registrations with N (0 without), as the library seeds a
    registration with it: another draw of the same lists, the seed in its CSV rows and report."""
    folder, entries = threedmatch_folder(tmp_path)
    name = f"3dmatch_hotel_umd3_{entries[1]['j']}_{entries[1]['i']}"
    rows = {}
    for seed in (None, 7):
        out = tmp_path / f"out{seed}"
        main(["--threedmatch", str(folder), "--pairs", name, "--methods", "regor", "--out", str(out),
              *(["--set", f"seed={seed}"] if seed else [])])
        rows[seed] = next(csv.DictReader(open(out / "threedmatch.csv")))
        assert f"registrations seeded with {seed or 0}," in (out / "threedmatch.md").read_text()
    assert rows[None]["seed"] == "" and rows[7]["seed"] == "7"
    config = for_clouds_seen_from(RegorConfig.preset("indoor").replace({"seed": 7}), ORIGIN, ORIGIN)
    source, target = (np.load(THREEDMATCH / UMD / f"{entries[1][k]}.npy") for k in "ji")
    result = register(prepare_cloud(source, config, "source", viewpoint=ORIGIN),
                      prepare_cloud(target, config, "target", viewpoint=ORIGIN), config)
    assert float(rows[7]["rotation_error_deg"]) == rotation_error_deg(result.transform, np.array(entries[1]["T"]))
    assert rows[7]["rotation_error_deg"] != rows[None]["rotation_error_deg"]   # another draw


@pytest.mark.parametrize("mode", [["--threedmatch"], ["--maps"], ["--profile"]])
def test_a_motion_the_run_would_not_apply_is_refused(mode, tmp_path, capsys):
    """Only the pairs run moves its sources: under the lists, the maps or the profile a --rotate
    would be dropped without a word, and a run meant under another motion would repeat the last."""
    with pytest.raises(SystemExit):
        main([*mode, str(tmp_path), "--rotate", "1", "--out", str(tmp_path / "out")])
    assert "--rotate moves the sources of a run over folders of pairs" in capsys.readouterr().err


def test_without_viewpoints_no_free_space_is_measured_and_the_report_says_so(tmp_path, capsys):
    folder = pair_folder(tmp_path, TWO[:1])
    out = tmp_path / "out"
    assert main([str(folder), "--no-viewpoints", "--methods", "regor", "--out", str(out)]) == 0
    row = next(csv.DictReader(open(out / "benchmark.csv")))
    assert all(np.isnan(float(row[side] or "nan")) for side in ("free_space_source", "free_space_target"))
    assert "Viewpoints dropped (--no-viewpoints)" in (out / "benchmark.md").read_text()
    seen = tmp_path / "seen"
    assert main([str(folder), "--methods", "regor", "--out", str(seen)]) == 0
    assert not np.isnan(float(next(csv.DictReader(open(seen / "benchmark.csv")))["free_space_target"]))
    with pytest.raises(SystemExit):
        main(["--maps", str(tmp_path), "--no-viewpoints", "--out", str(out)])
    assert "--no-viewpoints is for pairs and --threedmatch" in capsys.readouterr().err
