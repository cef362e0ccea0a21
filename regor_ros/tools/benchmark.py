"""regor-bench: Regor against the methods users would otherwise pick, on a folder of real pairs.

A folder holds ``pairs.json`` (name and kind of every pair) and ``<name>/src.npy``,
``tgt.npy``, ``gt.txt`` (T_target_source). Each pair is registered by every method on the same
downsampled clouds and FPFH features (preset chosen by kind); ``--rotate SEED`` first moves every
source by a random rigid motion (truth adjusted). Writes a markdown table, a per-pair CSV and
plots, and prints the table.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import json
import os
import platform
import sys
import time
import traceback
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from ..core import RegorConfig, prepare_cloud
from ..core.config import ConfigError
from ..core.matching import match_features
from ..core.visibility import ORIGIN
from ..core.metrics import (INLIER_THRESHOLDS, correct_mask, is_success, random_rigid_motion,
                            rotation_error_deg, translation_error)
from .peers import DESCRIPTIONS, METHODS
from .register_cli import parse_overrides

UP_Z = np.array([0.0, 0.0, 1.0])  # a level-mounted sensor's up in its own frame
LEVEL_NOTE = (" Gravity prior (--level): every cloud's z axis is up (level-mounted sensors on ground "
              "vehicles); `-noprior` methods run without it.")
STAGES = ("matching", "initial", "regeneration", "estimation", "verification")  # of Regor's timings
EVIDENCE_COLUMNS = ["surface_agreement", "independent_agreeing", "log10_false_alarms", "candidate_margin"]
CSV_FIELDS = ["seed", "pair", "kind", "method", "success", "accepted", "rotation_error_deg",
              "translation_error_m", "seconds_registration", "seconds_total",
              *(f"seconds_{stage}" for stage in STAGES), "inliers_final",
              "final_count", "inliers_initial", "initial_count", "reason", "num_inliers", "fitness",
              "feature_inliers", "free_space_source", "free_space_target", "opposite_sides", "ambiguity", "rivals",
              *EVIDENCE_COLUMNS, "error"]


def gate_columns(figures: dict) -> dict:
    """The verdict, the gate's figures and the stage timings of a RegistrationResult.summary(), as
    CSV columns (what regor-calibrate-gate reads)."""
    visibility, evidence = figures["visibility"], figures["evidence"] or {}
    return {**{f"seconds_{stage}": figures["timings"][stage] for stage in STAGES},
            "reason": figures["reason"], "num_inliers": figures["num_inliers"],
            "fitness": figures["fitness"], "feature_inliers": figures["feature_inliers"],
            "free_space_source": visibility["source_violation"],
            "free_space_target": visibility["target_violation"],
            "opposite_sides": visibility["opposite_sides"], "map_seen": visibility["map_seen"],
            "ambiguity": figures["ambiguity"],
            "rivals": ";".join(f"{r['inlier_ratio']:.3f}:{r['feature_ratio']:.3f}:"
                               f"{r['violation']}:{r['opposite_sides']}:{r['distance_deg']:.1f}"
                               for r in figures["rivals"]),
            **{name: evidence.get(name) for name in EVIDENCE_COLUMNS[:3]},
            "candidate_margin": figures["candidate_margin"]}


def load_pairs(folder: Path, name_filter: Optional[str]):
    """Each selected pair; its index in pairs.json seeds the pair's random motion, so a filtered
    run moves a pair as a full run does."""
    listing = json.loads((folder / "pairs.json").read_text())
    for index, entry in enumerate(listing):
        if not selected(entry["name"], name_filter):
            continue
        d = folder / entry["name"]
        yield Pair(index, entry["name"], entry["kind"], np.load(d / "src.npy"), np.load(d / "tgt.npy"),
                   np.loadtxt(d / "gt.txt"), _viewpoint(entry.get("src_viewpoint", ORIGIN)),
                   _viewpoint(entry.get("tgt_viewpoint", ORIGIN)))


def selected(name: str, name_filter: Optional[str]) -> bool:
    """Whether ``name`` contains one of the comma-separated ``name_filter`` strings (all names
    are selected without a filter): --pairs."""
    return not name_filter or any(part in name for part in name_filter.split(","))


def _viewpoint(value):
    return None if value is None else np.asarray(value, dtype=np.float64)


@dataclass
class Pair:
    index: int
    name: str
    kind: str
    src: np.ndarray
    tgt: np.ndarray
    T_gt: Optional[np.ndarray]              # T_target_source; None: different places, no true pose
    src_viewpoint: Optional[np.ndarray]     # sensor position in the cloud's frame; None = unknown
    tgt_viewpoint: Optional[np.ndarray]
    src_up: Optional[np.ndarray] = None     # up direction in the cloud's frame; None = unknown
    tgt_up: Optional[np.ndarray] = None

    def moved(self, seed: Optional[int]) -> "Pair":
        """The pair with its source (and the source's viewpoint and up) moved by the seeded motion."""
        if seed is None:
            return self
        M = random_rigid_motion([seed, self.index])
        viewpoint = None if self.src_viewpoint is None else M[:3, :3] @ self.src_viewpoint + M[:3, 3]
        return dataclasses.replace(self, src=self.src @ M[:3, :3].T + M[:3, 3],
                                   T_gt=None if self.T_gt is None else self.T_gt @ np.linalg.inv(M),
                                   src_viewpoint=viewpoint,
                                   src_up=None if self.src_up is None else M[:3, :3] @ self.src_up)

    def swapped(self) -> "Pair":
        """The target as the source and the source as the target; no true pose."""
        return dataclasses.replace(self, src=self.tgt, tgt=self.src, T_gt=None,
                                   src_viewpoint=self.tgt_viewpoint, tgt_viewpoint=self.src_viewpoint,
                                   src_up=self.tgt_up, tgt_up=self.src_up)

    def configured(self, config: RegorConfig) -> RegorConfig:
        """``config`` with the pair's up directions as its gravity prior, when both are known."""
        if self.src_up is None or self.tgt_up is None:
            return config
        return config.replace({"gravity.source_up": " ".join(f"{v:.9f}" for v in self.src_up),
                               "gravity.target_up": " ".join(f"{v:.9f}" for v in self.tgt_up)})


def evaluate_pair(pair: Pair, methods, config: RegorConfig, seed) -> List[dict]:
    """Every method on one pair; a crash counts as a failure with its error recorded."""
    name, kind, src, tgt, T_gt = pair.name, pair.kind, pair.src, pair.tgt, pair.T_gt
    t0 = time.perf_counter()
    source = prepare_cloud(src, config, "source", viewpoint=pair.src_viewpoint)
    target = prepare_cloud(tgt, config, "target", viewpoint=pair.tgt_viewpoint)
    feature_seconds = time.perf_counter() - t0
    threshold = INLIER_THRESHOLDS[kind]
    nearest = match_features(source, target, 1, np.zeros(0, np.int64), mutual=False).target_index
    initial_correct = 0 if T_gt is None else int(correct_mask(source.points, target.points[nearest],
                                                                T_gt, threshold).sum())
    rows = []
    for method in methods:
        row = {"seed": seed, "pair": name, "kind": kind, "method": method, "success": False,
               "accepted": "", "inliers_initial": initial_correct, "initial_count": len(source),
               "error": ""}
        try:
            out = METHODS[method](source, target, src, tgt, config, seed or 0)
        except Exception as exc:  # a crashing peer fails this pair; the run goes on
            row["error"] = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:200]
            traceback.print_exc(file=sys.stderr)
            rows.append(row)
            continue
        row.update({
            "success": T_gt is not None and is_success(out.transform, T_gt, kind),
            "accepted": "" if out.accepted is None else out.accepted,
            "rotation_error_deg": np.nan if T_gt is None else rotation_error_deg(out.transform, T_gt),
            "translation_error_m": np.nan if T_gt is None else translation_error(out.transform, T_gt),
            "seconds_registration": out.seconds,
            "seconds_total": out.seconds + (0.0 if out.includes_features else feature_seconds),
        })
        if out.figures is not None:
            row.update(gate_columns(out.figures))
        if out.final is not None and T_gt is not None:
            row["inliers_final"] = int(correct_mask(*out.final, T_gt, threshold).sum())
            row["final_count"] = len(out.final[0])
        rows.append(row)
    return rows


def place(name: str) -> str:
    """Where a pair was scanned: its name without fragment or scan numbers (``hotel_umd3_15_16``
    and ``hotel_umd_8_15`` are both maryland_hotel3)."""
    name = name.split(" (")[0]  # a cross-place run's role label: "(target)", "(source)"
    parts = [part.rstrip("0123456789") for part in name.split("_")
             if not part.isdigit() and part not in ("ds", "to")]
    return "_".join(part for part in parts if part)


def same_place(a: str, b: str) -> bool:
    """Conservative: ``avia_hku`` and ``avia_hkumb`` (one campus) count as one place."""
    return a.startswith(b) or b.startswith(a)


def cross_place_pairs(pairs: List[Pair], seed: Optional[int]) -> List[Pair]:
    """Each distinct source against one target of every other place of its kind, and each
    distinct target, as the source, against one source of every other place (a different one for
    each motion seed, round robin). There is no true pose, so any accepted pose is wrong. Both
    directions, because a wrong pose can pass the gate one way round and not the other."""
    swapped = [p.swapped() for p in pairs]
    return _crossed(pairs, seed, "", "") + _crossed(swapped, seed, " (target)", " (source)")


def _crossed(pairs: List[Pair], seed: Optional[int], source_role: str, target_role: str) -> List[Pair]:
    """Each distinct source cloud against one target cloud of every other place; the role labels
    name which cloud of each pair was used when it is not the usual one."""
    sources, targets = {}, defaultdict(dict)
    for p in pairs:
        sources.setdefault(p.src.tobytes().__hash__(), p)
        targets[(p.kind, place(p.name))].setdefault(p.tgt.tobytes().__hash__(), p)
    crossed = []
    for a in sources.values():
        for (kind, where), group in sorted(targets.items()):
            if kind != a.kind or same_place(where, place(a.name)):
                continue
            group = list(group.values())
            b = group[((seed or 0) + a.index) % len(group)]
            crossed.append(dataclasses.replace(
                a, name=f"{a.name}{source_role} -> {b.name}{target_role}", tgt=b.tgt, T_gt=None,
                tgt_viewpoint=b.tgt_viewpoint, tgt_up=b.tgt_up))
    return crossed


def _mean(values) -> float:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else float("nan")


def summarise(rows: List[dict]) -> Dict:
    """Per (method, kind) figures, kind "all" included; recall also as mean and spread over seeds."""
    groups = defaultdict(list)
    for r in rows:
        groups[(r["method"], r["kind"])].append(r)
        groups[(r["method"], "all")].append(r)
    summary = {}
    for key, rs in groups.items():
        ok = [r for r in rs if r["success"]]
        by_seed = defaultdict(list)
        for r in rs:
            by_seed[r["seed"]].append(r["success"])
        seed_recalls = [np.mean(v) for v in by_seed.values()]
        with_final = [r for r in rs if "inliers_final" in r]
        timed = [r for r in rs if "seconds_total" in r]
        accepted = [r for r in rs if r["accepted"] is True]
        summary[key] = {
            "pairs": len(rs),
            "successes": len(ok),
            "recall": len(ok) / len(rs),
            "recall_spread": float(np.std(seed_recalls)) if len(seed_recalls) > 1 else 0.0,
            "re": _mean([r["rotation_error_deg"] for r in ok]),
            "te_cm": 100 * _mean([r["translation_error_m"] for r in ok]),
            "ip": _mean([r["inliers_final"] / r["final_count"] if r["final_count"] else 0.0 for r in with_final]),
            "in": _mean([r["inliers_final"] for r in with_final]),
            "inr": 100 * _mean([r["inliers_final"] / r["inliers_initial"] if r["inliers_initial"]
                                else r["inliers_final"] for r in with_final]),
            "fmr": 100 * _mean([r["inliers_initial"] / r["initial_count"] > 0.05 for r in rs]),
            "median_s": float(np.median([r["seconds_total"] for r in timed])) if timed else float("nan"),
            "p90_s": float(np.percentile([r["seconds_total"] for r in timed], 90)) if timed else float("nan"),
            "median_reg_s": float(np.median([r["seconds_registration"] for r in timed])) if timed else float("nan"),
            "stage_s": {stage: float(np.median([r[f"seconds_{stage}"] for r in timed]))
                        for stage in STAGES if timed and all(f"seconds_{stage}" in r for r in timed)},
            "features_s": float(np.median([r["seconds_total"] - r["seconds_registration"] for r in timed]))
                          if timed else float("nan"),
            "accepted": len(accepted) if rs[0]["accepted"] != "" else None,
            "false_accepts": sum(1 for r in accepted if not r["success"]) if rs[0]["accepted"] != "" else None,
        }
    return summary


def _fmt(value, spec: str) -> str:
    return "–" if value is None or (isinstance(value, float) and np.isnan(value)) else format(value, spec)


def markdown(summary: Dict, rows: List[dict], methods: List[str], header: str) -> str:
    kinds = sorted({k for _, k in summary if k != "all"}) + ["all"]
    lines = [header, "", "| kind | method | RR | successes | RE ° | TE cm | IP % | IN | INR % | "
             "median s (reg) | p90 s | published correct / WRONG |", "|" + "---|" * 12]
    for kind in kinds:
        for method in methods:
            s = summary.get((method, kind))
            if s is None:
                continue
            rr = f"{100 * s['recall']:.1f} %" + (f" ± {100 * s['recall_spread']:.1f}" if s["recall_spread"] else "")
            acc = "–" if s["accepted"] is None else f"{s['accepted'] - s['false_accepts']} / {s['false_accepts']}"
            lines.append(
                f"| {kind} | {method} | {rr} | {s['successes']}/{s['pairs']} | {_fmt(s['re'], '.2f')} | "
                f"{_fmt(s['te_cm'], '.1f')} | {_fmt(100 * s['ip'], '.1f')} | {_fmt(s['in'], '.0f')} | "
                f"{_fmt(s['inr'], '.0f')} | {_fmt(s['median_s'], '.2f')} ({_fmt(s['median_reg_s'], '.2f')}) | "
                f"{_fmt(s['p90_s'], '.2f')} | {acc} |")
    staged = [(kind, method) for kind in kinds for method in methods
              if summary.get((method, kind), {}).get("stage_s")]
    if staged:
        lines += ["", "Median seconds per stage (FPFH of both clouds, then the stages of the attempt "
                  "returned; retries re-run them):", "",
                  "| kind | method | features | " + " | ".join(STAGES) + " |", "|" + "---|" * (len(STAGES) + 3)]
        for kind, method in staged:
            s = summary[(method, kind)]
            lines.append(f"| {kind} | {method} | {_fmt(s['features_s'], '.2f')} | "
                         + " | ".join(_fmt(s["stage_s"][stage], ".3f") for stage in STAGES) + " |")
    fmr = {kind: summary[(methods[0], kind)]["fmr"] for kind in kinds}
    lines += ["", "FMR (initial FPFH matches more than 5 % correct): " +
              ", ".join(f"{k} {v:.0f} %" for k, v in fmr.items()), ""]
    lines += ["Per pair (successes over seeds):", "",
              "| pair | kind | " + " | ".join(methods) + " |", "|" + "---|" * (len(methods) + 2)]
    per_pair = defaultdict(lambda: defaultdict(list))
    kind_of = {}
    for r in rows:
        per_pair[r["pair"]][r["method"]].append(r["success"])
        kind_of[r["pair"]] = r["kind"]
    for pair, by_method in per_pair.items():
        cells = [f"{sum(by_method[m])}/{len(by_method[m])}" for m in methods]
        lines.append(f"| {pair} | {kind_of[pair]} | " + " | ".join(cells) + " |")
    lines += ["", "Methods:", ""] + [f"- `{m}`: {DESCRIPTIONS[m]}" for m in methods]
    return "\n".join(lines) + "\n"


def plots(summary: Dict, methods: List[str], out: Path) -> None:
    """Recall per kind, median time and correct final correspondences, as one PNG at ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    kinds = sorted({k for _, k in summary})
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    width = 0.8 / len(methods)
    x = np.arange(len(kinds))
    for i, method in enumerate(methods):
        recall = [100 * summary.get((method, k), {"recall": np.nan})["recall"] for k in kinds]
        axes[0].bar(x + i * width, recall, width, label=method)
    axes[0].set_xticks(x + 0.4 - width / 2, kinds)
    axes[0].set_ylabel("registration recall [%]")
    axes[0].set_title("Recall per kind")
    axes[0].legend(fontsize=8)
    for ax, key, label in [(axes[1], "median_s", "median time per pair, features included [s]"),
                           (axes[2], "in", "mean correct final correspondences (IN)")]:
        values = [summary[(m, "all")][key] for m in methods]
        ax.bar(methods, np.nan_to_num(values), color=[f"C{i}" for i in range(len(methods))])
        ax.set_title(label)
        ax.tick_params(axis="x", rotation=30)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, Python {platform.python_version()}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, nargs="*",
                        help="folders with pairs.json and one folder per pair")
    parser.add_argument("--methods", help=f"comma-separated subset of: {', '.join(METHODS)} (default: "
                                          "all; with --maps or --map-scaling: regor, kiss-matcher)")
    parser.add_argument("--rotate", type=int, nargs="+", metavar="SEED",
                        help="move each source by a random rigid motion drawn from SEED; several "
                             "seeds give a mean and spread")
    parser.add_argument("--pairs", help="only pairs (with --maps: sequences) whose name contains one of "
                                        "these comma-separated strings")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a core parameter for every preset (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    parser.add_argument("--level", action="store_true",
                        help="the clouds come from level-mounted sensors in z-up frames (ground "
                             "vehicles): the gravity prior is on with each cloud's z axis up (a moved "
                             "source's up turns with it); regor-noprior runs without it")
    parser.add_argument("--mismatched", action="store_true",
                        help="instead: register each source against targets of other places (one per "
                             "place and seed) and count the poses each method's gate accepts: all wrong")
    parser.add_argument("--maps", type=Path, metavar="DIR",
                        help="instead: scan-to-map relocalization on every sequence folder in DIR "
                             "(map.npy, queries.json, queries/<id>/), Regor and KISS-Matcher")
    parser.add_argument("--map-scaling", type=Path, metavar="SEQUENCE",
                        help="instead: tile the map of one sequence folder --tiles times and measure "
                             "preparation, registration time and peak memory against map size")
    parser.add_argument("--tiles", type=int, nargs="+", default=[1, 2, 4, 7],
                        help="copies of the map for --map-scaling (default 1 2 4 7)")
    parser.add_argument("--batch", type=Path, metavar="DIR",
                        help="instead: regor-batch's throughput on every within-sequence pair of query "
                             "scans of the maps folder DIR, serially and on --workers local workers")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                        help="local worker processes for --batch (default 1 2)")
    args = parser.parse_args(argv)
    if args.maps or args.map_scaling or args.batch:
        return _map_main(args, argv, parser)
    if not args.data:
        parser.error("give one or more folders of pairs, or --maps / --map-scaling")

    methods = _methods(args.methods, METHODS, parser)
    for folder in args.data:
        if not (folder / "pairs.json").is_file():
            parser.error(f"{folder} has no pairs.json")
    seeds = args.rotate or [None]
    pairs = [p for folder in args.data for p in load_pairs(folder, args.pairs)]
    if args.level:
        pairs = [dataclasses.replace(p, src_up=UP_Z, tgt_up=UP_Z) for p in pairs]
    try:  # overrides apply to the presets of the kinds present
        overrides = parse_overrides(args.set)
        presets = {kind: RegorConfig.preset(kind).replace(overrides) for kind in {p.kind for p in pairs}}
    except ConfigError as exc:
        parser.error(str(exc))
    runs = [(seed, pair) for seed in seeds
            for pair in (cross_place_pairs(pairs, seed) if args.mismatched else pairs)]
    rows: List[dict] = []
    start = time.perf_counter()
    total = len(runs)
    done = 0
    for seed, pair in runs:
        moved = pair.moved(seed)
        pair_rows = evaluate_pair(moved, methods, moved.configured(presets[pair.kind]), seed)
        rows += pair_rows
        done += 1
        verdict = " ".join(f"{r['method']}:{'ok' if r['success'] else 'FAIL'}"
                           f"{'/published' if r['accepted'] is True else ''}" for r in pair_rows)
        print(f"[{done}/{total} {time.perf_counter() - start:6.0f} s] seed {seed} {pair.name}: {verdict}",
              flush=True)

    summary = summarise(rows)
    command = _command(argv)
    header = (f"# regor_ros benchmark\n\n{datetime.date.today().isoformat()}, {machine()}.  \n"
              f"Command: `{command}`  \nData: {', '.join(f'`{d}`' for d in args.data)} ({len(pairs)} pairs"
              f"{'; cross-place: each source against one target of every other place per seed, and each target against one source, no true pose' if args.mismatched else ''}), rotation seeds: "
              f"{', '.join(map(str, seeds))}. Success: RE < 15° and TE < 30 cm (indoor, object), "
              "RE < 5° and TE < 60 cm (outdoor). RE/TE are means over successes; time is per pair "
              "with FPFH included (registration alone in brackets); `published correct / WRONG`: poses that "
              "passed the method's own quality gate (published), correct and wrong." + LEVEL_NOTE * args.level)
    report = markdown(summary, rows, methods, header)
    stem = "mismatched" if args.mismatched else "benchmark"
    write_results(args.out, stem, report, rows, CSV_FIELDS, lambda _, path: plots(summary, methods, path))
    print(report)
    print(f"wrote {args.out / stem}.md, .csv and .png")
    return 0


def write_results(out: Path, stem: str, report: str, rows: List[dict], fields: List[str], plot) -> None:
    """<stem>.md, .csv and .png in ``out``; ``plot(rows, path)`` draws the picture."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(report)
    with open(out / f"{stem}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    plot(rows, out / f"{stem}.png")


def _command(argv) -> str:
    """The command line as run, for the report's header."""
    return "regor-bench " + " ".join(sys.argv[1:] if argv is None else argv)


def _methods(requested: Optional[str], available, parser) -> List[str]:
    """The methods named by --methods (all available ones when not given); an unknown or
    unsupported name is an error, not silently dropped."""
    if requested is None:
        return list(available)
    methods = [m.strip() for m in requested.split(",") if m.strip()]
    unknown = [m for m in methods if m not in available]
    if unknown or not methods:
        parser.error(f"unknown or unsupported method {(unknown or [requested])[0]!r} here; choose from "
                     f"{', '.join(available)}")
    return methods


def _map_main(args, argv, parser) -> int:
    """--maps, --map-scaling and --batch: the outdoor preset (every map here is LiDAR) with --set overrides."""
    from .map_benchmark import LEVEL_MOUNTED, MAP_METHODS, TILE_SPACING, run_maps, run_scaling
    try:
        overrides = {**(LEVEL_MOUNTED if args.level else {}), **parse_overrides(args.set)}
        config = RegorConfig.preset("outdoor").replace(overrides)
    except ConfigError as exc:
        raise SystemExit(f"regor-bench: {exc}")
    header = (f"# regor_ros scan-to-map benchmark\n\n{datetime.date.today().isoformat()}, {machine()}.  \n"
              f"Command: `{_command(argv)}`  \nOutdoor preset; success: RE < 5 deg and TE < 60 cm against "
              "the sequence's SLAM pose. Regor prepares the map once (its time is the preparation "
              "column) and registers each query against it; KISS-Matcher is given the scan and the map "
              "on every call. Peak memory is the resident peak of the process that ran the method.")
    if args.batch:
        from .batch_benchmark import run_batch_scaling
        report = run_batch_scaling(args.batch, args.workers, config, overrides, args.out, (
            f"# regor_ros batch benchmark\n\n{datetime.date.today().isoformat()}, {machine()}.  \n"
            f"Command: `{_command(argv)}`  \nEvery pair of query scans within each sequence of "
            f"`{args.batch}` (loop-closure candidates: each scan is in several pairs), outdoor preset; "
            "success: RE < 5 deg and TE < 60 cm against the sequences' SLAM poses. Serial: register() "
            "pair by pair in one process. regor-batch: a new local cluster per run (its start counted), "
            "worker processes started with this process's environment; identical: the same pose (every bit) and verdict "
            "as the serial run."))
    elif args.maps:
        report = run_maps(args.maps, _methods(args.methods, MAP_METHODS, parser), config, args.out,
                          header + LEVEL_NOTE * args.level, args.pairs)
    else:
        report = run_scaling(args.map_scaling, args.tiles, config, args.out, header.replace(
            "scan-to-map benchmark", "map scaling benchmark") + " The map is tiled: identical copies "
            f"{TILE_SPACING:.0f} m apart, each turned about the vertical; a pose counts as correct against any copy.")
    print(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
