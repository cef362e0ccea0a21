"""Scan-to-map relocalization benchmark (``regor-bench --maps DIR`` and ``--map-scaling``).

A sequence folder holds ``map.npy`` (no single viewpoint) with ``map_trajectory.txt`` (the sensor
poses it was built from), ``queries.json`` and ``queries/<id>/scan.npy`` + ``gt.txt`` (T_map_scan;
the scan's sensor at its origin), and ``scans/`` + ``odometry.txt``: the scans a robot received up
to each query with their odometry poses. Every query is registered twice: the scan alone, and the
scan fused with the ones before it along odometry (``sequence`` in queries.json), as the node does
with an odometry input. Regor prepares the map once with its trajectory and registers every query
against it, as the node does in map mode; KISS-Matcher gets the same scan or fused cloud and the
map on every call (it has no prepared-map interface). The cross-map set registers each sequence's
queries against every other place's map (one_place): any published pose there is wrong. Each (map,
method) runs in its own process so that its peak memory is its own.

``--map-scaling`` tiles one real map side by side (each copy turned about the vertical) to grow
it, and measures map preparation, registration time and peak memory against map size: a cold
start (prepared from the file) and a warm start (from the cache) with the queries, each in a
process of its own. The copies are identical, so a pose is scored against the nearest copy's truth.
"""
from __future__ import annotations

import multiprocessing
import resource
import time
from pathlib import Path

import numpy as np

from ..core import (
    ERROR_SIGMAS_99,
    RegistrationError,
    RegorConfig,
    ScanSequence,
    at_rest,
    error_sigmas,
    is_success,
    prepare_cloud,
    register,
    rotation_error_deg,
    to_matrix,
    translation_error,
    warm_up,
)
from ..io.map_file import load_map_file, write_trajectory
from .datasets import (
    INPUTS,
    MAP_UP,
    NARROW_AT_REST_INPUTS,
    NARROW_FIELD_DEG,
    NARROW_HEADINGS,
    NARROW_INPUTS,
    NARROW_MIN_RETURNS,
    NARROW_STEP_DEG,
    RESTING_FRAMES,
    STRESS_INPUTS,
    TILE_SPACING,
    gravity_overrides,
    imu_up,
    load_sequence,
    one_place,
    place_of,
    sequence_folders,
    tile_poses,
    tiled,
)
from .peers import NO_PRIOR, PLANE, kiss_matcher_pose
from .results import GATE_COLUMNS, STAGES, gate_columns, selected, write_results

# method: its config overrides
REGOR_VARIANTS: dict[str, dict] = {"regor": {}, "regor-noprior": NO_PRIOR, "regor-plane": PLANE}
MAP_METHODS = (*REGOR_VARIANTS, "kiss-matcher")
# --level: the gravity prior of a level-mounted sensor in a z-up map (a ground vehicle's)
LEVEL_MOUNTED = {"gravity.source_up": "0 0 1", "gravity.target_up": "0 0 1"}
MAP_FIELDS = ["map", "method", "query", "input", "set", "pair", "kind", "query_kind", "scans", "map_points",
              "map_keypoints", "success", "accepted", "rotation_error_deg", "translation_error_m", "seconds",
              *(f"seconds_{stage}" for stage in STAGES), "map_seconds", "peak_memory_gb", "error_sigmas",
              *GATE_COLUMNS, "error"]
NARROW_NOTE = (" Narrow (--narrow): each query scan as a narrow solid-state sensor at its origin would see it, "
               f"facing {', '.join(map(str, NARROW_HEADINGS))} deg about its z axis (input `narrow <heading>`): "
               f"the nearest return per {NARROW_STEP_DEG:g} deg of azimuth and elevation over "
               f"{NARROW_FIELD_DEG:g} x {NARROW_FIELD_DEG:g} deg, views with fewer than {NARROW_MIN_RETURNS} "
               "returns left out.")
AT_REST_NOTE = (f" At rest (--at-rest): each narrow view also as {RESTING_FRAMES} frames of the sensor at rest, each "
                "the nearest return per bin of a grid shifted by a random fraction of a bin (a non-repeating "
                "pattern filling in), the newest the view itself; Regor fuses the ones the scans show were "
                "taken at rest, at identity (core.at_rest, as the node does without odometry), KISS-Matcher is "
                "given the same (input `narrow <heading> at rest`).")
STRESS_NOTE = (" Stress (--stress): each map is enlarged with every other place's map (and trajectory), "
               f"{TILE_SPACING:.0f} m apart, so the target is several times the size it was and chance support "
               "grows; `thinned` is the query scan with every 4th point (a sparse sensor's density).")
IMU_NOTE = (" IMU up (--imu-up {:g}): each query is given its up as an IMU would give it, the truth's "
            "tilted by that many degrees about a horizontal axis drawn per query, and the map's up (z) "
            "(gravity.source_up, gravity.target_up); regor-noprior runs without it.")
SCALING_QUERIES = 10  # queries registered at each map size (fewer: the median moved between runs)


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB on Linux


def _score(T: np.ndarray, truths: list[np.ndarray]) -> tuple:
    """(success, rotation error, translation error) against the nearest of the true poses."""
    best = min(truths, key=lambda G: translation_error(T, G))
    return is_success(T, best, "outdoor"), rotation_error_deg(T, best), translation_error(T, best)


def enlarged(cloud: np.ndarray, trajectory: np.ndarray | None, others: list[str]):
    """(cloud, trajectory) with every other place's map beside it, TILE_SPACING apart along x: a
    target several times larger where the true place is still inside, so chance support grows."""
    clouds, trajectories = [cloud], [trajectory]
    for k, other in enumerate(others, start=1):
        shift = to_matrix(np.eye(3), np.array([k * TILE_SPACING, 0.0, 0.0]))
        other_cloud, other_trajectory, _ = load_sequence(Path(other))
        clouds.append(other_cloud + shift[:3, 3])
        trajectories.append(None if other_trajectory is None else shift @ other_trajectory)
    known = [t for t in trajectories if t is not None]
    return np.vstack(clouds), (np.concatenate(known) if len(known) == len(trajectories) else None)


def _run_map(job) -> list[dict]:
    """One method on every query against one map (in a child process): the map's own queries,
    then every other sequence's (cross-map: no true pose), each as each of ``inputs``. Under
    ``stress`` the map is enlarged with the other places' maps instead (``enlarged``), its own
    queries also go in thinned, and there is no cross-map set (the other places are inside the map)."""
    folder, others, method, config, stress, inputs, imu_tilt = job
    warm_up()  # this child's compile or cache load, before any clock starts
    cloud, trajectory, queries = load_sequence(Path(folder))
    if stress:
        cloud, trajectory = enlarged(cloud, trajectory, others)
    else:
        for other in others:
            queries += load_sequence(Path(other))[2]
    name = Path(folder).name
    base = {"map": name, "method": method, "kind": "outdoor", "map_points": len(cloud)}
    regor = method in REGOR_VARIANTS
    if regor:
        config = config.replace(REGOR_VARIANTS[method])
        start = time.perf_counter()
        prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
        base.update(map_seconds=time.perf_counter() - start, map_keypoints=len(prepared))
    rows = []
    for query in queries:
        for which in inputs:
            source = query.cloud(which)
            if source is None:
                continue
            if isinstance(source, list):   # a resting sensor's frames: fused as the node fuses them
                fused, _ = at_rest(source, config.features.voxel_size, config.features.normal_radius)
                source = source[-1] if fused is None else fused
            same = query.sequence == name
            row = dict(base, query=f"{query.sequence}/{query.id}", input=which, query_kind=query.kind,
                       set="same" if same else "cross",
                       scans=len(source.scans) if isinstance(source, ScanSequence) else 1,
                       pair=f"{place_of(query.sequence)} ({query.id} {which}) -> {place_of(name)} (map)", error="")
            if regor:
                given = config
                if imu_tilt is not None:   # the variant's own settings last: regor-noprior stays without
                    up = imu_up(query.truth, MAP_UP, imu_tilt, f"{query.sequence}/{query.id}")
                    given = config.replace({**gravity_overrides(up, MAP_UP), **REGOR_VARIANTS[method]})
                try:
                    result = register(source, prepared, given)
                except RegistrationError as exc:   # too few keypoints in a narrow view: no pose, said why
                    rows.append(dict(row, success=False, accepted=False, rotation_error_deg=np.nan,
                                     translation_error_m=np.nan, seconds=np.nan, error=str(exc)[:200]))
                    continue
                T, seconds, accepted = result.transform, result.timings["total"], result.accepted
                row.update(gate_columns(result.summary()))
                if same:
                    row["error_sigmas"] = error_sigmas(T, query.truth, result.covariance)
            else:
                points = source.fused().points if isinstance(source, ScanSequence) else source
                T, seconds, accepted = kiss_matcher_pose(points, cloud, config.features.voxel_size)
            success, rot, trans = _score(T, [query.truth]) if same else (False, np.nan, np.nan)
            row.update(success=success, accepted=accepted, rotation_error_deg=rot, translation_error_m=trans,
                       seconds=seconds)
            rows.append(row)
    for row in rows:
        row["peak_memory_gb"] = _peak_gb()
    return rows


def _in_child(function, job):
    """Run ``function(job)`` in a fresh process, so its peak memory is measured alone."""
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        return pool.apply(function, (job,))


def _median(values) -> float:
    """The median of the finite values (a query refused as input has no time)."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.median(finite)) if finite else float("nan")


def _groups(rows: list[dict], *keys) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    return groups


def _published(group: list[dict]) -> tuple:
    """(published correct, published wrong)."""
    right = sum(r["accepted"] is True and r["success"] for r in group)
    return right, sum(r["accepted"] is True for r in group) - right


def map_report(rows: list[dict], header: str) -> str:
    same = [r for r in rows if r["set"] == "same"]
    cross = [r for r in rows if r["set"] == "cross"]
    lines = [header, "", "## Queries against their own map", "",
             "`single`: the query scan alone; `sequence`: fused with the scans received just before it "
             "(odometry). KISS-Matcher's `published` is its own valid flag.", "",
             "| method | input | queries | correct | published correct / WRONG | published correct / all queries "
             "| published correct / correct | median s per query |", "|---|---|---|---|---|---|---|---|"]
    for (method, which), group in _groups(same, "method", "input").items():
        correct = sum(r["success"] for r in group)
        right, wrong = _published(group)
        lines.append(f"| {method} | {which} | {len(group)} | {correct} | {right} / {wrong} | "
                     f"{100 * right / len(group):.0f} % | {100 * right / max(correct, 1):.0f} % | "
                     f"{_median([r['seconds'] for r in group]):.2f} |")
    lines += ["", "Per map:", "", "| map | method | input | correct | published correct / WRONG | median s | "
              "map preparation s | peak memory GB |", "|---|---|---|---|---|---|---|---|"]
    for (name, method, which), group in _groups(same, "map", "method", "input").items():
        right, wrong = _published(group)
        prep = group[0].get("map_seconds")
        lines.append(f"| {name} | {method} | {which} | {sum(r['success'] for r in group)}/{len(group)} | "
                     f"{right} / {wrong} | {_median([r['seconds'] for r in group]):.2f} | "
                     f"{'-' if prep is None else f'{prep:.1f}'} | {group[0]['peak_memory_gb']:.2f} |")
    covered = [r for r in same if r["accepted"] is True and r["success"] and "error_sigmas" in r]
    for (method,), group in _groups(covered, "method").items():
        within = sum(r["error_sigmas"] <= ERROR_SIGMAS_99 for r in group)
        lines += ["", f"{method}'s covariance against the truth: {within} of {len(group)} published correct poses "
                  f"lie within its 99 % ellipsoid (6-D Mahalanobis distance at most {ERROR_SIGMAS_99}); median "
                  f"{_median([r['error_sigmas'] for r in group]):.1f} sigma, largest "
                  f"{max(r['error_sigmas'] for r in group):.1f}."]
    if cross:
        lines += ["", "## Cross-map: every query against every other place's map (any published pose is wrong)", "",
                  "| method | input | registrations | published WRONG | median s |", "|---|---|---|---|---|"]
        for (method, which), group in _groups(cross, "method", "input").items():
            lines.append(f"| {method} | {which} | {len(group)} | {_published(group)[1]} | "
                         f"{_median([r['seconds'] for r in group]):.2f} |")
    timed = list(_groups([r for r in same if "seconds_matching" in r], "map", "input").items())
    if timed:
        lines += ["", "Regor's median seconds per stage (the scan's FPFH and the map's views are the rest):", "",
                  "| map | input | " + " | ".join(STAGES) + " |", "|---|---|" + "---|" * len(STAGES)]
        for (name, which), group in timed:
            medians = (_median([r[f"seconds_{stage}"] for r in group]) for stage in STAGES)
            lines.append(f"| {name} | {which} | " + " | ".join(f"{m:.3f}" for m in medians) + " |")
    lines += ["", "Per query (error against the truth; `published` = passed the method's own gate):", "",
              "| query | input | method | correct | published | RE deg | TE m | s | reason |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in same:
        lines.append(f"| {r['query']} | {r['input']} | {r['method']} | {'yes' if r['success'] else 'no'} | "
                     f"{'yes' if r['accepted'] else 'no'} | {r['rotation_error_deg']:.1f} | "
                     f"{r['translation_error_m']:.2f} | {r['seconds']:.2f} | {r.get('reason', '')} |")
    return "\n".join(lines) + "\n"


def run_maps(folders: list[Path], methods: list[str], config: RegorConfig, out: Path, header: str,
             name_filter: str | None = None, stress: bool = False, narrow: bool = False,
             imu_tilt: float | None = None, at_rest: bool = False) -> str:
    """The map of every sequence under ``folders`` (whose name contains one of the comma-separated
    ``name_filter``) with every method, against its own queries and every other place's (one_place);
    writes maps.md, .csv and .png. With ``stress``: each map enlarged with the other places'
    maps, its queries single, thinned and fused (stress.md, .csv and .png). With ``narrow``: the
    query scans seen by a narrow sensor (narrow_view; narrow.md, .csv and .png). With ``imu_tilt``
    (degrees): every query given its up as an IMU would (imu_up), but to regor-noprior. With
    ``at_rest`` (and ``narrow``): each narrow view also as the frames of a sensor at rest
    (resting_frames), fused as the node fuses them (core.at_rest)."""
    inputs, name = (STRESS_INPUTS, "stress") if stress else (NARROW_INPUTS, "narrow") if narrow else (INPUTS, "maps")
    if at_rest:
        inputs, name = NARROW_INPUTS + NARROW_AT_REST_INPUTS, "at_rest"
    sequences = [str(p) for p in sequence_folders(folders)]
    maps = [s for s in sequences if selected(Path(s).name, name_filter)]
    if not maps:
        matching = f" matching {name_filter!r}" if name_filter else ""
        raise SystemExit(f"{', '.join(map(str, folders))} hold no sequence folder with queries.json{matching}")
    rows = []
    for sequence in maps:
        others = [s for s in sequences if not one_place(Path(s).name, Path(sequence).name)]
        for method in methods:
            new = _in_child(_run_map, (sequence, others, method, config, stress, inputs, imu_tilt))
            rows += new
            own = [r for r in new if r["set"] == "same"]
            print(f"{Path(sequence).name} {method}: {sum(r['success'] for r in own)} of {len(own)} correct, "
                  f"{sum(r['accepted'] is True and r['success'] for r in own)} published; cross-map: "
                  f"{sum(r['accepted'] is True for r in new if r['set'] == 'cross')} published", flush=True)
    report = map_report(rows, header)
    write_results(out, name, report, rows, MAP_FIELDS, _plot_maps)
    return report


def _plot_maps(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    same = [r for r in rows if r["set"] == "same"]
    groups = sorted(_groups(same, "method", "input").items())
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(groups))
    axes[0].bar(x - 0.2, [sum(r["success"] for r in g) for _, g in groups], 0.4, label="correct")
    axes[0].bar(x + 0.2, [_published(g)[0] for _, g in groups], 0.4, label="published correct")
    axes[0].bar(x + 0.2, [_published(g)[1] for _, g in groups], 0.4,
                bottom=[_published(g)[0] for _, g in groups], color="red", label="published WRONG")
    axes[0].set_ylabel("queries against their own map")
    axes[0].legend()
    axes[1].bar(x, [_median([r["seconds"] for r in g]) for _, g in groups])
    axes[1].set_ylabel("median seconds per query")
    for ax in axes:
        ax.set_xticks(x, [f"{m}\n{i}" for (m, i), _ in groups], fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- scaling: one real map tiled ---


def _cold_start(job) -> dict:
    """Write the tiled map to files in ``scratch`` and prepare it from them, as a robot's first
    start does (the cache written beside them); in a child process, so its peak is that start's."""
    warm_up()
    folder, tiles, config, scratch = job
    cloud, trajectory, _ = load_sequence(Path(folder))
    big, poses = tiled(cloud, tiles)
    map_points = len(big)
    map_file, trajectory_file = Path(scratch) / "map.npy", None
    np.save(map_file, big)
    del cloud, big
    if trajectory is not None:
        trajectory_file = Path(scratch) / "trajectory.txt"
        write_trajectory(trajectory_file, np.concatenate([P @ trajectory for P in poses]))
    start = time.perf_counter()
    cold = load_map_file(map_file, config, trajectory_file)
    return {"map_points": map_points, "map_seconds": time.perf_counter() - start,
            "cache_mb": cold.info["map_cache_bytes"] / 1e6, "cold_peak_memory_gb": _peak_gb()}


def _warm_start(job) -> dict:
    """Load the prepared map from its cache (a robot's restart) and register the queries against
    it; in a child process of its own, so its peak is a restarted robot's."""
    warm_up()
    folder, tiles, config, scratch = job
    _, _, queries = load_sequence(Path(folder))
    queries = [q for q in queries if q.kind == "scan"][:SCALING_QUERIES]
    poses = tile_poses(tiles)
    trajectory_file = Path(scratch) / "trajectory.txt"
    start = time.perf_counter()
    warm = load_map_file(Path(scratch) / "map.npy", config, trajectory_file if trajectory_file.is_file() else None)
    warm_seconds = time.perf_counter() - start
    prepared = warm.prepared
    seconds, matching, correct, published = [], [], 0, 0
    for query in queries:
        result = register(query.scan, prepared, config)
        seconds.append(result.timings["total"])
        matching.append(result.timings["matching"])
        success = _score(result.transform, [P @ query.truth for P in poses])[0]
        correct += success
        published += success and result.accepted
    return {"map_keypoints": len(prepared), "exact_search": prepared.index.exact, "warm_seconds": warm_seconds,
            "first_pose_seconds": warm_seconds + seconds[0],
            "median_seconds": _median(seconds), "median_matching_seconds": _median(matching),
            "queries": len(seconds), "correct": correct, "published_correct": published,
            "peak_memory_gb": _peak_gb()}


def _run_scaling(folder: Path, tiles: int, config: RegorConfig) -> dict:
    """One map size: its cold start and its warm start with the queries, each in a process of its own."""
    import tempfile
    with tempfile.TemporaryDirectory() as scratch:
        job = (str(folder), tiles, config, scratch)
        return {"tiles": tiles, **_in_child(_cold_start, job), **_in_child(_warm_start, job)}


SCALING_FIELDS = ["tiles", "map_points", "map_keypoints", "exact_search", "map_seconds", "cache_mb",
                  "cold_peak_memory_gb", "warm_seconds", "first_pose_seconds", "median_seconds",
                  "median_matching_seconds", "queries", "correct", "published_correct", "peak_memory_gb"]


def run_scaling(folder: Path, tiles: list[int], config: RegorConfig, out: Path, header: str) -> str:
    rows = []
    for count in tiles:
        rows.append(_run_scaling(folder, count, config))
        print(", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in rows[-1].items()),
              flush=True)
    lines = [header, "", "| tiles | map points | map keypoints | search | cold start s (prepared, cached) | cache MB "
             "| warm start s (cache loaded) | first pose after a warm start s | median s per query (matching) "
             "| correct (published) | peak memory GB, cold start / warm start and queries |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['tiles']} | {r['map_points']:,} | {r['map_keypoints']:,} | "
                     f"{'exact' if r['exact_search'] else 'index'} | {r['map_seconds']:.1f} | {r['cache_mb']:.0f} | "
                     f"{r['warm_seconds']:.2f} | {r['first_pose_seconds']:.2f} | "
                     f"{r['median_seconds']:.2f} ({r['median_matching_seconds']:.2f}) | "
                     f"{r['correct']}/{r['queries']} ({r['published_correct']}) | "
                     f"{r['cold_peak_memory_gb']:.2f} / {r['peak_memory_gb']:.2f} |")
    report = "\n".join(lines) + "\n"
    write_results(out, "map_scaling", report, rows, SCALING_FIELDS, _plot_scaling)
    return report


def _plot_scaling(rows: list[dict], path: Path) -> None:
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
    axes[1].plot(points, [r["cold_peak_memory_gb"] for r in rows], "s--", label="cold start (preparing)")
    axes[1].plot(points, [r["peak_memory_gb"] for r in rows], "o-", label="warm start (cache) and queries")
    axes[1].legend()
    axes[1].set_xlabel("map points [millions]")
    axes[1].set_ylabel("peak memory [GB]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
