"""What every benchmark shares: the gate's columns in the per-registration CSVs (which
regor-calibrate-gate reads), place naming, the results files, and the report header's facts.

Each benchmark (pairs_benchmark, map_benchmark, batch_benchmark) builds on this module alone;
regor-bench (benchmark.py) only dispatches to them.
"""
from __future__ import annotations

import csv
import datetime
import os
import platform
import sys
from pathlib import Path

STAGES = ("matching", "initial", "regeneration", "estimation", "verification")  # of Regor's timings
EVIDENCE_COLUMNS = ["surface_agreement", "independent_agreeing", "log10_false_alarms", "candidate_margin"]
LEVEL_NOTE = (" Gravity prior (--level): every cloud's z axis is up (level-mounted sensors on ground "
              "vehicles); `-noprior` methods run without it.")

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


def selected(name: str, name_filter: str | None) -> bool:
    """Whether ``name`` contains one of the comma-separated ``name_filter`` strings (all names
    are selected without a filter): --pairs."""
    return not name_filter or any(part in name for part in name_filter.split(","))


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


def header(title: str, argv) -> str:
    """A report's first lines: the title, the date, the machine and the command as run."""
    return (f"# {title}\n\n{datetime.date.today().isoformat()}, {machine()}.  \n"
            f"Command: `{command(argv)}`  \n")


def write_results(out: Path, stem: str, report: str, rows: list[dict], fields: list[str], plot) -> None:
    """<stem>.md, .csv and .png in ``out``; ``plot(rows, path)`` draws the picture."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.md").write_text(report)
    with open(out / f"{stem}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    plot(rows, out / f"{stem}.png")


def command(argv) -> str:
    """The command line as run, for the report's header."""
    return "regor-bench " + " ".join(sys.argv[1:] if argv is None else argv)


