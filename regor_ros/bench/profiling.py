"""regor-bench --profile: where a registration spends its time, per stage and per function.

Pairs (each source moved by seed 1's rigid motion, as the pairs benchmark's first seed) are
registered end to end from raw clouds; map queries (single scans and fused sequences) against a
map prepared once, as the node does. Every registration runs under cProfile; the report gives the
stage medians from the pipeline's own clock and the functions with the most own time per
registration, so a kernel's before and after can be compared line by line.
"""
from __future__ import annotations

import cProfile
import pstats
import time
from pathlib import Path

import numpy as np

from ..core import RegorConfig, is_success, prepare_cloud, register
from .datasets import INPUTS, load_pairs, load_sequence, sequence_folders
from .results import STAGES, header

PROFILE_SEED = 1
TOP_FUNCTIONS = 25
COLUMNS = ("features", *STAGES, "total")


class Profiled:
    """One group of registrations (say, indoor pairs): their stage timings and one cProfile."""

    def __init__(self, name: str):
        self.name = name
        self.timings: list[dict[str, float]] = []
        self.correct = 0
        self.accepted = 0
        self.profile = cProfile.Profile()

    def run(self, register_call, truth: np.ndarray | None, kind: str) -> None:
        self.profile.enable()
        result = register_call()
        self.profile.disable()
        self.timings.append(result.timings)
        self.correct += bool(truth is not None and is_success(result.transform, truth, kind))
        self.accepted += bool(result.accepted)

    def stage_row(self) -> str:
        medians = [np.median([t.get(stage, 0.0) for t in self.timings]) for stage in COLUMNS]
        return (f"| {self.name} | {len(self.timings)} | {self.correct} | {self.accepted} | "
                + " | ".join(f"{m:.3f}" for m in medians) + " |")

    def function_table(self) -> str:
        stats = pstats.Stats(self.profile)
        rows = sorted(stats.stats.items(), key=lambda item: -item[1][2])[:TOP_FUNCTIONS]  # type: ignore[attr-defined]
        n = max(len(self.timings), 1)
        lines = [f"### {self.name}: the {TOP_FUNCTIONS} functions with the most own time", "",
                 "| function | calls per registration | own s per registration | cumulative s per registration |",
                 "|---|---|---|---|"]
        for (path, line, function), (_, calls, own, cumulative, _) in rows:
            where = f"{_short(path)}:{line}({function})" if line else function
            lines.append(f"| `{where}` | {calls / n:.1f} | {own / n:.4f} | {cumulative / n:.4f} |")
        return "\n".join(lines)


def _short(path: str) -> str:
    """A source path from the package or library it belongs to."""
    parts = Path(path).parts
    for anchor in ("regor_ros", "numpy", "scipy", "open3d", "faiss"):
        if anchor in parts:
            return "/".join(parts[len(parts) - 1 - parts[::-1].index(anchor):])
    return Path(path).name


def profile_pairs(folders: list[Path], name_filter: str | None) -> list[Profiled]:
    groups: dict[str, Profiled] = {}
    for folder in folders:
        for pair in load_pairs(folder, name_filter):
            moved = pair.moved(PROFILE_SEED)
            config = moved.configured(RegorConfig.preset(pair.kind))
            group = groups.setdefault(pair.kind, Profiled(f"{pair.kind} pairs"))
            group.run(lambda: register(moved.src, moved.tgt, config, source_viewpoint=moved.src_viewpoint,
                                       target_viewpoint=moved.tgt_viewpoint), moved.T_gt, pair.kind)
    return list(groups.values())


def profile_maps(folders: list[Path]) -> tuple:
    """(groups of map queries by input, [(sequence, map points, preparation seconds)])."""
    config = RegorConfig.preset("outdoor")
    groups = {which: Profiled(f"map queries, {which}") for which in INPUTS}
    maps = []
    for sequence in sequence_folders(folders):
        cloud, trajectory, queries = load_sequence(sequence)
        start = time.perf_counter()
        prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
        maps.append((sequence.name, len(cloud), time.perf_counter() - start))
        for query in queries:
            for which, group in groups.items():
                source = query.cloud(which)
                if source is not None:
                    group.run(lambda: register(source, prepared, config), query.truth, "outdoor")
    return [g for g in groups.values() if g.timings], maps


def run_profile(folders: list[Path], maps: list[Path] | None, name_filter: str | None, out: Path, argv) -> str:
    groups = profile_pairs(folders, name_filter)
    prepared_maps = []
    if maps is not None:
        map_groups, prepared_maps = profile_maps(maps)
        groups += map_groups
    lines = [header("regor_ros profile", argv).rstrip(),
             "", f"Pairs moved by seed {PROFILE_SEED}'s motion and registered from raw clouds (features "
             "included); map queries against a map prepared once. Times are under cProfile (its overhead "
             "is in every figure alike).", "",
             "## Stage medians (seconds)", "",
             "| group | registrations | correct | accepted | " + " | ".join(COLUMNS) + " |",
             "|---|---|---|---|" + "---|" * len(COLUMNS)]
    lines += [g.stage_row() for g in groups]
    if prepared_maps:
        lines += ["", "| map | points | preparation s |", "|---|---|---|"]
        lines += [f"| {name} | {points:,} | {seconds:.2f} |" for name, points, seconds in prepared_maps]
    for g in groups:
        lines += ["", g.function_table()]
    report = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "profile.md").write_text(report)
    return report

