"""What the gate judges a pose on: every figure, measured whatever the verdict.

One pose's figures are numbers; ``stack`` turns many poses' into arrays with one entry per pose,
so that regor-calibrate-gate judges thousands of recorded registrations at once with the same
judge the pipeline calls. NaN is "not measured": a viewpoint unknown, no gravity prior, no hint,
the reverse registration not run. A figure not measured is no evidence either way, and the check
that reads it passes (the checks that need it are made stricter elsewhere: min_feature_inliers_partial).
This module is light (numpy only): the calibration reads CSVs with it before any kernel is loaded.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

NOT_MEASURED = float("nan")


@dataclass
class RivalFigures:
    """The pose's rivals, refined (gate/rivals.py): its symmetric twins, then the other places the
    search found. One entry per rival along the last axis (NaN-padded when poses with fewer rivals
    are stacked)."""

    inlier_ratio: np.ndarray    # its inliers / the pose's
    feature_ratio: np.ndarray   # its agreeing feature matches / the pose's
    worst_free_space: np.ndarray  # its worse free-space figure (Figures.worst_free_space)
    opposite_sides: np.ndarray  # its matched surface seen from opposite sides
    distance_deg: np.ndarray    # its rotation from the pose after refinement
    lead_chance: np.ndarray     # chance that a tie gives the pose its lead in independent agreeing matches
    moved_tau: np.ndarray       # how far it moves the source from the pose's place (RMS), in initial.inlier_threshold
    log10_false_alarms: np.ndarray  # its own agreeing matches against chance (measured with its free space)

    @classmethod
    def of(cls, rows) -> RivalFigures:
        """From (inlier ratio, feature ratio, worst free space, opposite sides, distance, lead chance,
        moved, false alarms) rows, None for a figure not measured (and for a row's missing last figures: a CSV from
        before they were recorded)."""
        width = len(dataclasses.fields(cls))
        table = np.array([[NOT_MEASURED if v is None else float(v) for v in row] + [NOT_MEASURED] * (width - len(row))
                          for row in rows], dtype=float).reshape(-1, width)
        return cls(*table.T)

    def rows(self) -> list[dict]:
        """One dict per rival (None for a figure not measured): for summaries and CSVs."""
        names = [f.name for f in dataclasses.fields(self)]
        columns = [np.asarray(getattr(self, name)) for name in names]
        return [{name: (None if np.isnan(value) else float(value)) for name, value in zip(names, row, strict=True)}
                for row in zip(*columns, strict=True)]


def _no_rivals() -> RivalFigures:
    return RivalFigures.of([])


@dataclass
class Figures:
    """Everything gate/judge.py reads, with the names of the benchmark CSVs' columns."""

    num_inliers: float             # source keypoints within tau_e of the target after refinement
    fitness: float                 # num_inliers / source keypoints
    surface_agreement: float       # gate/evidence.py
    log10_false_alarms: float      # gate/evidence.py: the feature matches' test against chance
    independent_agreeing: float    # gate/evidence.py
    feature_inliers: float         # initial feature matches within initial.inlier_threshold of the pose
    # the inliers fix all six degrees of freedom (always measured; a CSV from before it was a column
    # reads as True: the calibration's committed runs have no pose that failed it)
    constrained: bool = True
    free_space_source: float = NOT_MEASURED  # target keypoints inside the source sensor's seen free space
    free_space_target: float = NOT_MEASURED  # source keypoints inside the target sensor's (or map's)
    opposite_sides: float = NOT_MEASURED     # matched surface the two sensors saw from opposite sides
    weakest_support: float = NOT_MEASURED    # gate/slide.py: neighbourhoods facing the least pinned direction
    rivals: RivalFigures = field(default_factory=_no_rivals)
    # gate/surface_evidence.py: the surfaces' test against chance, measured when the features' fails
    surface_log10_false_alarms: float = NOT_MEASURED
    surface_cells: float = NOT_MEASURED
    surface_cells_agreeing: float = NOT_MEASURED
    surface_chance: float = NOT_MEASURED      # the best decoy's fraction of cells on the surfaces
    tilt_deg: float = NOT_MEASURED           # the source's up turned by the pose, from the target's up
    tilt_allowed_deg: float = NOT_MEASURED   # gravity.max_tilt
    tilt_inside: bool = True                 # the gravity prior's own predicate (True: no prior)
    height_offset: float = NOT_MEASURED      # the source's sensor above the target's nearest viewpoint
    height_allowed: float = NOT_MEASURED
    height_distance: float = NOT_MEASURED    # horizontally from that viewpoint
    height_inside: bool = True
    region_offset: float = NOT_MEASURED      # the source's origin from the hinted position, horizontally
    region_radius: float = NOT_MEASURED      # the hint's search region
    reverse_turn_deg: float = NOT_MEASURED   # the reverse registration, inverted, from the pose
    reverse_offset_tau: float = NOT_MEASURED  # (its translation in units of initial.inlier_threshold)

    @property
    def both_sides(self):
        """Each cloud was checked against the other sensor's free space."""
        return ~np.isnan(self.free_space_source) & ~np.isnan(self.free_space_target)

    @property
    def worst_free_space(self):
        """The larger free-space fraction (NaN when neither side was measured)."""
        return np.fmax(self.free_space_source, self.free_space_target)

    @property
    def both_sides_free_space(self):
        """The smaller free-space fraction: what both sensors saw through (NaN unless both sides
        were measured)."""
        return np.minimum(self.free_space_source, self.free_space_target)

    def columns(self) -> dict:
        """Each figure as a CSV column (None: not measured); the rivals as regor-bench writes them."""
        out = {}
        for f in dataclasses.fields(self):
            if f.name != "rivals":
                value = getattr(self, f.name)
                out[f.name] = None if isinstance(value, float) and np.isnan(value) else value
        out["rivals"] = ";".join(f"{r['inlier_ratio']:.3f}:{r['feature_ratio']:.3f}:{r['worst_free_space']}:"
                                 f"{r['opposite_sides']}:{r['distance_deg']:.1f}:{r['lead_chance']}:{r['moved_tau']:.1f}:"
                                 f"{r['log10_false_alarms']}"
                                 for r in self.rivals.rows())
        return out

    @classmethod
    def from_columns(cls, row: dict) -> Figures:
        """The figures a regor-bench CSV row recorded (columns() written out); a column the CSV does
        not have keeps its default ("not measured"). ValueError names a required one missing."""
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            text = row.get(f.name)
            if text is None:
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                    raise ValueError(f"no column {f.name!r} (written before the gate recorded it: rerun regor-bench)")
                continue
            if f.name == "rivals":
                values[f.name] = RivalFigures.of([[_number(v) for v in item.split(":")]
                                                  for item in text.split(";") if item])
            elif f.type == "bool":
                values[f.name] = text == "True"
            else:
                values[f.name] = _number(text)
        return cls(**values)


def _number(text: str) -> float:
    return float(text) if text not in ("", "None", "nan") else NOT_MEASURED


def stack(figures: list[Figures]) -> Figures:
    """Many poses' figures as one Figures of arrays (one entry per pose; rivals padded with NaN)."""
    most = max((len(np.atleast_1d(f.rivals.distance_deg)) for f in figures), default=0)

    def padded(values) -> np.ndarray:
        values = np.atleast_1d(np.asarray(values, dtype=float))
        return np.concatenate([values, np.full(most - len(values), NOT_MEASURED)])

    columns: dict[str, Any] = {}
    for f in dataclasses.fields(Figures):
        if f.name == "rivals":
            columns[f.name] = RivalFigures(*(np.array([padded(getattr(one.rivals, r.name)) for one in figures])
                                             .reshape(len(figures), most)
                                             for r in dataclasses.fields(RivalFigures)))
        else:
            columns[f.name] = np.array([getattr(one, f.name) for one in figures],
                                       dtype=bool if f.type == "bool" else float)
    return Figures(**columns)
