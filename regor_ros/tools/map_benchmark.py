"""Scan-to-map relocalization benchmark (``regor-bench --maps DIR`` and ``--map-scaling``).

A sequence folder holds ``map.npy`` (no single viewpoint), ``queries.json`` and
``queries/<id>/scan.npy`` + ``gt.txt`` (T_map_scan; the scan's sensor at its origin). Regor
prepares the map once and registers every query against it, as the node does in map mode;
KISS-Matcher gets the scan and the map on every call (it has no prepared-map interface). Each
(sequence, method) runs in its own process so that its peak memory is its own.

``--map-scaling`` tiles one real map side by side (each copy turned about the vertical) to grow
it, and measures map preparation, registration time and peak memory against map size. The copies
are identical, so a pose is scored against the nearest copy's truth.
"""
from __future__ import annotations

import json
import multiprocessing
import resource
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

from ..core import RegorConfig, prepare_cloud, register
from ..core.estimate import to_matrix
from ..core.metrics import is_success, rotation_error_deg, translation_error
from .benchmark import STAGES, write_results

MAP_METHODS = ("regor", "kiss-matcher")
MAP_FIELDS = ["sequence", "method", "query", "kind", "map_points", "map_keypoints", "success", "accepted",
              "rotation_error_deg", "translation_error_m", "seconds", *(f"seconds_{stage}" for stage in STAGES),
              "map_seconds", "peak_memory_gb", "feature_inliers", "free_space_source", "reason"]
TILE_SPACING = 400.0  # metres between copies: beyond a LiDAR's reach
SCALING_QUERIES = 10  # queries registered at each map size (the median of 5 moved by 0.1 s between runs)


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB on Linux


def load_sequence(folder: Path):
    """(map points, [(query id, kind, scan, T_map_scan)]) of one sequence folder."""
    queries = json.loads((folder / "queries.json").read_text())
    return np.load(folder / "map.npy"), [
        (q["id"], q["kind"], np.load(folder / "queries" / q["id"] / "scan.npy"),
         np.loadtxt(folder / "queries" / q["id"] / "gt.txt")) for q in queries]


def _score(T: np.ndarray, truths: List[np.ndarray]) -> tuple:
    """(success, rotation error, translation error) against the nearest of the true poses."""
    best = min(truths, key=lambda G: translation_error(T, G))
    return is_success(T, best, "outdoor"), rotation_error_deg(T, best), translation_error(T, best)


def _run_sequence(job) -> List[dict]:
    """One method on every query of one sequence (in a child process)."""
    folder, method, config = job
    cloud, queries = load_sequence(Path(folder))
    rows = []
    base = {"sequence": Path(folder).name, "method": method, "map_points": len(cloud)}
    if method == "regor":
        start = time.perf_counter()
        prepared = prepare_cloud(cloud, config, "map", viewpoint=None)
        base.update(map_seconds=time.perf_counter() - start, map_keypoints=len(prepared))
    for qid, kind, scan, T_gt in queries:
        row = dict(base, query=qid, kind=kind)
        if method == "regor":
            result = register(scan, prepared, config)
            T, seconds, accepted, reason = result.transform, result.timings["total"], result.accepted, result.reason
            # the gate's figures whatever the verdict; the map has no viewpoint: the scan's side only
            row.update({f"seconds_{stage}": result.timings[stage] for stage in STAGES},
                       feature_inliers=result.num_feature_inliers,
                       free_space_source=result.visibility.source_violation)
        else:
            import kiss_matcher as km
            matcher = km.KISSMatcher(km.KISSMatcherConfig(config.features.voxel_size))
            start = time.perf_counter()
            solution = matcher.estimate(np.asarray(scan, np.float32), np.asarray(cloud, np.float32))
            seconds = time.perf_counter() - start
            T = to_matrix(np.asarray(solution.rotation), np.asarray(solution.translation).reshape(3))
            accepted, reason = bool(solution.valid), ""
        success, rot, trans = _score(T, [T_gt])
        row.update(success=success, accepted=accepted, rotation_error_deg=rot, translation_error_m=trans,
                   seconds=seconds, reason=reason)
        rows.append(row)
    for row in rows:
        row["peak_memory_gb"] = _peak_gb()
    return rows


def _in_child(function, job):
    """Run ``function(job)`` in a fresh process, so its peak memory is measured alone."""
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(function, (job,))


def _median(values) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def map_report(rows: List[dict], header: str) -> str:
    lines = [header, "", "| sequence | method | correct | published correct / WRONG | median s per query | "
             "map preparation s | peak memory GB |", "|---|---|---|---|---|---|---|"]
    groups: Dict[tuple, List[dict]] = {}
    for r in rows:
        groups.setdefault((r["sequence"], r["method"]), []).append(r)
    for (sequence, method), group in groups.items():
        correct = sum(r["success"] for r in group)
        published = [r for r in group if r["accepted"]]
        right = sum(r["success"] for r in published)
        prep = group[0].get("map_seconds")
        lines.append(f"| {sequence} | {method} | {correct}/{len(group)} | {right} / {len(published) - right} | "
                     f"{_median([r['seconds'] for r in group]):.2f} | "
                     f"{'-' if prep is None else f'{prep:.1f}'} | {group[0]['peak_memory_gb']:.2f} |")
    timed = [(sequence, group) for (sequence, _), group in groups.items()
             if all(f"seconds_{stage}" in r for r in group for stage in STAGES)]
    if timed:
        lines += ["", "Regor's median seconds per stage (the scan's FPFH is the rest of the time per query):", "",
                  "| sequence | " + " | ".join(STAGES) + " |", "|---|" + "---|" * len(STAGES)]
        for sequence, group in timed:
            medians = (_median([r[f"seconds_{stage}"] for r in group]) for stage in STAGES)
            lines.append(f"| {sequence} | " + " | ".join(f"{m:.3f}" for m in medians) + " |")
    lines += ["", "Per query (error against the truth; `published` = passed the method's own gate):", "",
              "| sequence | query | method | correct | published | RE deg | TE m | s | reason |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['sequence']} | {r['query']} | {r['method']} | {'yes' if r['success'] else 'no'} | "
                     f"{'yes' if r['accepted'] else 'no'} | {r['rotation_error_deg']:.1f} | "
                     f"{r['translation_error_m']:.2f} | {r['seconds']:.2f} | {r['reason']} |")
    return "\n".join(lines) + "\n"


def run_maps(folder: Path, methods: List[str], config: RegorConfig, out: Path, header: str) -> str:
    """Every sequence under ``folder`` with every method; writes maps.md, .csv and .png."""
    sequences = sorted(p for p in folder.iterdir() if (p / "queries.json").is_file())
    if not sequences:
        raise SystemExit(f"{folder} holds no sequence folder with queries.json")
    rows = []
    for sequence in sequences:
        for method in methods:
            rows += _in_child(_run_sequence, (str(sequence), method, config))
            print(f"{sequence.name} {method}: {sum(r['success'] for r in rows if r['method'] == method and r['sequence'] == sequence.name)} correct", flush=True)
    report = map_report(rows, header)
    write_results(out, "maps", report, rows, MAP_FIELDS, _plot_maps)
    return report


def _plot_maps(rows: List[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    groups = sorted({(r["sequence"], r["method"]) for r in rows})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{s}\n{m}" for s, m in groups]
    correct = [sum(r["success"] for r in rows if (r["sequence"], r["method"]) == g) for g in groups]
    published = [sum(r["success"] and r["accepted"] for r in rows if (r["sequence"], r["method"]) == g) for g in groups]
    x = np.arange(len(groups))
    axes[0].bar(x - 0.2, correct, 0.4, label="correct")
    axes[0].bar(x + 0.2, published, 0.4, label="published correct")
    axes[0].set_ylabel("queries")
    axes[0].legend()
    axes[1].bar(x, [_median([r["seconds"] for r in rows if (r["sequence"], r["method"]) == g]) for g in groups])
    axes[1].set_ylabel("median seconds per query")
    for ax in axes:
        ax.set_xticks(x, labels, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- scaling: one real map tiled ---

def tiled(cloud: np.ndarray, tiles: int) -> tuple:
    """``tiles`` copies of the map on a grid, each turned about the vertical, and their poses."""
    side = int(np.ceil(np.sqrt(tiles)))
    copies, poses = [], []
    for i in range(tiles):
        angle = 0.7 * i
        c, s = np.cos(angle), np.sin(angle)
        pose = to_matrix(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                         np.array([TILE_SPACING * (i % side), TILE_SPACING * (i // side), 0.0]))
        copies.append(cloud @ pose[:3, :3].T + pose[:3, 3])
        poses.append(pose)
    return np.vstack(copies), poses


def _run_scaling(job) -> dict:
    """Prepare the tiled map and register the queries (in a child process)."""
    folder, tiles, config = job
    cloud, queries = load_sequence(Path(folder))
    big, poses = tiled(cloud, tiles)
    del cloud
    start = time.perf_counter()
    prepared = prepare_cloud(big, config, "map", viewpoint=None)
    prep = time.perf_counter() - start
    seconds, matching, correct, published = [], [], 0, 0
    for _, kind, scan, T_gt in [q for q in queries if q[1] == "scan"][:SCALING_QUERIES]:
        result = register(scan, prepared, config)
        seconds.append(result.timings["total"])
        matching.append(result.timings["matching"])
        success = _score(result.transform, [P @ T_gt for P in poses])[0]
        correct += success
        published += success and result.accepted
    return {"tiles": tiles, "map_points": len(big), "map_keypoints": len(prepared),
            "exact_search": prepared.index.exact, "map_seconds": prep,
            "median_seconds": _median(seconds), "median_matching_seconds": _median(matching),
            "queries": len(seconds), "correct": correct, "published_correct": published,
            "peak_memory_gb": _peak_gb()}


SCALING_FIELDS = ["tiles", "map_points", "map_keypoints", "exact_search", "map_seconds", "median_seconds",
                  "median_matching_seconds", "queries", "correct", "published_correct", "peak_memory_gb"]


def run_scaling(folder: Path, tiles: List[int], config: RegorConfig, out: Path, header: str) -> str:
    rows = []
    for count in tiles:
        rows.append(_in_child(_run_scaling, (str(folder), count, config)))
        print(", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in rows[-1].items()),
              flush=True)
    lines = [header, "", "| tiles | map points | map keypoints | search | map preparation s | median s per query "
             "(matching) | correct (published) | peak memory GB |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['tiles']} | {r['map_points']:,} | {r['map_keypoints']:,} | "
                     f"{'exact' if r['exact_search'] else 'index'} | {r['map_seconds']:.1f} | "
                     f"{r['median_seconds']:.2f} ({r['median_matching_seconds']:.2f}) | "
                     f"{r['correct']}/{r['queries']} ({r['published_correct']}) | {r['peak_memory_gb']:.2f} |")
    report = "\n".join(lines) + "\n"
    write_results(out, "map_scaling", report, rows, SCALING_FIELDS, _plot_scaling)
    return report


def _plot_scaling(rows: List[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    points = [r["map_points"] / 1e6 for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    axes[0].plot(points, [r["median_seconds"] for r in rows], "o-", label="registration (median)")
    axes[0].plot(points, [r["median_matching_seconds"] for r in rows], "s--", label="of it: feature matching")
    axes[0].set_xlabel("map points [millions]")
    axes[0].set_ylabel("seconds per query")
    axes[0].legend()
    axes[1].plot(points, [r["peak_memory_gb"] for r in rows], "o-")
    axes[1].set_xlabel("map points [millions]")
    axes[1].set_ylabel("peak memory [GB]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
