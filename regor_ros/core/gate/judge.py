"""The one judge of a pose: every check, in order, each with its reason.

The pipeline measures a pose's figures (gate/measure.py) and calls ``judge``; regor-calibrate-gate
rebuilds the figures from the benchmark's CSVs and calls ``passes`` with the thresholds it tries, so
the calibration cannot drift from the gate. Each check's test is written on numpy arrays: figures
(one entry per pose) and thresholds (an array of values to try) broadcast against each other.
The checks, in the order a reason names the first that fails:
- measurable: enough inliers that fix all six degrees of freedom, enough fitness, and inside the
  gravity prior (a tipped-over pose is no candidate whatever else it shows);
- beyond chance (not fitted): the overlap on the target's surfaces, and either the feature matches
  (evidence.py) or the surfaces themselves (surface_evidence.py) more than chance gives;
- right rather than wrong (thresholds calibrated on held-out places): enough agreeing feature
  matches (more when free space was not checked from both sides; none when the matches single the
  pose out among every other answer measured), free space (each side, and both at once), opposite
  sides;
- unique (not fitted): no rival (a symmetric twin, another place the search found) that the
  evidence cannot tell from the pose (rivals.py);
- pinned (a unit, not fitted): at least one independent neighbourhood of surface faces every
  direction, or the pose can slide along repeated structure (slide.py);
- inside the hint's search region, and given back by the reverse registration (when run).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..places import another_answer
from .figures import Figures

REVERSE_MAX_DEG = 10.0  # the reverse registration agrees when within these
REVERSE_MAX_TAU = 3.0   # (translation in units of initial.inlier_threshold)


def _per_pose(value):
    """A pose's figure or threshold against its rivals: broadcast over the rivals' last axis."""
    return np.expand_dims(value, -1)


def rival_chances(f: Figures, a):
    """Each rival's lead chance (gate/rivals.py), NaN for one that is no contender: not another
    answer (places.another_answer: it leaves the source where the pose put it), failing a
    visibility check, or short of what a pose must have to be judged at all (min_inliers,
    min_fitness, min_feature_inliers; the rival's counts are the pose's scaled by its ratios). A
    turn that keeps a tenth of the overlap is no second pose, however few matches the pose has.
    Over the last axis (the rivals)."""
    r = f.rivals
    with np.errstate(invalid="ignore"):
        counts = (another_answer(r.moved_tau, r.distance_deg)
                  & ~(r.violation > _per_pose(a.max_free_space_violation))
                  & ~(r.opposite_sides > _per_pose(a.max_opposite_sides))
                  & (r.inlier_ratio * _per_pose(f.num_inliers) >= _per_pose(a.min_inliers))
                  & (r.inlier_ratio * _per_pose(f.fitness) >= _per_pose(a.min_fitness))
                  & (r.feature_ratio * _per_pose(f.feature_inliers) >= _per_pose(a.min_feature_inliers)))
    return np.where(counts, r.lead_chance, np.nan)


def ambiguity(f: Figures, a):
    """How well the evidence tells the pose from its rivals: the largest of the contenders' lead
    chances (NaN when there is none)."""
    return np.fmax.reduce(rival_chances(f, a), axis=-1, initial=np.nan)


def _beyond_chance(log10_false_alarms, a):
    return log10_false_alarms <= np.log10(a.max_false_alarms)


def _chance_reason(f: Figures, a) -> str:
    surfaces = ("" if np.isnan(f.surface_log10_false_alarms) else
                f", and {f.surface_cells_agreeing:.0f} of {f.surface_cells:.0f} independent cells on the target's "
                f"surfaces (wrong poses refined there: up to {100 * f.surface_chance:.0f} %) in about "
                f"10^{f.surface_log10_false_alarms:.1f}")
    return (f"chance alone gives {f.independent_agreeing:.0f} independent agreeing feature matches in about "
            f"10^{f.log10_false_alarms:.1f} of the poses this search tried{surfaces} "
            f"(acceptance.max_false_alarms={a.max_false_alarms}): too little support for a target this size")


def carried_by(f: Figures, a) -> str:
    """Which test against chance a pose passes: its feature matches, else its surfaces."""
    if _beyond_chance(f.log10_false_alarms, a):
        return "feature matches"
    return "surfaces" if _beyond_chance(f.surface_log10_false_alarms, a) else ""


def singled_out(f: Figures, a):
    """Whether the feature matches single the pose out: it leads every rival that is another
    answer (its symmetric twins and the search's other places, each refined, whatever their
    free space) beyond what a tie gives (lead chance at most acceptance.max_ambiguity). The
    count min_feature_inliers stands in for lookalikes nobody measured (the same room turned, the
    next bay of a shelf); where every lookalike the pair offers was measured and lost, the count
    has nothing left to stop. False without such a rival."""
    r = f.rivals
    with np.errstate(invalid="ignore"):
        other = another_answer(r.moved_tau, r.distance_deg)
        lost = r.lead_chance <= _per_pose(a.max_ambiguity)
    return np.any(other, axis=-1) & np.all(~other | lost, axis=-1)


def _needed_features(f: Figures, a):
    """The feature count a pose needs: 0 where free space was checked from both sides and either
    its surfaces carried it against chance (a sparse scan has a few matches even when right, and
    the count was fitted for the feature test's poses) or its features single it out among every
    other answer measured (singled_out); where free space was not checked both ways, the features
    must still stand on their own."""
    waived = _beyond_chance(f.surface_log10_false_alarms, a) | singled_out(f, a)
    return np.where(f.both_sides, np.where(waived, 0, a.min_feature_inliers), a.min_feature_inliers_partial)


def _features_reason(f: Figures, a) -> str:
    if f.both_sides:
        name, needed, why = "min_feature_inliers", a.min_feature_inliers, ""
    else:  # visibility cannot catch what it would have: features must stand on their own
        name, needed, why = ("min_feature_inliers_partial", a.min_feature_inliers_partial,
                             ": free space was not checked from both sides, a viewpoint is unknown "
                             "or too little of one cloud is in the other's view")
    return f"only {f.feature_inliers:.0f} feature matches agree with the pose (acceptance.{name}={needed}{why})"


@dataclass(frozen=True)
class Check:
    """One check of the gate: its name (Verdict.failed), its test and its reason."""

    name: str
    fails: Callable   # (figures, acceptance) -> bool, or a bool array where either holds arrays
    reason: Callable  # (figures, acceptance) -> str, for one pose


# NaN compares False: a figure not measured fails no check
CHECKS = (
    Check("min_inliers", lambda f, a: f.num_inliers < a.min_inliers,
          lambda f, a: f"only {f.num_inliers:.0f} inliers (acceptance.min_inliers={a.min_inliers})"),
    Check("constrained", lambda f, a: ~np.asarray(f.constrained, dtype=bool),
          lambda f, a: "the inliers do not constrain all six degrees of freedom (plane or line?)"),
    Check("min_fitness", lambda f, a: f.fitness < a.min_fitness,
          lambda f, a: f"fitness {f.fitness:.3f} below acceptance.min_fitness={a.min_fitness}"),
    Check("gravity_tilt", lambda f, a: ~np.asarray(f.tilt_inside, dtype=bool),
          lambda f, a: (f"the pose tilts the source's up by {f.tilt_deg:.1f} deg from the target's "
                        f"(gravity.max_tilt={f.tilt_allowed_deg:g}): tipped over")),
    Check("gravity_height", lambda f, a: ~np.asarray(f.height_inside, dtype=bool),
          lambda f, a: (f"the pose puts the source's sensor {f.height_offset:+.2f} m from the height the "
                        f"target was seen from, {f.height_distance:.1f} m away (allowed {f.height_allowed:.2f} m: "
                        "gravity.height_tolerance plus gravity.max_slope over that distance)")),
    Check("min_surface_agreement", lambda f, a: f.surface_agreement < a.min_surface_agreement,
          lambda f, a: (f"only {100 * f.surface_agreement:.0f} % of the overlap lies on the target's surfaces "
                        f"at the keypoint spacing (acceptance.min_surface_agreement={a.min_surface_agreement}): "
                        "the clouds touch, they do not coincide")),
    Check("max_false_alarms", lambda f, a: (~_beyond_chance(f.log10_false_alarms, a)
                                             & ~_beyond_chance(f.surface_log10_false_alarms, a)), _chance_reason),
    Check("min_feature_inliers", lambda f, a: f.feature_inliers < _needed_features(f, a), _features_reason),
    Check("max_free_space_violation", lambda f, a: f.worst_free_space > a.max_free_space_violation,
          lambda f, a: (f"{100 * f.worst_free_space:.0f} % of one cloud lies in space the other sensor saw "
                        f"through (acceptance.max_free_space_violation={a.max_free_space_violation}): "
                        "surfaces pass through each other, the pose is wrong")),
    Check("max_free_space_both_sides", lambda f, a: f.both_sides_free_space > a.max_free_space_both_sides,
          lambda f, a: (f"both sensors saw through the other cloud's surfaces ({100 * f.free_space_source:.1f} % "
                        f"and {100 * f.free_space_target:.1f} % of the keypoints, "
                        f"acceptance.max_free_space_both_sides={a.max_free_space_both_sides}): a correct pose's "
                        "conflicts are one sensor's artefacts, surfaces that pass through each other show from "
                        "both sides; the pose is wrong")),
    Check("max_opposite_sides", lambda f, a: f.opposite_sides > a.max_opposite_sides,
          lambda f, a: (f"{100 * f.opposite_sides:.0f} % of the shared surface was seen from opposite sides "
                        f"(acceptance.max_opposite_sides={a.max_opposite_sides}): the clouds are back to back, "
                        "the pose is wrong")),
    Check("max_ambiguity", lambda f, a: ambiguity(f, a) > a.max_ambiguity,
          lambda f, a: (f"ambiguous: two poses fit. Another pose (the pose turned about the scene's symmetry: "
                        "a box room's quarter turn, a corridor's half turn; or another place the search found: "
                        "the next bay of a shelf) passes the visibility checks too, and a tie would give this "
                        f"pose its lead in the independent feature matches only one of the two explains with "
                        f"probability {ambiguity(f, a):.2f} (acceptance.max_ambiguity={a.max_ambiguity}); "
                        "the rival is among the candidates")),
    Check("min_weakest_support", lambda f, a: f.weakest_support < a.min_weakest_support,
          lambda f, a: (f"ambiguous: only {f.weakest_support:.2f} independent neighbourhoods of surface face the "
                        f"direction the overlap pins least (acceptance.min_weakest_support={a.min_weakest_support}): "
                        "slid along it past a repeated structure (a bookshelf's bays, a row of doors) the pose "
                        "fits as well")),
    Check("search_region", lambda f, a: f.region_offset > f.region_radius,
          lambda f, a: (f"the pose puts the source {f.region_offset:.1f} m from the hinted position, outside "
                        f"its {f.region_radius:.1f} m search region")),
    Check("reverse_check",
          lambda f, a: (f.reverse_turn_deg >= REVERSE_MAX_DEG) | (f.reverse_offset_tau >= REVERSE_MAX_TAU),
          lambda f, a: (f"registering target to source gives another pose ({f.reverse_turn_deg:.0f} deg, "
                        f"{f.reverse_offset_tau:.1f} inlier thresholds away): a different place or an ambiguous "
                        "scene (acceptance.reverse_check)")),
)
MEASURABLE = CHECKS[:5]  # the checks before which a pose's rivals are not worth refining
FREE_SPACE_CHECKS = tuple(check for check in CHECKS if check.name.startswith("max_free_space"))
PASSED = len(CHECKS)


def first_failure(figures: Figures, acceptance, checks=CHECKS):
    """The index in ``checks`` of the first check each pose fails; len(checks) where it passes all."""
    first = len(checks)
    with np.errstate(invalid="ignore"):
        for index in reversed(range(len(checks))):
            first = np.where(checks[index].fails(figures, acceptance), index, first)
    return first


def passes(figures: Figures, acceptance, checks=CHECKS):
    """Whether each pose passes every one of ``checks`` (bool, or an array where figures or
    thresholds are arrays)."""
    return first_failure(figures, acceptance, checks) == len(checks)


@dataclass(frozen=True)
class Verdict:
    """The gate's ruling on one pose."""

    accepted: bool
    reason: str            # why it was not accepted; empty when accepted
    failed: str = ""       # the name of the check that failed (Check.name); empty when accepted
    ambiguity: float | None = None  # judge.ambiguity: the largest lead chance of a rival that counts
    carried_by: str = ""   # the test against chance that carried an accepted pose: "feature matches" or "surfaces"
    singled_out: bool = False  # its feature matches beat every other answer measured (min_feature_inliers waived)


def judge(figures: Figures, acceptance) -> Verdict:
    """The verdict on one pose, naming the first check it fails."""
    index = int(first_failure(figures, acceptance))
    level = float(ambiguity(figures, acceptance))
    shown = None if np.isnan(level) else level
    alone = bool(singled_out(figures, acceptance))
    if index == PASSED:
        return Verdict(True, "", "", shown, carried_by(figures, acceptance), alone)
    check = CHECKS[index]
    return Verdict(False, check.reason(figures, acceptance), check.name, shown, singled_out=alone)
