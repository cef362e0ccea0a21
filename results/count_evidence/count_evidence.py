"""What stands between the count (acceptance.min_feature_inliers) and #51's published share.

Every run of the five scenes' lists and of the cross-place runs that the gate would publish were
the count waived (the figures results/singled_out recorded) is registered again with the shipped
preset, as regor-bench registers it, and the pose's feature count is measured once more in ways
that could tell a right pose with few matches from a wrong one:
- at other agreement distances than initial.inlier_threshold (0.1 m): a right pose a few degrees
  off loses true matches beyond it, while chance agreements grow with the volume;
- on three re-drawn voxel grids (the source turned as acceptance.retries turns it): the count of
  the same pose on another draw of the keypoints, so that an average could replace one draw;
- and the surfaces' test against chance (gate/surface_evidence.py), which waives the count for a
  pose it carries, run here on the poses that the count withholds (the pipeline runs it only on
  poses whose feature matches fail their own test against chance).
Then, for each gross pose of the lists, its rivals (gate/rivals.py) are refined further, from a
coarse agreement distance down to the estimator's, to see whether one reaches the true pose: the
gate would then find the pose ambiguous, or could publish the rival instead.
Writes count_evidence.csv (one row per run) and prints the figures of README.md. Run from the
repository: python results/count_evidence/count_evidence.py (about 15 minutes on two cores).
"""
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig, is_gross, pipeline, prepare_cloud  # noqa: E402
from regor_ros.core.estimate import agreeing, point_refine, point_refine_all  # noqa: E402
from regor_ros.core.gate.figures import Figures  # noqa: E402
from regor_ros.core.gate.judge import CHECKS, passes  # noqa: E402
from regor_ros.core.gate.rivals import RIVAL_POINTS  # noqa: E402
from regor_ros.core.gate.surface_evidence import surface_evidence  # noqa: E402
from regor_ros.core.gate.visibility import visibility_figures  # noqa: E402
from regor_ros.core.geometry import evenly_spaced  # noqa: E402
from regor_ros.core.matching import match_features  # noqa: E402
from regor_ros.core.metrics import rotation_error_deg, translation_error  # noqa: E402
from regor_ros.tools.pairs_benchmark import cross_place_pairs, evaluate_pair, load_pairs  # noqa: E402
from regor_ros.tools.threedmatch_benchmark import Fragments, as_pair, load_list  # noqa: E402

SHIPPED = Path("results/singled_out")
DATA = Path("../shared/data")
OUT = Path("results/count_evidence/count_evidence.csv")
DISTANCES = (0.05, 0.075, 0.1, 0.125, 0.15, 0.2)  # agreement distances the count is taken at [m]
GRIDS = (1, 2, 3)                                # re-drawn grids (pipeline.regrid_rotation's attempts)
CONFIG = RegorConfig.preset("indoor")
WITHOUT_COUNT = tuple(check for check in CHECKS if check.name != "min_feature_inliers")
FIELDS = ["set", "pair", "seed", "correct", "gross", "published", "withheld_by_count",
          *(f"count_{d}" for d in DISTANCES), *(f"count_grid{g}" for g in GRIDS),
          "surface_cells", "surface_agreeing", "surface_chance", "surface_log10_false_alarms"]


def waivable(path: Path) -> dict:
    """The runs of a regor-bench CSV the gate publishes with the count's check dropped (the count
    still decides which rivals are contenders): key -> withheld by the count."""
    runs = {}
    for row in csv.DictReader(open(path)):
        if row["method"] != "regor" or row["error"]:
            continue
        figures, gate = Figures.from_columns(row), RegorConfig.preset(row["kind"]).acceptance
        if passes(figures, gate, WITHOUT_COUNT):
            runs[(row.get("bench") or row["seed"], row["pair"])] = not passes(figures, gate)
    return runs


class Spy:
    """pipeline.measure, recording what it was given: the pose, the clouds, the matches."""

    def __init__(self):
        self.measure, self.calls, self.measured = pipeline.measure, [], []

    def __call__(self, *args, **kwargs):
        self.calls.append(args)
        self.measured.append(self.measure(*args, **kwargs))
        return self.measured[-1]


def extra_figures(call, source_points: np.ndarray, source_viewpoint, withheld: bool) -> dict:
    """The pose's count at each distance; for a pose the count withholds, also on the re-drawn
    grids and the surfaces' test."""
    refined, source, target, (match_source, match_target, _), _, _, hypotheses, _, config, prior = call
    T = refined.transform
    row = {f"count_{d}": int(agreeing(T, match_source, match_target, d).sum()) for d in DISTANCES}
    if not withheld:
        return row
    tau = config.initial.inlier_threshold
    for attempt in GRIDS:
        turn = pipeline.regrid_rotation(config.seed, attempt)
        turned = prepare_cloud(source_points @ turn[:3, :3].T, config, viewpoint=turn[:3, :3] @ source_viewpoint)
        nearest = match_features(turned, target, config.initial.candidates, np.arange(0), mutual=False).target_index
        row[f"count_grid{attempt}"] = int(agreeing(T @ np.linalg.inv(turn), turned.points,
                                                   target.points[nearest], tau).sum())
    surfaces = surface_evidence(T, source, target, config, hypotheses, np.inf, prior)
    row.update(surface_cells=surfaces.cells, surface_agreeing=surfaces.agreeing, surface_chance=surfaces.chance,
               surface_log10_false_alarms=surfaces.log10_false_alarms)
    return row


def measured_pairs(spy: Spy):
    """(set, pair, seed, the run's row, the extra figures) of every waivable run."""
    lists = waivable(SHIPPED / "threedmatch/threedmatch.csv")
    fragments = Fragments(DATA / "threedmatch")
    for entry in load_list(DATA / "threedmatch", None, None):
        key = (entry["bench"], entry["name"])
        if key in lists:
            pair = as_pair(entry, fragments)
            spy.calls.clear()
            row = evaluate_pair(pair, ["regor"], CONFIG, None)[0]
            yield (*key, "", row, extra_figures(spy.calls[0], pair.src, pair.src_viewpoint, lists[key]))
    crossed = waivable(SHIPPED / "mismatched/mismatched.csv")
    pairs = [p for name in ("pairs", "pairs_scenes", "pairs_hard") for p in load_pairs(DATA / name, "3dmatch")]
    for seed in sorted({int(s) for s, _ in crossed}):
        for pair in cross_place_pairs(pairs, seed):
            key = (str(seed), pair.name)
            if key in crossed:
                moved = pair.moved(seed)
                spy.calls.clear()
                row = evaluate_pair(moved, ["regor"], moved.configured(CONFIG), seed)[0]
                yield ("cross-place", pair.name, seed, row,
                       extra_figures(spy.calls[0], moved.src, moved.src_viewpoint, crossed[key]))


def run() -> None:
    spy = Spy()
    pipeline.measure = spy
    with open(OUT, "w", newline="") as handle:
        writer = csv.DictWriter(handle, FIELDS)
        writer.writeheader()
        for bench, name, seed, row, extra in measured_pairs(spy):
            correct = bench != "cross-place" and row["success"]
            gross = not correct and (bench == "cross-place"
                                     or is_gross(row["rotation_error_deg"], row["translation_error_m"], "indoor"))
            writer.writerow({"set": bench, "pair": name, "seed": seed, "correct": correct, "gross": gross,
                             "published": row["accepted"], "withheld_by_count": "count_grid1" in extra, **extra})


def report() -> None:
    rows = list(csv.DictReader(open(OUT)))
    correct = np.array([r["correct"] == "True" for r in rows])
    gross = np.array([r["gross"] == "True" for r in rows])
    withheld = np.array([r["withheld_by_count"] == "True" for r in rows])
    bench = np.array([r["set"] for r in rows])
    print(f"{len(rows)} runs publishable with the count waived: {correct.sum()} correct, "
          f"{(~correct).sum()} wrong ({gross.sum()} gross); the count withholds {withheld.sum()} of them "
          f"({(withheld & correct).sum()} correct, {(withheld & gross).sum()} gross)")
    for name in ("3DMatch", "3DLoMatch"):
        shown = correct & (bench == name)
        print(f"  {name}: published correct with the count {(shown & ~withheld).sum()}, without it {shown.sum()}")
    print("Were the count's threshold set just above every gross pose (in-sample, the best it can do):")
    for distance in DISTANCES:
        counts = np.array([float(r[f"count_{distance}"]) for r in rows])
        print(f"  count at {distance} m: {_above_gross(counts, correct, gross, bench)}")
    # a pose the count lets through today keeps its verdict; the ones it withholds are judged on
    # their four grids' counts (the first grid's is the run's own)
    grids = np.array([[float(r[f"count_{CONFIG.initial.inlier_threshold}"])]
                      + [float(r[f"count_grid{g}"] or "inf") for g in GRIDS] for r in rows])
    for label, aggregate in (("mean", np.mean), ("median", np.median)):
        print(f"  the {label} of four grids' counts: {_above_gross(aggregate(grids, axis=1), correct, gross, bench)}")
    lfa = np.array([float(r["surface_log10_false_alarms"] or "nan") for r in rows])
    carried = withheld & (lfa <= np.log10(CONFIG.acceptance.max_false_alarms))
    print(f"The surfaces' test on the {withheld.sum()} poses the count withholds: carries {(carried & correct).sum()} "
          f"correct and {(carried & ~correct).sum()} wrong; the correct ones' false alarms 10^"
          f"{np.nanpercentile(lfa[withheld & correct], [10, 50, 90]).round(1)} (10th, 50th, 90th percentile)")


def _above_gross(counts: np.ndarray, correct: np.ndarray, gross: np.ndarray, bench: np.ndarray) -> str:
    bar = counts[gross].max()
    passing = correct & (counts > bar)
    return (f"gross poses up to {bar:g}; correct published: 3DMatch {(passing & (bench == '3DMatch')).sum()}, "
            f"3DLoMatch {(passing & (bench == '3DLoMatch')).sum()}")


def rivals_refined_further() -> None:
    """Each gross pose's rivals refined coarse to fine: how near the truth they get."""
    spy, tau = Spy(), CONFIG.estimation.inlier_threshold
    pipeline.measure = spy
    gross = {(r["set"], r["pair"]) for r in csv.DictReader(open(OUT)) if r["gross"] == "True" and r["seed"] == ""}
    fragments = Fragments(DATA / "threedmatch")
    print("The gross poses' rivals refined further (error from the true pose before -> after; its worst free space):")
    for entry in load_list(DATA / "threedmatch", None, None):
        if (entry["bench"], entry["name"]) not in gross:
            continue
        pair = as_pair(entry, fragments)
        spy.calls.clear(), spy.measured.clear()
        evaluate_pair(pair, ["regor"], CONFIG, None)
        source, target = spy.calls[0][1:3]
        sample = evenly_spaced(source.points, RIVAL_POINTS)
        starts = spy.measured[0].rival_poses
        poses = starts
        for distance in (5 * tau, 3 * tau, 2 * tau, tau):
            poses = np.array([r.transform for r in point_refine_all(poses, sample, target.neighbours, distance,
                                                                    CONFIG.estimation.max_iterations)])
        print(f"  {entry['name']}:")
        for start, pose in zip(starts, poses, strict=True):
            seen = visibility_figures(pose, source, target, CONFIG.acceptance,
                                      point_refine(pose, sample, target.neighbours, tau, 0).target_index)
            before, after = (f"{rotation_error_deg(P, pair.T_gt):5.1f} deg {translation_error(P, pair.T_gt):4.2f} m"
                             for P in (start, pose))
            print(f"    {before} -> {after}, free space {seen.worst:.3f}")


if __name__ == "__main__":
    if not OUT.is_file():
        run()
    report()
    rivals_refined_further()
