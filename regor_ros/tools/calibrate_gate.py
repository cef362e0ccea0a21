"""regor-calibrate-gate: choose the quality gate's fitted thresholds so that they hold on new places.

Reads the per-registration CSVs that ``regor-bench`` writes (pairs with ground truth, and the
``--mismatched`` cross-place runs, where every pose is wrong), with the gate's figures recorded
whatever the verdict. Three thresholds are fitted for each kind (preset), since each kind is a
different sensor (fused RGB-D fragments, LiDAR scans): ``acceptance.max_free_space_violation``,
``acceptance.max_ambiguity`` and ``acceptance.min_feature_inliers``. The structural checks
(min_inliers, min_fitness, six constrained degrees of freedom) and the opposite-sides check
(``acceptance.max_opposite_sides``, a majority rule) are not fitted.

The rule: no wrong pose published, then as many correct ones as possible; among equally good
choices the thresholds in the middle of the tied ones (the widest margin on both sides). Leave one place (scene or sensor family) out:
fit on every registration that does not involve it, report on those that do. The last line fits
on everything: the values the presets use.
"""
from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional

import numpy as np

from ..core import RegorConfig
from ..core.verification import Rival, ambiguity
from .benchmark import place, same_place

VIOLATION_GRID = np.round(np.arange(0.02, 0.51, 0.01), 2)
FEATURE_GRID = np.arange(0, 151, 5)
AMBIGUITY_GRID = [0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0, 10.0]  # 10: off


@dataclass
class Sample:
    kind: str
    places: tuple            # the source's place, and the target's for a cross-place run
    correct: bool            # the pose is right (never for a cross-place run)
    structural: bool         # passes the checks that are not fitted
    feature_inliers: int
    violation: Optional[float]  # worst free-space figure; None when no viewpoint is known
    opposite: Optional[float] = None  # matched surface seen from opposite sides
    rivals: tuple = ()          # Rival fields of the symmetric rivals

    @property
    def max_opposite(self) -> float:
        return RegorConfig.preset(self.kind).acceptance.max_opposite_sides

    def ambiguity(self, max_violation: float) -> Optional[float]:
        return ambiguity([Rival(*r) for r in self.rivals], max_violation, self.max_opposite)


def _rivals(text: str) -> tuple:
    """'ratio:feature ratio:violation:opposite:deg;...' as written by regor-bench."""
    return tuple((float(a), float(b), _number(c), _number(d), float(e)) for a, b, c, d, e in
                 (item.split(":") for item in text.split(";") if item))


def _number(text: str) -> Optional[float]:
    return float(text) if text not in ("", "None", "nan") else None


def load_samples(paths: List[Path], method: str) -> List[Sample]:
    samples = []
    for path in paths:
        for row in csv.DictReader(open(path)):
            if row["method"] != method or row["error"]:
                continue
            kind = row["kind"]
            gate = RegorConfig.preset(kind).acceptance
            names = row["pair"].split(" -> ")
            sides = [v for v in (_number(row["free_space_source"]), _number(row["free_space_target"]))
                     if v is not None]
            samples.append(Sample(
                kind, tuple(place(n) for n in names), row["success"] == "True",
                int(row["num_inliers"]) >= gate.min_inliers and float(row["fitness"]) >= gate.min_fitness
                and "six degrees" not in row["reason"],
                int(row["feature_inliers"]), max(sides) if sides else None,
                _number(row["opposite_sides"]), _rivals(row["rivals"])))
    return samples


def published(samples: List[Sample], violation: float, min_features: int, max_ambiguity: float) -> np.ndarray:
    """Which samples a gate with these thresholds publishes."""
    shown = []
    for s in samples:
        ambiguous = s.ambiguity(violation)
        shown.append(s.structural and s.feature_inliers >= min_features
                     and (s.violation is None or s.violation <= violation)
                     and (s.opposite is None or s.opposite <= s.max_opposite)
                     and (ambiguous is None or ambiguous < max_ambiguity))
    return np.array(shown, dtype=bool)


def score(samples: List[Sample], violation: float, min_features: int, max_ambiguity: float):
    """(correct registrations, published correct, published wrong, registrations)."""
    shown = published(samples, violation, min_features, max_ambiguity)
    return (sum(s.correct for s in samples), int(sum(p and s.correct for p, s in zip(shown, samples))),
            int(sum(p and not s.correct for p, s in zip(shown, samples))), len(samples))


def preset_thresholds(kind: str):
    gate = RegorConfig.preset(kind).acceptance
    return gate.max_free_space_violation, gate.min_feature_inliers, gate.max_ambiguity


def fit(samples: List[Sample], kind: str):
    """(max_free_space_violation, min_feature_inliers, max_ambiguity) for samples of one kind, by
    the module's rule; the preset's own values when no sample is wrong (nothing to fit on)."""
    if all(s.correct for s in samples):
        return preset_thresholds(kind)
    best_count, candidates = -1, []
    for v in VIOLATION_GRID:
        for a in AMBIGUITY_GRID:
            safe = [int(f) for f in FEATURE_GRID if score(samples, v, int(f), a)[2] == 0]
            if not safe:
                continue
            count = score(samples, v, safe[0], a)[1]   # the lowest safe feature threshold publishes most
            if count > best_count:
                best_count, candidates = count, []
            if count == best_count:
                candidates.append((v, safe[0], a))
    if not candidates:   # nothing is safe: publish nothing
        return float(VIOLATION_GRID[0]), int(FEATURE_GRID[-1]), AMBIGUITY_GRID[0]
    tied_v = sorted({c[0] for c in candidates})
    middle = tied_v[len(tied_v) // 2]
    at_middle = sorted((c for c in candidates if c[0] == middle), key=lambda c: c[2])
    return at_middle[len(at_middle) // 2]


def families(samples: List[Sample]) -> List[str]:
    """Places, with places that may be one (a prefix of another) merged."""
    out: List[str] = []
    for name in sorted({p for s in samples for p in s.places}, key=lambda p: (len(p), p)):
        if not any(same_place(name, f) for f in out):
            out.append(name)
    return out


def _row(name: str, thresholds, figures) -> str:
    v, f, a = thresholds
    return (f"| {name} | {v:.2f} | {f} | {'off' if a > 1 else f'{a:.2f}'} | "
            + " | ".join(map(str, (figures[3], figures[0], figures[1], figures[2]))) + " |")


def report(samples: List[Sample]) -> str:
    lines = []
    for kind in sorted({s.kind for s in samples}):
        group = [s for s in samples if s.kind == kind]
        lines += [f"### {kind}", "", "| held out | max_free_space_violation | min_feature_inliers | "
                  "max_ambiguity | held-out runs | correct | published correct | published WRONG |",
                  "|---|---|---|---|---|---|---|---|"]
        totals = np.zeros(4, dtype=int)
        for family in families(group):
            held = [s for s in group if any(same_place(p, family) for p in s.places)]
            rest = [s for s in group if not any(same_place(p, family) for p in s.places)]
            thresholds = fit(rest, kind)
            figures = score(held, *thresholds)
            totals += figures
            lines.append(_row(family, thresholds, figures))
        lines.append(f"| **sum over held-out places** | | | | {totals[3]} | {totals[0]} | {totals[1]} | {totals[2]} |")
        thresholds = fit(group, kind)
        lines += [_row("**fitted on all of it (preset)**", thresholds, score(group, *thresholds)), ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-calibrate-gate", description=__doc__.split("\n\n")[0])
    parser.add_argument("csv", type=Path, nargs="+", help="benchmark.csv / mismatched.csv files of regor-bench")
    parser.add_argument("--method", default="regor", help="the Regor variant whose figures are used")
    parser.add_argument("--out", type=Path, help="also write the report here (markdown)")
    args = parser.parse_args(argv)
    samples = load_samples(args.csv, args.method)
    if not samples:
        parser.error(f"no rows of method {args.method!r} in {', '.join(map(str, args.csv))}")
    text = ("# Quality gate calibration, leave one place out\n\n" + __doc__.split("\n\n", 1)[1] + "\n"
            + f"Data: {', '.join(f'`{p}`' for p in args.csv)}.\n\n" + report(samples))
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
