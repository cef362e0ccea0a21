"""Verifying given poses (``regor-bench --verify``): verify() against the checks users apply today.

For every pair of the pair folders, and every query of the map folders (the scan alone and fused
along odometry), the poses a localization stack or a loop closer could hand over:
- right: the true pose, the true pose moved within the success tolerance (0.2 m, or two thirds of
  the tolerance where that is less, and 1 deg), and
  KISS-Matcher's pose where it is right;
- wrong, made: the true pose shifted by 1, 2 and 5 m across the scene, turned by 20, 30, 90 and 180
  deg about its up direction through the sensor, and slid along its dominant direction by three
  success tolerances (a corridor, a road);
- wrong, real: KISS-Matcher's pose where it is wrong (the same run).
Each pose is verified (verify(), the preset of its kind), and given to the checks users apply today:
Open3D's point-to-plane ICP from the pose, its fitness thresholded (at the threshold that passes as
many of the right poses as verify() verifies, how many wrong ones pass), and for KISS-Matcher's own
poses its final inlier count. The cost of a check is set against register() on the same input.
The scene's up is the target's direction of least extent (a site's, a room's vertical) and its
dominant direction that of most.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..core import (
    RegorConfig,
    ScanSequence,
    for_clouds_seen_from,
    is_success,
    prepare_cloud,
    register,
    to_matrix,
    verify,
    warm_up,
)
from .datasets import INPUTS, load_pairs, load_sequence, sequence_folders
from .peers import kiss_matcher_solution
from .results import write_results

NUDGE = (0.2, 1.0)                  # [m], [deg]: a right pose as a tracker holds it
NUDGE_SHARE = 2.0 / 3.0             # at most this share of the success tolerance (an object's is centimetres)
SHIFTS_M = (1.0, 2.0, 5.0)
TURNS_DEG = (20.0, 30.0, 90.0, 180.0)
SLIDE_TOLERANCES = 3.0              # a slide along the dominant direction, in success tolerances
FIELDS = ["set", "case", "input", "kind", "pose", "right", "verified", "failed_check", "correction_m",
          "correction_deg", "seconds_verify", "icp_fitness", "kiss_inliers", "seconds_register", "reason"]


def scene_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(up, dominant): the directions of least and most extent of ``points``."""
    sample = points[:: max(1, len(points) // 50000)]
    _, vectors = np.linalg.eigh(np.cov((sample - sample.mean(axis=0)).T))
    return vectors[:, 0], vectors[:, 2]


def turned(T: np.ndarray, axis: np.ndarray, degrees: float) -> np.ndarray:
    """``T`` turned by ``degrees`` about ``axis`` through where it puts the source's origin."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    return to_matrix(R, T[:3, 3] - R @ T[:3, 3]) @ T


def shifted(T: np.ndarray, offset: np.ndarray) -> np.ndarray:
    return to_matrix(np.eye(3), offset) @ T


def given_poses(truth: np.ndarray, up: np.ndarray, dominant: np.ndarray, tolerance: float):
    """[(label, pose, right)] made from the truth: right ones within the tolerance, wrong ones beyond."""
    across = np.cross(up, dominant)
    step = min(NUDGE[0], NUDGE_SHARE * tolerance)
    nudge = turned(shifted(truth, step * (across + dominant) / np.sqrt(2.0)), up, NUDGE[1])
    poses = [("true", truth, True), ("nudged", nudge, True)]
    poses += [(f"shift {m:g} m", shifted(truth, m * across), False) for m in SHIFTS_M]
    poses += [(f"turn {d:g} deg", turned(truth, up, d), False) for d in TURNS_DEG]
    poses.append(("slide", shifted(truth, SLIDE_TOLERANCES * tolerance * dominant), False))
    return poses


def icp_fitness(source: np.ndarray, target: np.ndarray, T: np.ndarray, config: RegorConfig) -> float:
    """Open3D point-to-plane ICP from ``T`` on the clouds at the preset's voxel, within the success
    tolerance: its fitness (the share of the source with a target point within it)."""
    import open3d as o3d
    voxel = config.features.voxel_size

    def cloud(points):
        points = o3d.utility.Vector3dVector(np.asarray(points, np.float64))
        return o3d.geometry.PointCloud(points).voxel_down_sample(voxel)
    src, tgt = cloud(source), cloud(target)
    tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=config.features.normal_radius, max_nn=30))
    result = o3d.pipelines.registration.registration_icp(
        src, tgt, config.verification.max_correction, T,
        o3d.pipelines.registration.TransformationEstimationPointToPlane())
    return float(result.fitness)


def case_rows(base: dict, source, target, raw_source: np.ndarray, raw_target: np.ndarray, truth: np.ndarray,
              axes, config: RegorConfig, viewpoints: dict) -> list[dict]:
    """Every given pose of one case (a pair, or a query against a prepared map) verified and checked."""
    start = time.perf_counter()
    register(source, target, config, **viewpoints)
    registered = time.perf_counter() - start
    up, dominant = axes
    poses = given_poses(truth, up, dominant, config.verification.max_correction)
    kiss_inliers = ""
    try:
        kiss, _, _, kiss_inliers = kiss_matcher_solution(raw_source, raw_target, config.features.voxel_size)
        poses.append(("kiss-matcher", kiss, bool(is_success(kiss, truth, base["kind"]))))
    except RuntimeError as exc:  # it refuses some inputs (an object's millimetre voxels): no pose of its
        print(f"KISS-Matcher: {exc}", flush=True)
    rows = []
    for label, pose, right in poses:
        result = verify(source, target, pose, config, **viewpoints)
        rows.append(dict(base, pose=label, right=right, verified=result.accepted, failed_check=result.verdict.failed,
                         correction_m=result.correction_m, correction_deg=result.correction_deg,
                         seconds_verify=result.timings["total"],
                         icp_fitness=icp_fitness(raw_source, raw_target, pose, config),
                         kiss_inliers=kiss_inliers if label == "kiss-matcher" else "",
                         seconds_register=registered, reason=result.reason))
    return rows


def map_rows(folder: Path, config: RegorConfig) -> list[dict]:
    cloud, trajectory, queries = load_sequence(folder)
    prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
    axes = scene_axes(cloud)
    rows = []
    for query in queries:
        for which in INPUTS:
            source = query.cloud(which)
            if source is None:
                continue
            raw = source.fused().points if isinstance(source, ScanSequence) else source
            base = {"set": folder.name, "case": query.id, "input": which, "kind": "outdoor"}
            rows += _told(case_rows(base, source, prepared, raw, cloud, query.truth, axes, config, {}))
    return rows


def pair_rows(folder: Path, presets: dict[str, RegorConfig], name_filter: str | None) -> list[dict]:
    rows = []
    for pair in load_pairs(folder, name_filter):
        config = for_clouds_seen_from(pair.configured(presets[pair.kind]), pair.src_viewpoint, pair.tgt_viewpoint)
        base = {"set": folder.name, "case": pair.name, "input": "pair", "kind": pair.kind}
        viewpoints = {"source_viewpoint": pair.src_viewpoint, "target_viewpoint": pair.tgt_viewpoint}
        rows += _told(case_rows(base, pair.src, pair.tgt, pair.src, pair.tgt, pair.T_gt, scene_axes(pair.tgt),
                                config, viewpoints))
    return rows


def _told(rows: list[dict]) -> list[dict]:
    """The rows of one case, after printing how many of its poses verify() judged right."""
    first = rows[0]
    print(f"{first['set']} {first['case']} {first['input']}: {sum(r['verified'] == r['right'] for r in rows)} of "
          f"{len(rows)} poses judged right, {sum(r['verified'] and not r['right'] for r in rows)} wrong verified",
          flush=True)
    return rows


def run_verify(pair_folders: list[Path], map_folders: list[Path], overrides: dict, name_filter: str | None,
               out: Path, header: str) -> str:
    """The benchmark on every pair and map query; writes verify.md, .csv and .png to ``out``."""
    warm_up()
    presets = {kind: RegorConfig.preset(kind).replace(overrides) for kind in ("indoor", "outdoor", "object")}
    rows = []
    for folder in pair_folders:
        rows += pair_rows(folder, presets, name_filter)
    for folder in sequence_folders(map_folders):
        rows += map_rows(folder, presets["outdoor"])
    report = verify_report(rows, header)
    write_results(out, "verify", report, rows, FIELDS, _plot)
    return report


def _median(values) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def _wrong_kind(label: str) -> str:
    return label.split(" ")[0] if label != "kiss-matcher" else "KISS-Matcher's wrong"


def threshold_matching(scores: np.ndarray, right: np.ndarray, share: float) -> tuple[float, int]:
    """(the largest threshold at which ``scores`` >= it passes at least ``share`` of the right
    ones, how many wrong ones pass there)."""
    ranked = np.sort(scores[right])[::-1]
    needed = int(np.ceil(share * len(ranked)))
    if needed == 0 or not len(ranked):
        return float("inf"), 0
    threshold = ranked[needed - 1]
    return float(threshold), int((scores[~right] >= threshold).sum())


def verify_report(rows: list[dict], header: str) -> str:
    lines = [header, "", "## Given poses verified", "",
             "Right: the true pose, nudged by 0.2 m and 1 deg, KISS-Matcher's where right. Wrong: made (shifts, turns "
             "about up, a slide along the dominant direction) and KISS-Matcher's where wrong.", "",
             "| set | input | right verified | wrong verified | shifts | turns | slides | KISS-Matcher's wrong | "
             "median s verify | median s register | ratio |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["set"], r["input"]), []).append(r)
    for (name, which), group in groups.items():
        right = [r for r in group if r["right"]]
        wrong = [r for r in group if not r["right"]]

        def of(kind, wrong=wrong):
            chosen = [r for r in wrong if _wrong_kind(r["pose"]) == kind]
            return f"{sum(r['verified'] for r in chosen)} / {len(chosen)}"
        verify_s = _median([r["seconds_verify"] for r in group])
        register_s = _median(list({r["case"]: r["seconds_register"] for r in group}.values()))
        lines.append(f"| {name} | {which} | {sum(r['verified'] for r in right)} / {len(right)} | "
                     f"**{sum(r['verified'] for r in wrong)}** / {len(wrong)} | {of('shift')} | {of('turn')} | "
                     f"{of('slide')} | {of(_wrong_kind('kiss-matcher'))} | {verify_s:.3f} | {register_s:.3f} | "
                     f"{verify_s / register_s:.2f} |")
    lines += ["", "## The checks users apply today, at verify()'s share of right poses passed", "",
              "ICP: Open3D point-to-plane from the given pose within the success tolerance, its fitness "
              "thresholded. KISS-Matcher: its final inlier count, on its own poses only.", "",
              "| kind | check | right poses | share passed (verify()) | threshold | wrong poses | wrong passed |",
              "|---|---|---|---|---|---|---|"]
    for kind in sorted({r["kind"] for r in rows}):
        of_kind = [r for r in rows if r["kind"] == kind]
        right_mask = np.array([r["right"] for r in of_kind])
        share = float(np.mean([r["verified"] for r in of_kind if r["right"]])) if right_mask.any() else 0.0
        ours = sum(r["verified"] for r in of_kind if not r["right"])
        lines.append(f"| {kind} | verify() | {right_mask.sum()} | {100 * share:.1f} % | - | "
                     f"{(~right_mask).sum()} | **{ours}** |")
        threshold, passed = threshold_matching(np.array([r["icp_fitness"] for r in of_kind]), right_mask, share)
        lines.append(f"| {kind} | ICP fitness | {right_mask.sum()} | {100 * share:.1f} % | {threshold:.3f} | "
                     f"{(~right_mask).sum()} | **{passed}** |")
        kiss = [r for r in of_kind if r["pose"] == "kiss-matcher"]
        kiss_right = np.array([r["right"] for r in kiss], dtype=bool)
        if kiss_right.any():
            kiss_share = float(np.mean([r["verified"] for r in kiss if r["right"]]))
            threshold, passed = threshold_matching(np.array([float(r["kiss_inliers"]) for r in kiss]), kiss_right,
                                                   kiss_share)
            lines.append(f"| {kind} | KISS-Matcher inliers (its poses) | {kiss_right.sum()} | "
                         f"{100 * kiss_share:.1f} % | {threshold:.0f} | {(~kiss_right).sum()} | **{passed}** |")
    lines += ["", "Not verified, right poses (the reason):", ""]
    lines += [f"- {r['set']} {r['case']} {r['input']} {r['pose']}: {r['reason']}"
              for r in rows if r["right"] and not r["verified"]]
    lines += ["", "Verified, wrong poses:", ""]
    lines += [f"- {r['set']} {r['case']} {r['input']} {r['pose']}" for r in rows if not r["right"] and r["verified"]]
    return "\n".join(lines) + "\n"


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for right, colour, label in ((True, "tab:green", "right poses"), (False, "tab:red", "wrong poses")):
        chosen = [r for r in rows if r["right"] == right]
        ax.scatter([r["icp_fitness"] for r in chosen], [1.0 if r["verified"] else 0.0 for r in chosen]
                   + np.random.default_rng(0).uniform(-0.15, 0.15, len(chosen)), s=6, c=colour, label=label)
    ax.set_xlabel("ICP fitness from the given pose")
    ax.set_yticks([0, 1], ["not verified", "verified"])
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
