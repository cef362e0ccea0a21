"""The pairs benchmark (``regor-bench FOLDER...``, and ``--mismatched``): every method on real pairs.

A folder holds ``pairs.json`` (name and kind of every pair) and ``<name>/src.npy``,
``tgt.npy``, ``gt.txt`` (T_target_source). Each pair is registered by every method on the same
downsampled clouds and FPFH features (preset chosen by kind); ``--rotate SEED`` first moves every
source by a random rigid motion (truth adjusted). Writes a markdown table, a per-pair CSV and
plots. ``--mismatched`` registers each source against targets of other places instead: every
pose published there is wrong.
"""
from __future__ import annotations

import dataclasses
import sys
import time
import traceback
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..core import (
    INLIER_THRESHOLDS,
    ConfigError,
    RegorConfig,
    correct_mask,
    for_clouds_seen_from,
    is_success,
    match_features,
    prepare_cloud,
    rotation_error_deg,
    translation_error,
)
from ..tools.register_cli import parse_overrides
from .datasets import UP_Z, Pair, load_pairs
from .peers import DESCRIPTIONS, METHODS
from .results import (
    GATE_COLUMNS,
    LEVEL_NOTE,
    STAGES,
    UNSEEN_NOTE,
    gate_columns,
    header,
    place,
    same_place,
    write_results,
)

CROSS_PLACE_NOTE = ("; cross-place: each source against one target of every other place per seed, and each target "
                    "against one source, no true pose")
CSV_FIELDS = ["seed", "pair", "kind", "method", "success", "accepted", "rotation_error_deg",
              "translation_error_m", "seconds_registration", "seconds_total",
              *(f"seconds_{stage}" for stage in STAGES), "inliers_final",
              "final_count", "inliers_initial", "initial_count", *GATE_COLUMNS, "error"]


def evaluate_pair(pair: Pair, methods, config: RegorConfig, seed) -> list[dict]:
    """Every method on one pair; a crash counts as a failure with its error recorded."""
    name, kind, src, tgt, T_gt = pair.name, pair.kind, pair.src, pair.tgt, pair.T_gt
    t0 = time.perf_counter()
    config = for_clouds_seen_from(config, pair.src_viewpoint, pair.tgt_viewpoint)
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
        if out.summary is not None:
            row.update(gate_columns(out.summary))
        if out.final is not None and T_gt is not None:
            final_source, final_target = out.final
            row["inliers_final"] = int(correct_mask(final_source, final_target, T_gt, threshold).sum())
            row["final_count"] = len(out.final[0])
        rows.append(row)
    return rows


def cross_place_pairs(pairs: list[Pair], seed: int | None) -> list[Pair]:
    """Each distinct source against one target of every other place of its kind, and each
    distinct target, as the source, against one source of every other place (a different one for
    each motion seed, round robin). There is no true pose, so any accepted pose is wrong. Both
    directions, because a wrong pose can pass the gate one way round and not the other."""
    swapped = [p.swapped() for p in pairs]
    return _crossed(pairs, seed, "", "") + _crossed(swapped, seed, " (target)", " (source)")


def _crossed(pairs: list[Pair], seed: int | None, source_role: str, target_role: str) -> list[Pair]:
    """Each distinct source cloud against one target cloud of every other place; the role labels
    name which cloud of each pair was used when it is not the usual one."""
    sources: dict = {}
    targets: defaultdict = defaultdict(dict)
    for p in pairs:
        sources.setdefault(p.src.tobytes().__hash__(), p)
        targets[(p.kind, place(p.name))].setdefault(p.tgt.tobytes().__hash__(), p)
    crossed = []
    for a in sources.values():
        for (kind, where), group in sorted(targets.items()):
            if kind != a.kind or same_place(where, place(a.name)):
                continue
            choices = list(group.values())
            b = choices[((seed or 0) + a.index) % len(choices)]
            crossed.append(dataclasses.replace(
                a, name=f"{a.name}{source_role} -> {b.name}{target_role}", tgt=b.tgt, T_gt=None,
                tgt_viewpoint=b.tgt_viewpoint, tgt_up=b.tgt_up))
    return crossed


def _mean(values) -> float:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else float("nan")


def summarise(rows: list[dict]) -> dict:
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


def markdown(summary: dict, rows: list[dict], methods: list[str], header: str, per_pair: bool = True) -> str:
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
    if per_pair:   # (cross-place pairs have no true pose to succeed at: their rows are in the CSV)
        lines += ["Per pair (successes over seeds):", "",
                  "| pair | kind | " + " | ".join(methods) + " |", "|" + "---|" * (len(methods) + 2)]
        by_pair: dict = defaultdict(lambda: defaultdict(list))
        kind_of = {}
        for r in rows:
            by_pair[r["pair"]][r["method"]].append(r["success"])
            kind_of[r["pair"]] = r["kind"]
        for pair, by_method in by_pair.items():
            cells = [f"{sum(by_method[m])}/{len(by_method[m])}" for m in methods]
            lines.append(f"| {pair} | {kind_of[pair]} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["Methods:", ""] + [f"- `{m}`: {DESCRIPTIONS[m]}" for m in methods]
    return "\n".join(lines) + "\n"


def plots(summary: dict, methods: list[str], out: Path) -> None:
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


def run_pairs(args, argv, methods: list[str], parser) -> int:
    """The pairs (or cross-place) benchmark of regor-bench's arguments; prints and writes the report."""
    for folder in args.data:
        if not (folder / "pairs.json").is_file():
            parser.error(f"{folder} has no pairs.json")
    seeds = args.rotate or [None]
    pairs = [p for folder in args.data for p in load_pairs(folder, args.pairs)]
    if args.level:
        pairs = [dataclasses.replace(p, src_up=UP_Z, tgt_up=UP_Z) for p in pairs]
    if args.no_viewpoints:
        pairs = [p.unseen() for p in pairs]
    try:  # overrides apply to the presets of the kinds present
        overrides = parse_overrides(args.set)
        presets = {kind: RegorConfig.preset(kind).replace(overrides) for kind in {p.kind for p in pairs}}
    except ConfigError as exc:
        parser.error(str(exc))
    runs = [(seed, pair) for seed in seeds
            for pair in (cross_place_pairs(pairs, seed) if args.mismatched else pairs)]
    rows: list[dict] = []
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
    title = (header("regor_ros benchmark", argv) + f"Data: {', '.join(f'`{d}`' for d in args.data)} ({len(pairs)} pairs"
              f"{CROSS_PLACE_NOTE if args.mismatched else ''}), rotation seeds: "
              f"{', '.join(map(str, seeds))}. Success: RE < 15° and TE < 30 cm (indoor, object), "
              "RE < 5° and TE < 60 cm (outdoor). RE/TE are means over successes; time is per pair "
              "with FPFH included (registration alone in brackets); `published correct / WRONG`: poses that "
              "passed the method's own quality gate (published), correct and wrong." + LEVEL_NOTE * args.level
              + UNSEEN_NOTE * args.no_viewpoints)
    report = markdown(summary, rows, methods, title, per_pair=not args.mismatched)
    stem = "mismatched" if args.mismatched else "benchmark"
    write_results(args.out, stem, report, rows, CSV_FIELDS, lambda _, path: plots(summary, methods, path))
    print(report)
    print(f"wrote {args.out / stem}.md, .csv and .png")
    return 0


