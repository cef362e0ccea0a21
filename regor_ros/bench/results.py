"""What every benchmark shares: the gate's columns in the per-registration CSVs (which
regor-calibrate-gate reads), place naming, the results files, and the report header's facts.

Each benchmark (pairs_benchmark, map_benchmark, batch_benchmark) builds on this module alone;
regor-bench (benchmark.py) only dispatches to them.
"""
from __future__ import annotations

import csv
import dataclasses
import datetime
import gzip
import os
import platform
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import Figures

if TYPE_CHECKING:
    from ..core import Summary

FIGURE_COLUMNS = [f.name for f in dataclasses.fields(Figures)]
STAGES = ("matching", "initial", "regeneration", "estimation", "verification")  # of Regor's timings
# the gate's columns: its verdict, every figure it judged (core/gate/figures.py, which
# regor-calibrate-gate reads back), and figures reported beside them
GATE_COLUMNS = ["reason", "failed_check", "carried_by", *FIGURE_COLUMNS, "map_seen", "ambiguity", "candidate_margin",
                "attempts"]
LEVEL_NOTE = (" Gravity prior (--level): every cloud's z axis is up (level-mounted sensors on ground "
              "vehicles); `-noprior` methods run without it.")
UNSEEN_NOTE = (" Viewpoints dropped (--no-viewpoints): neither sensor position is given, so free space is not "
               "checked and the normals keep the solver's signs.")


def gate_columns(summary: Summary) -> dict:
    """The verdict, the gate's figures, the stage timings and the registrations run (1 + the
    acceptance.retries used) of a registration, as CSV columns (what regor-calibrate-gate reads)."""
    return {**{f"seconds_{stage}": summary.timings[stage] for stage in STAGES},
            "reason": summary.reason, "failed_check": summary.failed_check, "carried_by": summary.carried_by,
            **summary.figures.columns(), "map_seen": summary.visibility.map_seen, "ambiguity": summary.ambiguity,
            "candidate_margin": summary.candidate_margin, "attempts": summary.attempts}


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


def open_run(path: Path):
    """A run's CSV opened for reading as text, as regor-bench wrote it (.csv) or as results/ keeps
    it (.csv.gz)."""
    path = Path(path)
    if path.suffix == ".gz":
        return gzip.open(path, "rt", newline="", encoding="utf-8")
    return open(path, newline="", encoding="utf-8")


def run_files(folder: Path) -> list[Path]:
    """The run CSVs below ``folder``, compressed or not, in name order."""
    return sorted([*folder.rglob("*.csv"), *folder.rglob("*.csv.gz")])


def same_run(path: Path, folder: Path) -> Path:
    """The run in ``folder`` with ``path``'s name (the other of .csv and .csv.gz when only it is there)."""
    name = path.name[:-3] if path.suffix == ".gz" else path.name
    plain = folder / name
    return plain if plain.exists() or not (folder / f"{name}.gz").exists() else folder / f"{name}.gz"


def command(argv) -> str:
    """The command line as run, for the report's header."""
    return "regor-bench " + " ".join(sys.argv[1:] if argv is None else argv)


