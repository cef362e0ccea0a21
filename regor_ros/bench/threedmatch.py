"""The 3DMatch / 3DLoMatch benchmark (``regor-bench --threedmatch DIR``): the paper's own test lists.

``DIR`` holds ``pairs.json`` (a list of ``{bench, scene, i, j, T}``: ``T`` maps fragment ``j``, the
source, into fragment ``i``, the target) and ``<scene>/<k>.npy``, each fragment in its camera
frame (viewpoint at the origin). Every pair is registered by every method as in the pairs
benchmark (indoor preset, FPFH included in the time), with no added motion: the benchmark's
fragments are registered as they are. Reported per list: registration recall with the paper's
thresholds (RE < 15 deg, TE < 30 cm), the poses each method's own gate published, correct and
wrong, and the gross wrong ones among them (> 20 deg or > 0.6 m: a pose a robot cannot use at all,
not a near miss of the 3DMatch truth, which is itself loose by a few degrees), and median time.
``--sample N`` runs a fixed, seeded sample of N pairs (the same pairs for the same N). Every
registration is seeded with 0, or with N under ``--set seed=N`` (the CSV's seed column says which):
the same lists under other seeds show how far a figure moves by chance alone.
"""
from __future__ import annotations

import time
from collections import defaultdict

import numpy as np

from ..core import GROSS_THRESHOLDS, ConfigError, RegorConfig, is_gross
from ..tools.register_cli import parse_overrides
from .datasets import Fragments, as_pair, load_list
from .pairs import CSV_FIELDS, evaluate_pair
from .peers import DESCRIPTIONS
from .results import UNSEEN_NOTE, header, place, write_results

LISTS = ("3DMatch", "3DLoMatch")
THREEDMATCH_FIELDS = ["bench", *CSV_FIELDS]


def entry_rows(entry: dict, fragments: Fragments, methods: list[str], config: RegorConfig,
               unseen: bool = False, seed: int | None = None) -> list[dict]:
    """Every method's row for one listed pair, each with its list (``bench``); ``unseen``: with
    neither viewpoint given (--no-viewpoints); ``seed``: the registrations' (None: 0)."""
    pair = as_pair(entry, fragments)
    if unseen:
        pair = pair.unseen()
    return [{**row, "bench": entry["bench"]} for row in evaluate_pair(pair, methods, config, seed)]


def gross(row: dict) -> bool:
    """A wrong pose far from the truth (not a near miss of a loose ground truth)."""
    return is_gross(row.get("rotation_error_deg", np.nan), row.get("translation_error_m", np.nan), "indoor")


def summarise(rows: list[dict]) -> dict:
    """Per (method, list) and (method, list, scene): RR, published correct / wrong / gross, times."""
    groups = defaultdict(list)
    for r in rows:
        groups[(r["method"], r["bench"], "all")].append(r)
        groups[(r["method"], r["bench"], place(r["pair"]).removeprefix("3dmatch_"))].append(r)
    summary = {}
    for key, rs in groups.items():
        timed = [r["seconds_total"] for r in rs if "seconds_total" in r]
        published = [r for r in rs if r["accepted"] is True]
        wrong = [r for r in published if not r["success"]]
        correct = sum(r["success"] for r in rs)
        verdicts = rs[0]["accepted"] != ""  # the method has a verdict of its own
        summary[key] = {
            "pairs": len(rs), "correct": correct, "recall": correct / len(rs),
            "published_correct": len(published) - len(wrong) if verdicts else None,
            "published_wrong": len(wrong) if verdicts else None,
            "gross_wrong": sum(gross(r) for r in wrong) if verdicts else None,
            "median_s": float(np.median(timed)) if timed else float("nan"),
        }
    return summary


def _cell(value) -> str:
    return "–" if value is None else str(value)


def markdown(summary: dict, rows: list[dict], methods: list[str], title: str) -> str:
    lines = [title, "", "| list | method | RR | correct / pairs | published correct (of correct) | "
             "published WRONG (gross) | median s |", "|" + "---|" * 7]
    for bench in LISTS:
        for method in methods:
            s = summary.get((method, bench, "all"))
            if s is None:
                continue
            share = "" if s["published_correct"] is None or not s["correct"] else \
                f" ({100 * s['published_correct'] / s['correct']:.0f} %)"
            wrong = "–" if s["published_wrong"] is None else f"{s['published_wrong']} ({s['gross_wrong']})"
            lines.append(f"| {bench} | {method} | {100 * s['recall']:.1f} % | {s['correct']} / {s['pairs']} | "
                         f"{_cell(s['published_correct'])}{share} | {wrong} | {s['median_s']:.2f} |")
    scenes = sorted({scene for _, _, scene in summary if scene != "all"})
    lines += ["", "Per scene: RR, published correct / WRONG (gross):", "",
              "| scene | list | " + " | ".join(methods) + " |", "|" + "---|" * (len(methods) + 2)]
    for scene in scenes:
        for bench in LISTS:
            cells = []
            for method in methods:
                s = summary.get((method, bench, scene))
                if s is None:
                    cells.append("–")
                    continue
                verdict = "" if s["published_wrong"] is None else \
                    f", {s['published_correct']} / {s['published_wrong']} ({s['gross_wrong']})"
                cells.append(f"{100 * s['recall']:.1f} % of {s['pairs']}{verdict}")
            if any(c != "–" for c in cells):
                lines.append(f"| {scene} | {bench} | " + " | ".join(cells) + " |")
    published_wrong = [r for r in rows if r["accepted"] is True and not r["success"]]
    if published_wrong:
        lines += ["", "Every wrong pose published:", "", "| pair | list | method | RE deg | TE m | feature inliers |",
                  "|" + "---|" * 6]
        for r in published_wrong:
            lines.append(f"| {r['pair']} | {r['bench']} | {r['method']} | {r['rotation_error_deg']:.1f} | "
                         f"{r['translation_error_m']:.2f} | {r.get('feature_inliers', '–')} |")
    lines += ["", "Methods:", ""] + [f"- `{m}`: {DESCRIPTIONS[m]}" for m in methods]
    return "\n".join(lines) + "\n"


def run_threedmatch(args, argv, methods: list[str], parser) -> int:
    """regor-bench --threedmatch: every selected pair by every method; prints and writes the report."""
    folder = args.threedmatch
    if not (folder / "pairs.json").is_file():
        parser.error(f"{folder} has no pairs.json (see --help for its format)")
    try:
        entries = load_list(folder, args.sample, args.pairs)
        overrides = parse_overrides(args.set)
        config = RegorConfig.preset("indoor").replace(overrides)
    except (ValueError, ConfigError) as exc:
        parser.error(str(exc))
    seed = config.seed if "seed" in overrides else None
    fragments = Fragments(folder)
    rows: list[dict] = []
    start = time.perf_counter()
    for done, entry in enumerate(entries, start=1):
        try:
            pair_rows = entry_rows(entry, fragments, methods, config, args.no_viewpoints, seed)
        except FileNotFoundError as exc:
            parser.error(str(exc))
        rows += pair_rows
        verdict = " ".join(f"{r['method']}:{'ok' if r['success'] else 'FAIL'}"
                           f"{'/published' if r['accepted'] is True else ''}" for r in pair_rows)
        print(f"[{done}/{len(entries)} {time.perf_counter() - start:6.0f} s] {entry['bench']} {entry['name']}: "
              f"{verdict}", flush=True)
    summary = summarise(rows)
    drawn = f"a fixed sample of {len(entries)} pairs" if args.sample else f"{len(entries)} pairs"
    title = (header("regor_ros on the 3DMatch / 3DLoMatch test lists", argv) + f"Data: `{folder}`, {drawn}. "
             f"Indoor preset (with --set overrides), registrations seeded with {seed or 0}, fragments as the "
             "benchmark gives them (no added motion), "
             "FPFH included in the time. Success (RR): RE < 15 deg and TE < 30 cm. Published: the method's own "
             f"gate passed the pose; gross: a published wrong pose > {GROSS_THRESHOLDS['indoor'][0]:g} deg or "
             f"> {GROSS_THRESHOLDS['indoor'][1]:g} m off." + UNSEEN_NOTE * args.no_viewpoints)
    report = markdown(summary, rows, methods, title)
    write_results(args.out, "threedmatch", report, rows, THREEDMATCH_FIELDS, lambda *_: None)
    print(report)
    print(f"wrote {args.out / 'threedmatch'}.md and .csv")
    return 0
