"""regor-calibrate-gate: choose the quality gate's fitted thresholds so that they hold on new places.

Reads the per-registration CSVs that ``regor-bench`` writes (pairs with ground truth, and the
``--mismatched`` cross-place runs, where every pose is wrong), with the gate's figures recorded
whatever the verdict. Four thresholds are fitted for each kind (preset), since each kind is a
different sensor (fused RGB-D fragments, LiDAR scans): ``acceptance.max_free_space_violation``
and ``acceptance.min_feature_inliers`` on the runs whose free space was checked from both sides,
then ``acceptance.max_free_space_both_sides`` on the same runs with those two fixed (fitted
after them, so that they never relax on what it stops: it only withholds more), then
``acceptance.min_feature_inliers_partial`` for a pose whose free space was not (a viewpoint
unknown, as for a map): on the runs that had no full check, and on every run again with its
viewpoints dropped, the target's or both (the run's figures without those sides; its rivals keep
their recorded figures, which only makes the fit stricter). Each run is judged by the gate's own
judge (core/gate/judge.py) on the figures its CSV row recorded, so the calibration cannot drift
from the gate. The checks not fitted keep the preset's values: the structural ones (min_inliers,
min_fitness, six constrained degrees of freedom, the gravity prior), those against chance
(``acceptance.min_surface_agreement``, a majority rule, and ``acceptance.max_false_alarms``, the
a-contrario bound of 1), the opposite-sides check (``acceptance.max_opposite_sides``, a majority
rule) and the rivals' test (``acceptance.max_ambiguity``, a significance level).

The rule: no gross wrong pose published (metrics.is_gross: beyond 20 degrees or 0.6 m indoors; every
cross-place pose), then as many correct ones as possible; among equally good choices the strictest
(the lowest free-space thresholds, the highest feature counts): every tied choice publishes the
same correct poses where it was fitted, and a wrong pose published costs more than a correct one
withheld, so the room left is left to the wrong side that the fit did not see. A near miss (wrong
by the benchmark's thresholds, within the gross ones: 5-10 degrees, 0.3-0.5 m off a ground truth
that is itself loose by a few degrees) is a pose a local refinement brings in; its figures are a
correct pose's, so a fit that must stop it too stops the correct poses with it. It is neither
counted for a setting nor against it, and every table reports how many are published. Then each
threshold is taken at its strictest among that fit and the fits with each training place left out
in turn (``stable_fit``): a relaxation whose gain rests on
one place's runs is not taken, since the next place may put wrong poses in the room it opens (a
threshold whose fitted value flips between folds is a weak check, and the strict side is the safe
one). Leave one
place (scene or sensor family) out: fit on every registration that does not involve it, report on
those that do: the headline, first, with each wrong pose it let through. The last two lines of each
table: the fit on everything (an in-sample figure), and the preset's own values as shipped
(chosen with this report in hand, not by it). The headline is
repeated for a fit that cannot lean on two thresholds at once: the feature counts alone stop
every wrong pose the unfitted checks let through (``fit_alone``), and for the single fit without
the places left out inside it (``fit``), with how far each threshold moves between folds under
each rule. A second table
reports the held-out runs again with the target's viewpoint dropped (a scan against a map) and
with both dropped (map against map).
"""
from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core import Figures, RegorConfig, passes, stack
from .results import open_run, place, same_place

VIOLATION_GRID = np.round(np.arange(0.02, 0.51, 0.01), 2)
BOTH_SIDES_GRID = np.append(np.round(np.arange(0.005, 0.051, 0.005), 3), 1.0)   # 1: off
BOTH_SIDES_AXIS = BOTH_SIDES_GRID[:, None]
FEATURE_GRID = np.arange(0, 151, 5)
FEATURE_AXIS = FEATURE_GRID[:, None]  # every feature threshold at once, on an axis before the runs'


@dataclass
class Sample:
    kind: str
    places: tuple            # the source's place, and the target's for a cross-place run
    correct: bool            # the pose is right (never for a cross-place run)
    figures: Figures         # what the gate judged it on, as regor-bench recorded it
    run: str = ""            # which registration: seed, pair, file
    error: tuple = (np.nan, np.nan)  # (rotation deg, translation m) from the truth; NaN: none (cross-place)

    @property
    def gross(self) -> bool:
        """A wrong pose of no use (metrics.is_gross), not a near miss."""
        from ..core import is_gross  # here: --help answers without scipy.spatial (test_startup)
        turn, shift = self.error
        return not self.correct and is_gross(turn, shift, self.kind)

    @property
    def near_miss(self) -> bool:
        return not self.correct and not self.gross

    @property
    def feature_inliers(self) -> int:
        return int(self.figures.feature_inliers)

    @property
    def worst_free_space(self) -> float | None:
        worst = float(self.figures.worst_free_space)
        return None if np.isnan(worst) else worst

    @property
    def free_space(self) -> tuple:
        """(source, target) free-space figures; None for a side not checked."""
        return tuple(None if np.isnan(v) else float(v)
                     for v in (self.figures.free_space_source, self.figures.free_space_target))

    @property
    def both_sides(self) -> bool:
        return bool(self.figures.both_sides)

    @property
    def passes_unfitted(self) -> bool:
        """Passes every check that is not fitted (the fitted ones at their most lenient)."""
        lenient = replace(RegorConfig.preset(self.kind).acceptance, **LENIENT)  # type: ignore[arg-type]
        return bool(passes(self.figures, lenient))

    def involves(self, family: str) -> bool:
        """The run registers a cloud of that place (either cloud, for a cross-place run)."""
        return any(same_place(p, family) for p in self.places)

    def blinded(self, keep_source: bool) -> Sample:
        """This run as if the target's viewpoint (and the source's too, unless ``keep_source``)
        were unknown: those free-space figures and the opposite-sides figure (it needs both) are
        gone; with none left the rivals lose theirs as well."""
        unknown = float("nan")
        figures = replace(self.figures, free_space_target=unknown, opposite_sides=unknown)
        if not keep_source:
            rivals = self.figures.rivals
            blind = np.full_like(rivals.worst_free_space, unknown)
            figures = replace(figures, free_space_source=unknown,
                              rivals=replace(rivals, worst_free_space=blind, opposite_sides=blind))
        return replace(self, figures=figures)


def load_samples(paths: list[Path], method: str) -> list[Sample]:
    """The runs of ``method`` the CSVs recorded with their gate figures (a run that raised is left
    out). ValueError when a CSV lacks a figure the gate judges (written by an older regor-bench)."""
    samples = []
    for path in paths:
        try:
            with open_run(path) as f:
                rows = list(csv.DictReader(f))
        except (OSError, EOFError, UnicodeDecodeError, csv.Error) as exc:
            raise ValueError(f"{path}: cannot be read as a CSV ({exc})") from None
        missing = {"method", "error", "pair", "kind", "success"} - set(rows[0] if rows else ())
        if missing:
            raise ValueError(f"{path}: not a regor-bench CSV (no column {', '.join(sorted(missing))})")
        for row in rows:
            if row["method"] != method or row["error"]:
                continue
            try:
                figures = Figures.from_columns(row)
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
            names = row["pair"].split(" -> ")
            samples.append(Sample(
                row["kind"], tuple(place(n) for n in names), row["success"] == "True", figures,
                f"{'seed ' + row['seed'] + ' ' if row.get('seed') else ''}{row['pair']} "
                f"({path.parent.name}/{path.name})",
                (float(row.get("rotation_error_deg") or "nan"), float(row.get("translation_error_m") or "nan"))))
    return samples


Thresholds = tuple[float, int, int, float]  # violation, min features, min features (partial), both sides
THRESHOLD_NAMES = ("max_free_space_violation", "min_feature_inliers", "min_feature_inliers_partial",
                   "max_free_space_both_sides")
# the fitted thresholds where they stop nothing: what the checks that are not fitted publish alone
LENIENT = dict(zip(THRESHOLD_NAMES, (1.0, 0, 0, 1.0), strict=True))


class Runs:
    """Samples of one kind as one Figures of arrays, so that the judge rules on all of them at once
    (the fit tries ~18,000 settings per fold), for many values of a threshold at a time."""

    def __init__(self, samples: list[Sample]):
        kinds = {s.kind for s in samples}
        if len(kinds) > 1:
            raise ValueError(f"runs of one kind are judged together, not {sorted(kinds)}")
        self.samples = samples
        self.acceptance = RegorConfig.preset(kinds.pop() if kinds else "indoor").acceptance
        self.figures = stack([s.figures for s in samples])
        self.correct = np.array([s.correct for s in samples], dtype=bool)
        self.gross = np.array([s.gross for s in samples], dtype=bool)
        self.near_miss = ~self.correct & ~self.gross

    def published(self, thresholds) -> np.ndarray:
        """Which runs (last axis) a gate with these thresholds publishes; a threshold may be an
        array of values shaped to broadcast before the runs' axis."""
        return passes(self.figures, replace(self.acceptance, **dict(zip(THRESHOLD_NAMES, thresholds, strict=True))))

    def counts(self, thresholds):
        """(published correct, published gross wrong), per threshold setting when they are arrays."""
        shown = self.published(thresholds)
        return (shown & self.correct).sum(axis=-1), (shown & self.gross).sum(axis=-1)

    def score(self, thresholds: Thresholds):
        """(correct registrations, published correct, published gross wrong, registrations,
        published near misses)."""
        shown = self.published(thresholds)
        return (int(self.correct.sum()), int((shown & self.correct).sum()), int((shown & self.gross).sum()),
                len(self.samples), int((shown & self.near_miss).sum()))


def score(samples: list[Sample], thresholds: Thresholds):
    """(correct registrations, published correct, published gross wrong, registrations, published
    near misses)."""
    if not samples:
        return 0, 0, 0, 0, 0
    return Runs(samples).score(thresholds)


def preset_thresholds(kind: str) -> Thresholds:
    acceptance = RegorConfig.preset(kind).acceptance
    return (acceptance.max_free_space_violation, acceptance.min_feature_inliers,
            acceptance.min_feature_inliers_partial, acceptance.max_free_space_both_sides)


def checked_runs(samples: list[Sample]) -> tuple[list[Sample], list[Sample]]:
    """(the runs checked from both sides: the full thresholds' fit; the runs the partial feature
    threshold judges: those not checked from both sides, and every full run again with the
    target's viewpoint dropped and with both dropped)."""
    full = [s for s in samples if s.both_sides]
    partial = ([s for s in samples if not s.both_sides]
               + [s.blinded(keep_source) for s in full for keep_source in (True, False)])
    return full, partial


def fit(samples: list[Sample], kind: str) -> Thresholds:
    """The thresholds for samples of one kind, by the module's rule: the two of a full check on
    the runs checked from both sides, then the both-sides bound on those runs, then the partial
    feature threshold on the others and on every run with its viewpoints dropped."""
    full, partial = checked_runs(samples)
    violation, min_features = _fit_full(full, kind)
    both = _fit_both_sides(full, kind, violation, min_features)
    if not any(s.gross for s in partial):
        return violation, min_features, max(min_features, preset_thresholds(kind)[2]), both
    right, wrong = Runs(partial).counts((violation, min_features, FEATURE_AXIS, both))
    safe = (FEATURE_GRID >= min_features) & (wrong == 0)
    if not safe.any():
        return violation, min_features, int(FEATURE_GRID[-1]), both
    return violation, min_features, strictest_features(safe, right), both


def strictest_features(safe: np.ndarray, right: np.ndarray) -> int:
    """The highest of the safe feature thresholds (``safe``: which of FEATURE_GRID publish no
    wrong pose) that still publishes as many correct runs (``right``, per threshold) as the lowest."""
    most = right[np.argmax(safe)]
    return int(FEATURE_GRID[safe & (right == most)].max())


def stable_fit(samples: list[Sample], kind: str, fitter=fit) -> Thresholds:
    """Each threshold at its strictest among ``fitter``'s fits on all ``samples`` and on the
    samples with each of their places left out in turn: a threshold is relaxed only as far as the
    fit still goes with any one place left out, so a gain that rests on one place's runs (a fit's
    edge next to wrong poses no training place happened to produce) is not taken. The leave-one-place-out
    inside the fit that the report runs around it. A place whose runs hold every wrong pose leaves
    nothing to fit on without it, and no vote."""
    rests = [[s for s in samples if not s.involves(family)] for family in families(samples)]
    fits = [fitter(samples, kind)] + [fitter(rest, kind) for rest in rests if any(s.gross for s in rest)]
    violation, min_features, min_partial, both = zip(*fits, strict=True)
    return min(violation), max(min_features), max(min_partial), min(both)


def fit_alone(samples: list[Sample], kind: str) -> Thresholds:
    """The feature thresholds fitted so that each alone stops every wrong pose the unfitted checks
    let through (no help from free space, which keeps the preset's value): a fit that cannot
    lean on a second fitted threshold. Reported beside the joint fit."""
    violation, _, _, both = preset_thresholds(kind)

    def above(runs: list[Sample]) -> int:
        wrong = [s.feature_inliers for s in runs if s.gross and s.passes_unfitted]
        return int(next((f for f in FEATURE_GRID if f > max(wrong, default=-1)), FEATURE_GRID[-1]))

    full, partial = checked_runs(samples)
    min_features = above(full)
    return violation, min_features, max(min_features, above(partial)), both


def _fit_full(samples: list[Sample], kind: str):
    """(max_free_space_violation, min_feature_inliers) for runs checked from both sides, the
    both-sides bound off; the preset's own values when no sample is wrong (nothing to fit on)."""
    if not any(s.gross for s in samples):
        return preset_thresholds(kind)[:2]
    runs, best_count, best = Runs(samples), -1, None
    off = LENIENT["max_free_space_both_sides"]
    for v in VIOLATION_GRID:          # ascending: the first of tied settings is the strictest
        right, wrong = runs.counts((v, FEATURE_AXIS, FEATURE_AXIS, off))
        safe = wrong == 0
        if not safe.any():
            continue
        count = right[np.argmax(safe)]   # the lowest safe feature threshold publishes most
        if count > best_count:
            best_count, best = count, (float(v), safe, right)
    if best is None:   # nothing is safe: publish nothing
        return float(VIOLATION_GRID[0]), int(FEATURE_GRID[-1])
    v, safe, right = best
    return v, strictest_features(safe, right)


def _fit_both_sides(samples: list[Sample], kind: str, violation: float, min_features: int) -> float:
    """max_free_space_both_sides for runs checked from both sides, the other two fixed: the
    strictest bound that publishes as many correct runs as the best safe one (the preset's own
    value when there is nothing to fit on)."""
    if not any(s.gross for s in samples):
        return preset_thresholds(kind)[3]
    right, wrong = Runs(samples).counts((violation, min_features, min_features, BOTH_SIDES_AXIS))
    safe = wrong == 0
    if not safe.any():
        return float(BOTH_SIDES_GRID[0])
    return float(BOTH_SIDES_GRID[safe & (right == right[safe].max())].min())


def families(samples: list[Sample]) -> list[str]:
    """Places, with places that may be one (a prefix of another) merged."""
    out: list[str] = []
    for name in sorted({p for s in samples for p in s.places}, key=lambda p: (len(p), p)):
        if not any(same_place(name, f) for f in out):
            out.append(name)
    return out


def _row(name: str, thresholds: Thresholds, figures) -> str:
    v, f, p, b = thresholds
    return (f"| {name} | {v:.2f} | {f} | {p} | {b:.3f} | "
            + " | ".join(map(str, (figures[3], figures[0], figures[1], figures[2], figures[4]))) + " |")


def _blind_row(name: str, thresholds: Thresholds, held: list[Sample]) -> str:
    """The held-out runs again without the target's viewpoint, and without either."""
    map_scan = score([s.blinded(True) for s in held], thresholds)
    map_map = score([s.blinded(False) for s in held], thresholds)
    return (f"| {name} | {thresholds[2]} | {map_scan[3]} | {map_scan[0]} | {map_scan[1]} / {map_scan[2]} "
            f"({map_scan[4]}) | {map_map[1]} / {map_map[2]} ({map_map[4]}) |")


def folds(samples: list[Sample], fitter=stable_fit) -> dict[str, list]:
    """Leave one place out, per kind: [(place, its runs, the thresholds fitted without them)]."""
    out: dict[str, list] = {}
    for kind in sorted({s.kind for s in samples}):
        group = [s for s in samples if s.kind == kind]
        out[kind] = []
        for family in families(group):
            held = [s for s in group if s.involves(family)]
            rest = [s for s in group if not s.involves(family)]
            out[kind].append((family, held, fitter(rest, kind)))
    return out


def in_sample(samples: list[Sample], fitter=stable_fit) -> dict[str, Thresholds]:
    """Per kind, the thresholds ``fitter`` gives on all of its runs."""
    return {kind: fitter([s for s in samples if s.kind == kind], kind) for kind in sorted({s.kind for s in samples})}


def headline(samples: list[Sample], folded: dict[str, list], inside: dict[str, Thresholds]) -> str:
    """Per kind: what the gate publishes on places it was not fitted on (``folded``: folds()),
    against the in-sample fit (``inside``: in_sample() with the same fitter)."""
    lines = ["| kind | held-out runs | correct | published correct, held out | published gross WRONG, held out | "
             "published gross WRONG, in-sample | published near misses, held out |", "|---|---|---|---|---|---|---|"]
    for kind, kind_folds in folded.items():
        group = [s for s in samples if s.kind == kind]
        held = sum((np.array(score(runs, thresholds)) for _, runs, thresholds in kind_folds), np.zeros(5, dtype=int))
        wrong_inside = score(group, inside[kind])[2]
        lines.append(f"| {kind} | {held[3]} | {held[0]} | {held[1]} | **{held[2]}** | {wrong_inside} | {held[4]} |")
    return "\n".join(lines)


def unfitted_share(samples: list[Sample]) -> str:
    """Per kind: how many gross wrong poses the checks that are not fitted stop, and how many are
    left for the fitted thresholds to stop (the fewer, the less the gate rests on a fit)."""
    lines = ["| kind | gross wrong poses | stopped by unfitted checks | left to the fitted thresholds (most feature "
             "inliers among them) | correct poses passing the unfitted checks |", "|---|---|---|---|---|"]
    for kind in sorted({s.kind for s in samples}):
        wrong = [s for s in samples if s.kind == kind and s.gross]
        left = [s for s in wrong if s.passes_unfitted]
        correct = [s for s in samples if s.kind == kind and s.correct and s.passes_unfitted]
        most = max((s.feature_inliers for s in left), default=0)
        lines.append(f"| {kind} | {len(wrong)} | {len(wrong) - len(left)} | {len(left)} ({most}) | {len(correct)} |")
    return "\n".join(lines)


def wrong_held_out(folded: dict[str, list]) -> str:
    """Each wrong pose published with its place held out, gross or a near miss, and its figures:
    what a check missed."""
    lines = ["| kind | held out | run | off the truth | feature inliers | free space (source, target) |",
             "|---|---|---|---|---|---|"]
    for kind, kind_folds in folded.items():
        for family, held, thresholds in kind_folds:
            for s, shown in zip(held, Runs(held).published(thresholds), strict=True):
                if shown and not s.correct:
                    off = "no truth" if np.isnan(s.error[0]) else f"{s.error[0]:.1f} deg, {s.error[1]:.2f} m"
                    lines.append(f"| {kind} | {family} | {s.run} | {off}{' (**gross**)' if s.gross else ''} | "
                                 f"{s.feature_inliers} | "
                                 + ", ".join("-" if v is None else f"{v:.3f}" for v in s.free_space) + " |")
    return "\n".join(lines) if len(lines) > 2 else "None."


def fold_spread(single: dict[str, list], stable: dict[str, list]) -> str:
    """Per kind and threshold, the range of values the folds fitted, by each rule: a threshold
    whose fitted value moves with the place left out rests on that place (a weak check)."""
    def span(kind_folds, i) -> str:
        values = sorted({float(thresholds[i]) for _, _, thresholds in kind_folds})
        text = [f"{v:g}" for v in (values[0], values[-1])]
        return text[0] if len(values) == 1 else f"{text[0]}-{text[1]}"
    lines = ["| kind | threshold | single fit, over the folds | stable fit, over the folds |", "|---|---|---|---|"]
    for kind in single:
        for i, name in enumerate(THRESHOLD_NAMES):
            lines.append(f"| {kind} | {name} | {span(single[kind], i)} | {span(stable[kind], i)} |")
    return "\n".join(lines)


def report(samples: list[Sample]) -> str:
    folded, inside = folds(samples), in_sample(samples)
    alone = headline(samples, folds(samples, fit_alone), in_sample(samples, fit_alone))
    edge_folds = folds(samples, fit)
    edge = headline(samples, edge_folds, in_sample(samples, fit))
    lines = ["## Held out (the headline)", "", headline(samples, folded, inside), "",
             "Wrong poses published with their place held out:", "", wrong_held_out(folded), "",
             "What the fitted thresholds are left to do:", "", unfitted_share(samples), "",
             "The same, with the feature thresholds fitted to stop those alone (free space at the presets' "
             "value, not leaned on):", "", alone, "",
             "The same with the thresholds where one fit on all the training places puts them (``fit``, the "
             "rule before ``stable_fit``: up to the edge of the wrong poses those places produced):", "", edge, "",
             "Wrong poses that fit published with their place held out:", "", wrong_held_out(edge_folds), "",
             "How far each fitted threshold moves with the place left out:", "",
             fold_spread(edge_folds, folded), "",
             "## Per place", ""]
    for kind in sorted({s.kind for s in samples}):
        group = [s for s in samples if s.kind == kind]
        table = [f"### {kind}", "", f"| held out | {' | '.join(THRESHOLD_NAMES)} | held-out runs | correct | "
                 "published correct | published gross WRONG | published near misses |",
                 "|---|---|---|---|---|---|---|---|---|---|"]
        blind = ["", f"{kind}, the same held-out runs with viewpoints dropped (the partial threshold applies):", "",
                 "| held out | min_feature_inliers_partial | runs | correct | target's dropped (scan to map): "
                 "published correct / gross WRONG (near misses) | both dropped (map to map): published correct / "
                 "gross WRONG (near misses) |",
                 "|---|---|---|---|---|---|"]
        totals = np.zeros(5, dtype=int)
        blind_totals = np.zeros((2, 5), dtype=int)
        for family, held, thresholds in folded[kind]:
            figures = score(held, thresholds)
            totals += figures
            table.append(_row(family, thresholds, figures))
            blind.append(_blind_row(family, thresholds, held))
            blind_totals += [score([s.blinded(k) for s in held], thresholds) for k in (True, False)]
        table.append(f"| **sum over held-out places** | | | | | {totals[3]} | {totals[0]} | {totals[1]} | "
                     f"{totals[2]} | {totals[4]} |")
        blind.append(f"| **sum over held-out places** | | {blind_totals[0][3]} | {blind_totals[0][0]} | "
                     f"{blind_totals[0][1]} / {blind_totals[0][2]} ({blind_totals[0][4]}) | "
                     f"{blind_totals[1][1]} / {blind_totals[1][2]} ({blind_totals[1][4]}) |")
        for name, thresholds in (("**fitted on all of it**", inside[kind]),
                                 ("**the preset as shipped**", preset_thresholds(kind))):
            table.append(_row(name, thresholds, score(group, thresholds)))
            blind.append(_blind_row(name, thresholds, group))
        lines += table + blind + [""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-calibrate-gate", description=__doc__.split("\n\n")[0],
                                     epilog="example:\n  regor-calibrate-gate bench-out/benchmark.csv "
                                            "bench-out/mismatched.csv --out bench-out/gate_calibration.md",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("csv", type=Path, nargs="+", help="benchmark.csv / mismatched.csv files of regor-bench "
                                                          "(or .csv.gz, as results/ keeps them)")
    parser.add_argument("--method", default="regor", help="the Regor variant whose figures are used "
                                                          "(default: %(default)s)")
    parser.add_argument("--out", type=Path, help="also write the report here (markdown; default: print only)")
    args = parser.parse_args(argv)
    try:
        samples = load_samples(args.csv, args.method)
    except ValueError as exc:
        print(f"regor-calibrate-gate: {exc}", file=sys.stderr)
        return 2
    if not samples:
        print(f"regor-calibrate-gate: no rows of method {args.method!r} in {', '.join(map(str, args.csv))}",
              file=sys.stderr)
        return 2
    text = ("# Quality gate calibration, leave one place out\n\n" + __doc__.split("\n\n", 1)[1] + "\n"
            + f"Data: {', '.join(f'`{p}`' for p in args.csv)}.\n\n" + report(samples))
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
