"""The one judge of a pose: every check, in order, each with its reason.

The pipeline measures a pose's figures (gate/measure.py) and calls ``judge`` once, on the pose it
keeps; regor-calibrate-gate
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

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import AcceptanceConfig
from ..gravity import EDGE_HELD_DEG
from ..places import another_answer
from .figures import Figures

REVERSE_MAX_DEG = 10.0  # the reverse registration agrees when within these
REVERSE_MAX_TAU = 3.0   # (translation in units of initial.inlier_threshold)


def _per_pose(value):
    """A pose's figure or threshold against its rivals: broadcast over the rivals' last axis."""
    return np.expand_dims(value, -1)


def rival_chances(figures: Figures, acceptance: AcceptanceConfig):
    """Each rival's lead chance (gate/rivals.py), NaN for one that is no contender: not another
    answer (places.another_answer: it leaves the source where the pose put it), failing a
    visibility check, or short of what a pose must have to be judged at all (min_inliers,
    min_fitness, min_feature_inliers; the rival's counts are the pose's scaled by its ratios). A
    turn that keeps a tenth of the overlap is no second pose, however few matches the pose has.
    Over the last axis (the rivals)."""
    r, at_least = figures.rivals, acceptance
    with np.errstate(invalid="ignore"):
        counts = (another_answer(r.moved_tau, r.distance_deg)
                  & ~(r.worst_free_space > _per_pose(at_least.max_free_space_violation))
                  & ~(r.opposite_sides > _per_pose(at_least.max_opposite_sides))
                  & (r.inlier_ratio * _per_pose(figures.num_inliers) >= _per_pose(at_least.min_inliers))
                  & (r.inlier_ratio * _per_pose(figures.fitness) >= _per_pose(at_least.min_fitness))
                  & (r.feature_ratio * _per_pose(figures.feature_inliers) >= _per_pose(at_least.min_feature_inliers)))
    return np.where(counts, r.lead_chance, np.nan)


def ambiguity(figures: Figures, acceptance: AcceptanceConfig):
    """How well the evidence tells the pose from its rivals: the largest of the contenders' lead
    chances (NaN when there is none)."""
    return np.fmax.reduce(rival_chances(figures, acceptance), axis=-1, initial=np.nan)


def undecided(figures: Figures, acceptance: AcceptanceConfig):
    """Which rivals the evidence cannot tell from the pose (over the last axis): the poses a user
    should see beside it."""
    return rival_chances(figures, acceptance) > acceptance.max_ambiguity


def _beyond_chance(log10_false_alarms, acceptance: AcceptanceConfig):
    return log10_false_alarms <= np.log10(acceptance.max_false_alarms)


def _chance_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    surfaces = ("" if np.isnan(figures.surface_log10_false_alarms) else
                f", and {figures.surface_cells_agreeing:.0f} of {figures.surface_cells:.0f} independent cells "
                f"on the target's surfaces (wrong poses refined there: up to {100 * figures.surface_chance:.0f} %) "
                f"in about 10^{figures.surface_log10_false_alarms:.1f}")
    return (f"chance alone gives {figures.independent_agreeing:.0f} independent agreeing feature matches in about "
            f"10^{figures.log10_false_alarms:.1f} of the poses this search tried{surfaces} "
            f"(acceptance.max_false_alarms={acceptance.max_false_alarms}): too little support for a target this size")


def carried_by(figures: Figures, acceptance: AcceptanceConfig) -> str:
    """Which test against chance a pose passes: its feature matches, else its surfaces."""
    if _beyond_chance(figures.log10_false_alarms, acceptance):
        return "feature matches"
    return "surfaces" if _beyond_chance(figures.surface_log10_false_alarms, acceptance) else ""


def singled_out(figures: Figures, acceptance: AcceptanceConfig):
    """Whether the feature matches single the pose out: it leads every rival that is another
    answer (its symmetric twins and the search's other places, each refined, whatever their
    free space) beyond what a tie gives (lead chance at most acceptance.max_ambiguity). The
    count min_feature_inliers stands in for lookalikes nobody measured (the same room turned, the
    next bay of a shelf); where every lookalike the pair offers was measured and lost, the count
    has nothing left to stop. False without such a rival."""
    r = figures.rivals
    with np.errstate(invalid="ignore"):
        other = another_answer(r.moved_tau, r.distance_deg)
        lost = r.lead_chance <= _per_pose(acceptance.max_ambiguity)
    return np.any(other, axis=-1) & np.all(~other | lost, axis=-1)


def _needed_features(figures: Figures, acceptance: AcceptanceConfig):
    """The feature count a pose needs: 0 where free space was checked from both sides and either
    its surfaces carried it against chance (a sparse scan has a few matches even when right, and
    the count was fitted for the feature test's poses) or its features single it out among every
    other answer measured (singled_out); where free space was not checked both ways, the features
    must still stand on their own."""
    waived = _beyond_chance(figures.surface_log10_false_alarms, acceptance) | singled_out(figures, acceptance)
    full = np.where(waived, 0, acceptance.min_feature_inliers)
    return np.where(figures.both_sides, full, acceptance.min_feature_inliers_partial)


def _features_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    if figures.both_sides:
        name, needed, why = "min_feature_inliers", acceptance.min_feature_inliers, ""
    else:  # visibility cannot catch what it would have: features must stand on their own
        name, needed, why = ("min_feature_inliers_partial", acceptance.min_feature_inliers_partial,
                             ": free space was not checked from both sides, a viewpoint is unknown "
                             "or too little of one cloud is in the other's view")
    return f"only {figures.feature_inliers:.0f} feature matches agree with the pose (acceptance.{name}={needed}{why})"


def _free_space_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    return (f"{100 * figures.worst_free_space:.0f} % of one cloud lies in space the other sensor saw through "
            f"(acceptance.max_free_space_violation={acceptance.max_free_space_violation}): surfaces pass "
            "through each other, the pose is wrong")


def _both_sides_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    return (f"both sensors saw through the other cloud's surfaces ({100 * figures.free_space_source:.1f} % "
            f"and {100 * figures.free_space_target:.1f} % of the keypoints, "
            f"acceptance.max_free_space_both_sides={acceptance.max_free_space_both_sides}): a correct pose's "
            "conflicts are one sensor's artefacts, surfaces that pass through each other show from both sides; "
            "the pose is wrong")


def _ambiguity_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    return ("ambiguous: two poses fit. Another pose (the pose turned about the scene's symmetry: a box room's "
            "quarter turn, a corridor's half turn; or another place the search found: the next bay of a shelf) "
            "passes the visibility checks too, and a tie would give this pose its lead in the independent "
            f"feature matches only one of the two explains with probability {ambiguity(figures, acceptance):.2f} "
            f"(acceptance.max_ambiguity={acceptance.max_ambiguity}); the rival is among the candidates")


def _slide_reason(figures: Figures, acceptance: AcceptanceConfig) -> str:
    return (f"ambiguous: only {figures.weakest_support:.2f} independent neighbourhoods of surface face the "
            f"direction the overlap pins least (acceptance.min_weakest_support={acceptance.min_weakest_support}): "
            "slid along it past a repeated structure (a bookshelf's bays, a row of doors) the pose fits as well")


Test = Callable[[Figures, AcceptanceConfig], Any]


@dataclass(frozen=True)
class Check:
    """One check of the gate: its name (Verdict.failed), its test and its reason."""

    name: str
    fails: Test    # a bool, or a bool array where the figures or the thresholds hold arrays
    reason: Callable[[Figures, AcceptanceConfig], str]  # for one pose


# NaN compares False: a figure not measured fails no check
CHECKS = (
    Check("min_inliers", lambda figures, acceptance: figures.num_inliers < acceptance.min_inliers,
          lambda figures, acceptance: (f"only {figures.num_inliers:.0f} inliers "
                                       f"(acceptance.min_inliers={acceptance.min_inliers})")),
    Check("constrained", lambda figures, _: ~np.asarray(figures.constrained, dtype=bool),
          lambda figures, _: "the inliers do not constrain all six degrees of freedom (plane or line?)"),
    Check("min_fitness", lambda figures, acceptance: figures.fitness < acceptance.min_fitness,
          lambda figures, acceptance: (f"fitness {figures.fitness:.3f} below "
                                       f"acceptance.min_fitness={acceptance.min_fitness}")),
    Check("gravity_tilt", lambda figures, _: ~np.asarray(figures.tilt_inside, dtype=bool),
          lambda figures, _: (f"the pose tilts the source's up by {figures.tilt_deg:.1f} deg from the target's "
                              f"(gravity.max_tilt={figures.tilt_allowed_deg:g}): " +
                              ("held on the edge the prior allows: the up given is off by more than that "
                               "(an IMU read while turning or accelerating, or a map whose z is not up?)"
                               if abs(figures.tilt_deg - figures.tilt_allowed_deg) <= EDGE_HELD_DEG
                               else "tipped over"))),
    Check("gravity_height", lambda figures, _: ~np.asarray(figures.height_inside, dtype=bool),
          lambda figures, _: (f"the pose puts the source's sensor {figures.height_offset:+.2f} m from the height "
                              f"the target was seen from, {figures.height_distance:.1f} m away (allowed "
                              f"{figures.height_allowed:.2f} m: gravity.height_tolerance plus gravity.max_slope "
                              "over that distance)")),
    Check("min_surface_agreement",
          lambda figures, acceptance: figures.surface_agreement < acceptance.min_surface_agreement,
          lambda figures, acceptance: (f"only {100 * figures.surface_agreement:.0f} % of the overlap lies on the "
                                       "target's surfaces at the keypoint spacing (acceptance.min_surface_agreement="
                                       f"{acceptance.min_surface_agreement}): the clouds touch, they do not coincide")),
    Check("max_false_alarms",
          lambda figures, acceptance: (~_beyond_chance(figures.log10_false_alarms, acceptance)
                                       & ~_beyond_chance(figures.surface_log10_false_alarms, acceptance)),
          _chance_reason),
    Check("min_feature_inliers",
          lambda figures, acceptance: figures.feature_inliers < _needed_features(figures, acceptance),
          _features_reason),
    Check("max_free_space_violation",
          lambda figures, acceptance: figures.worst_free_space > acceptance.max_free_space_violation,
          _free_space_reason),
    Check("max_free_space_both_sides",
          lambda figures, acceptance: figures.both_sides_free_space > acceptance.max_free_space_both_sides,
          _both_sides_reason),
    Check("max_opposite_sides", lambda figures, acceptance: figures.opposite_sides > acceptance.max_opposite_sides,
          lambda figures, acceptance: (f"{100 * figures.opposite_sides:.0f} % of the shared surface was seen from "
                                       f"opposite sides (acceptance.max_opposite_sides={acceptance.max_opposite_sides})"
                                       ": the clouds are back to back, the pose is wrong")),
    Check("max_ambiguity", lambda figures, acceptance: ambiguity(figures, acceptance) > acceptance.max_ambiguity,
          _ambiguity_reason),
    Check("min_weakest_support",
          lambda figures, acceptance: figures.weakest_support < acceptance.min_weakest_support, _slide_reason),
    Check("search_region", lambda figures, _: figures.region_offset > figures.region_radius,
          lambda figures, _: (f"the pose puts the source {figures.region_offset:.1f} m from the hinted position, "
                              f"outside its {figures.region_radius:.1f} m search region")),
    Check("reverse_check",
          lambda figures, _: ((figures.reverse_turn_deg >= REVERSE_MAX_DEG)
                              | (figures.reverse_offset_tau >= REVERSE_MAX_TAU)),
          lambda figures, _: (f"registering target to source gives another pose ({figures.reverse_turn_deg:.0f} deg, "
                              f"{figures.reverse_offset_tau:.1f} inlier thresholds away): a different place or an "
                              "ambiguous scene (acceptance.reverse_check)")),
)
FREE_SPACE_CHECKS = tuple(check for check in CHECKS if check.name.startswith("max_free_space"))
BEFORE_RIVALS = CHECKS[:[check.name for check in CHECKS].index("min_feature_inliers")]  # none reads a rival
PASSED = len(CHECKS)


def first_failure(figures: Figures, acceptance: AcceptanceConfig, checks: tuple[Check, ...] = CHECKS):
    """The index in ``checks`` of the first check each pose fails; len(checks) where it passes all."""
    first: Any = len(checks)
    with np.errstate(invalid="ignore"):
        for index in reversed(range(len(checks))):
            first = np.where(checks[index].fails(figures, acceptance), index, first)
    return first


def passes(figures: Figures, acceptance: AcceptanceConfig, checks: tuple[Check, ...] = CHECKS):
    """Whether each pose passes every one of ``checks`` (bool, or an array where figures or
    thresholds are arrays)."""
    return first_failure(figures, acceptance, checks) == len(checks)


@dataclass(frozen=True)
class Rules:
    """The judge's predicates under one acceptance config, for the modules that measure (which
    import no judge) to ask before they pay for a figure, or to read a figure as the judge would."""

    acceptance: AcceptanceConfig

    def rivals_may_matter(self, figures: Figures) -> bool:
        """Whether the rivals can change the verdict or the check it names: the pose passes every
        check before the first they bear on (the feature count, which a pose singled out among them
        is spared: _needed_features; then the ambiguity). Against chance, the surfaces must already
        have been tried."""
        return bool(passes(figures, self.acceptance, BEFORE_RIVALS))

    def chance_explains(self, log10_false_alarms: float) -> bool:
        """Whether chance gives this support more often than acceptance.max_false_alarms allows."""
        return bool(log10_false_alarms > np.log10(self.acceptance.max_false_alarms))

    def surfaces_may_carry(self, figures: Figures) -> bool:
        """Whether the surfaces' test against chance can change the verdict: the feature matches
        fail theirs and the pose passes every other check measured so far (their feature count
        included, which a pose the surfaces carry does not need: _needed_features)."""
        unless_chance = dataclasses.replace(self.acceptance, max_false_alarms=np.inf, min_feature_inliers=0)
        return self.chance_explains(figures.log10_false_alarms) and bool(passes(figures, unless_chance))

    def contends(self, lead_chance: float) -> bool:
        """Whether a rival is close enough in lead that its own figures may matter (max_ambiguity)."""
        return bool(lead_chance > self.acceptance.max_ambiguity)

    def free_space_passes(self, figures: Figures) -> bool:
        """Whether the pose passes the free-space checks (FREE_SPACE_CHECKS: each side's, and both
        at once)."""
        return bool(passes(figures, self.acceptance, FREE_SPACE_CHECKS))

    def sees_through(self, seen: int, inside: int) -> bool:
        """Whether more than max_free_space_violation of the ``seen`` points lie in the free space
        (too few seen to tell does not)."""
        acceptance = self.acceptance
        return seen >= acceptance.free_space_min_seen and inside > acceptance.max_free_space_violation * seen


@dataclass(frozen=True)
class Verdict:
    """The gate's ruling on one pose."""

    accepted: bool
    reason: str            # why it was not accepted; empty when accepted
    failed: str = ""       # the name of the check that failed (Check.name); empty when accepted
    ambiguity: float | None = None  # judge.ambiguity: the largest lead chance of a rival that counts
    carried_by: str = ""   # the test against chance that carried an accepted pose: "feature matches" or "surfaces"
    singled_out: bool = False  # its feature matches beat every other answer measured (min_feature_inliers waived)


def judge(figures: Figures, acceptance: AcceptanceConfig) -> Verdict:
    """The verdict on one pose, naming the first check it fails."""
    index = int(first_failure(figures, acceptance))
    level = float(ambiguity(figures, acceptance))
    shown = None if np.isnan(level) else level
    alone = bool(singled_out(figures, acceptance))
    if index == PASSED:
        return Verdict(True, "", "", shown, carried_by(figures, acceptance), alone)
    check = CHECKS[index]
    return Verdict(False, check.reason(figures, acceptance), check.name, shown, singled_out=alone)
