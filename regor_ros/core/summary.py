"""A verdict and every figure behind it, each figure under one name: what the node's status and
diagnostics, the command lines' JSON and the benchmarks' CSV columns read, by attribute.

The gate's figures keep the names gate/figures.py gives them (the CSV columns'); the JSON holds
each once (``as_json``). doc/node.md maps the keys of the JSON before this object to these.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .gate.evidence import Evidence
from .gate.figures import Figures
from .gate.judge import Verdict
from .gate.visibility import VisibilityFigures

# what VisibilityFigures holds beside the gate's figures: how much each side saw
SEEN = ("source_seen", "target_seen", "map_seen", "shake_bins", "map_changed")


@dataclass(frozen=True)
class Summary:
    """register()'s or verify()'s verdict with its figures. ``figures.num_inliers`` and the rest are
    floats, NaN when not measured; the JSON writes those as null."""

    accepted: bool
    reason: str                  # why it was not accepted; empty when accepted
    failed_check: str            # the check that failed (judge.CHECKS); empty when accepted
    carried_by: str              # the test against chance that carried an accepted pose
    singled_out: bool            # its feature matches beat every other answer measured
    ambiguity: float | None      # the largest chance a tie gives the pose its lead over a rival
    figures: Figures             # everything the gate judged, one name each
    visibility: VisibilityFigures  # how much each sensor saw (SEEN), beside the free-space figures
    timings: dict[str, float]    # seconds per stage
    inlier_rmse: float | None = None      # register(): RMS residual of the inliers [m]
    source_keypoints: int | None = None
    target_keypoints: int | None = None
    selected: str | None = None           # which pose the estimator kept
    stage_sizes: dict[str, int] = field(default_factory=dict)  # correspondences after each stage
    attempts: int = 1                     # registrations run: 1 + the acceptance.retries used
    evidence: Evidence | None = None      # the pose's support against chance
    candidates: list[int] = field(default_factory=list)  # FS-TCD support of the pose, then of other places
    candidate_margin: float | None = None  # the pose's support over the best other place's
    correction_m: float | None = None      # verify(): how far the refinement moved the given pose [m]
    correction_deg: float | None = None    # and turned it [deg]
    within_tolerance: bool | None = None   # verify(): the correction within verification.max_correction(_deg)

    @classmethod
    def judged(cls, verdict: Verdict, figures: Figures, visibility: VisibilityFigures, timings: dict[str, float],
               **extra) -> Summary:
        """The summary of one pose the gate judged; ``extra``: the fields of register() or verify()."""
        return cls(verdict.accepted, verdict.reason, verdict.failed, verdict.carried_by, verdict.singled_out,
                   verdict.ambiguity, figures, visibility, dict(timings), **extra)

    def as_json(self) -> dict:
        """Plain values for JSON: every figure once, under ``figures`` (the rivals as a list), what
        each side saw under ``visibility``; None for what was not measured."""
        figures = {name: _plain(value) for name, value in self.figures.columns().items() if name != "rivals"}
        figures.update(worst_free_space=_plain(self.figures.worst_free_space),
                       both_sides=bool(self.figures.both_sides), rivals=self.figures.rivals.rows())
        out = {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)
               if f.name not in ("figures", "visibility", "evidence")}
        out.update(figures=figures, visibility={name: getattr(self.visibility, name) for name in SEEN},
                   evidence=None if self.evidence is None else _plain(dataclasses.asdict(self.evidence)))
        return out


def _plain(value):
    """A JSON value: numpy scalars as Python's, NaN as None."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if np.isnan(value) else float(value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value
