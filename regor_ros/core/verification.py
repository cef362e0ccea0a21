"""Is this pose trustworthy? The quality gate: every check a pose must pass to be published.

A wrong pose published with confidence is the worst outcome, so a pose is accepted only when
- enough keypoints agree with it (inliers, fitness) and they fix all six degrees of freedom;
- its overlap lies on the target's surfaces at the keypoints' resolution, and its feature support
  is more than chance gives in a search of this size (core/evidence.py: neither depends on how
  large the target is);
- enough of the original feature matches agree with it (geometry alone aligns unrelated planes),
  more when free space cannot be checked from both sides (a map has no viewpoint);
- neither cloud puts surfaces into space the other sensor saw through, and the surface both saw
  was seen from the same side (visibility);
- the pose turned by 180 degrees about an axis of symmetry of the overlap does not explain the
  clouds about as well (a symmetric room turned around passes every other check: when both
  poses fit, neither can be trusted);
- it lies inside the search region a hint gave, and (acceptance.reverse_check) registering the
  target to the source gives it back.
Every rejection, with its reason, is made here; the pipeline only runs what these checks judge.
Every figure is computed whatever the verdict (the rivals once the pose is measurable), so a user,
and the calibration (regor-calibrate-gate), sees all of them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from . import kernels
from .cloud import PreparedCloud
from .config import AcceptanceConfig, RegorConfig
from .estimate import UNCONSTRAINED_VARIANCE, agreeing, point_refine, poses_close
from .evidence import Evidence
from .geometry import to_matrix, transform_points
from .gravity import GravityPrior, inside_band
from .metrics import rotation_error_deg, translation_error
from .range_image import seen_and_inside
from .search_region import SearchRegion
from .visibility import VisibilityFigures, opposite_sides

RIVAL_MIN_DEG = 10.0  # a refined rival closer than this to the pose has fallen back onto it
RIVAL_POINTS = 1000   # evenly spaced source keypoints on which the pose and its rivals are compared
RIVAL_ITERATIONS = 10


@dataclass
class Rival:
    """The pose turned about one symmetry axis of the overlap, refined like the pose."""

    inlier_ratio: float          # its inliers / the pose's
    feature_ratio: float         # its agreeing feature matches / the pose's
    violation: float | None   # its worst free-space figure
    opposite_sides: float | None  # its matched surface seen from opposite sides
    distance_deg: float          # its rotation from the pose after refinement


@dataclass
class Verdict:
    accepted: bool
    reason: str                     # why it was not accepted; empty when accepted
    visibility: VisibilityFigures
    rivals: list[Rival] = field(default_factory=list)
    ambiguity: float | None = None  # support ratio of the best rival that passes the visibility checks
    evidence: Evidence | None = None


def pose_slack(uncertainty: tuple[float, float] | None, sigmas: float):
    """How far the pose may misplace a point at distance r from the source's origin, as a
    function of r: ``sigmas`` standard deviations of ``uncertainty`` (translation [m], turn
    [rad]) as sigma_t + r sigma_turn (None: no allowance)."""
    if uncertainty is None or sigmas <= 0:
        return None
    translation, turn = uncertainty
    return lambda r: sigmas * (translation + turn * r)


def visibility_figures(T: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                       gate: AcceptanceConfig, matched_index: np.ndarray | None = None,
                       uncertainty: tuple[float, float] | None = None) -> VisibilityFigures:
    """The visibility figures of T_target_source; ``matched_index`` lists the target keypoints of
    its inlier pairs. Each side is a cloud's sensors (their range images), or, for a cloud with no
    viewpoint (a map), the map seen from the other cloud's sensors placed by the pose. With the
    pose's ``uncertainty`` (estimate.resolution_uncertainty) each point's free-space margin grows
    by it there (acceptance.free_space_sigmas)."""
    T_inv = np.linalg.inv(T)
    slack = pose_slack(uncertainty, gate.free_space_sigmas)
    source_side = _side(T_inv, source, target, gate, near_only=True, slack=slack)
    target_side = _side(T, target, source, gate, near_only=False, slack=slack)
    sides = None
    if matched_index is not None and source.views and target.views:
        points, normals = target.points[matched_index], target.normals[matched_index]
        sides = opposite_sides(_nearest(target.viewpoints, points),
                               _nearest(transform_points(T, source.viewpoints), points),
                               points, normals, gate.free_space_min_seen)
    return VisibilityFigures(source_side[0], target_side[0], sides, source_side[1], target_side[1],
                             source_side[2] if source.map_view is not None else target_side[2])


def _side(T_seer_other: np.ndarray, seer: PreparedCloud, other: PreparedCloud, gate: AcceptanceConfig,
          near_only: bool, slack=None):
    """(fraction of ``other``'s keypoints inside ``seer``'s seen free space or None, how many
    landed on seen bins, fraction of them seen: for a map side). ``near_only``: test only the
    other's keypoints within the seer's sensor range (the other may be a large map). ``slack``
    (pose_slack) widens each point's margin by its distance from the source's origin."""
    margin, ratio, min_seen = gate.free_space_margin, gate.free_space_margin_ratio, gate.free_space_min_seen
    # the source frame's origin in the seer's frame: the seer is the source when near_only
    source_origin = np.zeros(3) if near_only else T_seer_other[:3, 3]

    def widen(points: np.ndarray):
        return 0.0 if slack is None else slack(np.linalg.norm(points - source_origin, axis=1))

    if seer.views:
        points = other.points
        if near_only:
            reach = np.array([view.max_range for view in seer.views]) + margin
            points = other.points[kernels.within_any(other.points, transform_points(
                np.linalg.inv(T_seer_other), seer.viewpoints), reach)]
        points = transform_points(T_seer_other, points)
        seen, inside = seen_and_inside(seer.views, points, margin, ratio, widen(points))
        return (inside / seen if seen >= min_seen else None), seen, None
    if seer.map_view is not None and other.views:
        # the map seen from where the pose puts the other cloud's sensors, out to their reach
        points = transform_points(T_seer_other, other.points)
        reach = max(view.max_range for view in other.views) + margin
        images = seer.map_view.images(transform_points(T_seer_other, other.viewpoints), reach)
        seen, inside = seen_and_inside(images, points, margin, ratio, widen(points))
        fraction_seen = seen / max(len(points), 1)
        counts = seen >= min_seen and fraction_seen >= gate.map_view_min_seen
        return (inside / seen if counts else None), seen, fraction_seen
    return None, 0, None


def _nearest(viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each point, the nearest of the viewpoints (the sensor that saw it, most likely)."""
    if len(viewpoints) == 1:
        return viewpoints[0]
    return viewpoints[cKDTree(viewpoints).query(points)[1]]


def assess(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, num_inliers: int,
           fitness: float, matches: tuple, num_feature_inliers: int, covariance: np.ndarray,
           uncertainty: tuple[float, float], overlap_index: np.ndarray, support: Evidence, config: RegorConfig,
           prior: GravityPrior | None = None) -> Verdict:
    """Run every check on the pose T_target_source; the reason names the first that fails.
    ``matches`` are the feature matches (source, target points), ``num_feature_inliers`` how many
    of them the pose brings within initial.inlier_threshold; ``overlap_index`` lists the target
    keypoints of the pose's inlier pairs (the overlap); ``uncertainty`` how well a right pose is
    known at this resolution (estimate.resolution_uncertainty: the free-space check's allowance);
    ``support`` the pose's evidence against chance. With a gravity ``prior`` the pose must keep to
    it, and so must a symmetric rival to count."""
    gate = config.acceptance
    visibility = visibility_figures(T, source, target, gate, overlap_index, uncertainty)
    reason = _structural_failure(num_inliers, fitness, covariance, gate)
    if not reason and prior is not None:
        reason = gravity_failure(prior, T, source, target)
    rivals: list[Rival] = []
    ambiguous = None
    if not reason:  # the rivals cost a refinement each: only for poses that may be published
        rivals = symmetric_rivals(T, num_feature_inliers, matches, target.points[overlap_index],
                                  source, target, config, prior)
        ambiguous = ambiguity(rivals, gate.max_free_space_violation, gate.max_opposite_sides)
        reason = _chance_failure(support, gate) or _evidence_failure(
            num_feature_inliers, visibility, ambiguous, gate)
    return Verdict(not reason, reason, visibility, rivals, ambiguous, support)


def gravity_failure(prior: GravityPrior, T: np.ndarray, source: PreparedCloud, target: PreparedCloud) -> str:
    """Why the pose breaks the gravity prior (empty when it does not): tilt, then sensor height."""
    if not prior.tilt_inside(T[:3, :3]):
        tilt = float(prior.tilt_deg(T[:3, :3]))
        return (f"the pose tilts the source's up by {tilt:.1f} deg from the target's "
                f"(gravity.max_tilt={prior.max_tilt_deg:g}): tipped over")
    band = prior.height_band(T[None], source, target)
    if band is not None and not inside_band(band)[0]:
        height, allowed, distance = (float(v[0]) for v in band)
        return (f"the pose puts the source's sensor {height:+.2f} m from the height the target "
                f"was seen from, {distance:.1f} m away (allowed {allowed:.2f} m: "
                f"gravity.height_tolerance={prior.height_tolerance:g} plus gravity.max_slope="
                f"{prior.max_slope_deg:g} deg over that distance)")
    return ""


def free_space_plausible(T: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                         gate: AcceptanceConfig) -> bool:
    """Whether the pose passes the free-space check (initial.free_space_selection: FS-TCD's winner
    is the fittest hypothesis this holds for)."""
    worst = visibility_figures(T, source, target, gate).worst
    return worst is None or worst <= gate.max_free_space_violation


def half_turns(points: np.ndarray) -> np.ndarray:
    """(3, 4, 4): turns by 180 degrees about each principal axis of ``points``, through their
    centroid: the symmetries of a box-like room, a corridor or a road."""
    centre = points.mean(axis=0)
    axes = np.linalg.svd(points - centre, full_matrices=False)[2]
    rotations = 2.0 * axes[:, :, None] * axes[:, None, :] - np.eye(3)
    return to_matrix(rotations, centre - rotations @ centre)


def symmetric_rivals(T: np.ndarray, num_feature_inliers: int, matches: tuple, overlap: np.ndarray,
                     source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                     prior: GravityPrior | None = None) -> list[Rival]:
    """The pose turned about each symmetry axis of the overlap and refined; the inliers of the
    pose and its rivals are counted on the same RIVAL_POINTS source keypoints (for speed). A truly
    symmetric scene also gives the rival feature support: symmetric places look alike. Under a
    gravity prior, a turn that tips the source over, or lifts its sensor out of the height band,
    is no rival (a road seen upside down)."""
    if len(overlap) < 3:
        return []
    est, gate = config.estimation, config.acceptance
    sample = source.points[np.unique(np.linspace(0, len(source) - 1, RIVAL_POINTS).astype(np.int64))]
    own = len(point_refine(T, sample, target.tree, est.inlier_threshold, 0).source_index)
    rivals = []
    turned = half_turns(overlap) @ T
    if prior is not None:
        turned = turned[prior.allows(turned, source, target)]
    for start in turned:
        refined = point_refine(start, sample, target.tree, est.inlier_threshold, RIVAL_ITERATIONS,
                               prior and prior.clamp)
        visibility = visibility_figures(refined.transform, source, target, gate, refined.target_index)
        rivals.append(Rival(len(refined.source_index) / max(own, 1),
                            int(agreeing(refined.transform, *matches, config.initial.inlier_threshold).sum())
                            / max(num_feature_inliers, 1),
                            visibility.worst, visibility.opposite_sides,
                            rotation_error_deg(refined.transform, T)))
    return rivals


def ambiguity(rivals: list[Rival], max_violation: float, max_opposite: float) -> float | None:
    """How well the best rival that is distinct from the pose and passes the visibility checks
    explains the clouds, relative to the pose: the lesser of its point and feature support ratios
    (None when there is no such rival)."""
    ratios = [min(r.inlier_ratio, r.feature_ratio) for r in rivals if r.distance_deg > RIVAL_MIN_DEG
              and (r.violation is None or r.violation <= max_violation)
              and (r.opposite_sides is None or r.opposite_sides <= max_opposite)]
    return max(ratios) if ratios else None


def _structural_failure(num_inliers: int, fitness: float, covariance: np.ndarray,
                        gate: AcceptanceConfig) -> str:
    """The checks that make a pose measurable at all (not fitted to data)."""
    if num_inliers < gate.min_inliers:
        return f"only {num_inliers} inliers (acceptance.min_inliers={gate.min_inliers})"
    if np.linalg.eigvalsh(covariance).max() >= UNCONSTRAINED_VARIANCE:
        return "the inliers do not constrain all six degrees of freedom (plane or line?)"
    if fitness < gate.min_fitness:
        return f"fitness {fitness:.3f} below acceptance.min_fitness={gate.min_fitness}"
    return ""


def _chance_failure(support: Evidence, gate: AcceptanceConfig) -> str:
    """The checks whose evidence is scaled to chance in this search (core/evidence.py)."""
    if support.surface_agreement < gate.min_surface_agreement:
        return (f"only {100 * support.surface_agreement:.0f} % of the overlap lies on the target's "
                f"surfaces at the keypoint spacing (acceptance.min_surface_agreement="
                f"{gate.min_surface_agreement}): the clouds touch, they do not coincide")
    if support.log10_false_alarms > np.log10(gate.max_false_alarms):
        return (f"chance alone gives {support.independent_agreeing} independent agreeing feature "
                f"matches in about 10^{support.log10_false_alarms:.1f} of the poses this search tried "
                f"(acceptance.max_false_alarms={gate.max_false_alarms}): too little feature support "
                "for a target this size")
    return ""


def _evidence_failure(num_feature_inliers: int, visibility: VisibilityFigures,
                      ambiguous: float | None, gate: AcceptanceConfig) -> str:
    """The checks that tell a right pose from a wrong one (thresholds calibrated on held-out places)."""
    if visibility.both_sides:
        name, needed, why = "min_feature_inliers", gate.min_feature_inliers, ""
    else:  # visibility cannot catch what it would have: features must stand on their own
        name, needed, why = ("min_feature_inliers_partial", gate.min_feature_inliers_partial,
                             ": free space was not checked from both sides, a viewpoint is unknown "
                             "or too little of one cloud is in the other's view")
    if num_feature_inliers < needed:
        return (f"only {num_feature_inliers} feature matches agree with the pose "
                f"(acceptance.{name}={needed}{why})")
    violation, opposite = visibility.worst, visibility.opposite_sides
    if violation is not None and violation > gate.max_free_space_violation:
        return (f"{100 * violation:.0f} % of one cloud lies in space the other sensor saw through "
                f"(acceptance.max_free_space_violation={gate.max_free_space_violation}): surfaces "
                "pass through each other, the pose is wrong")
    if opposite is not None and opposite > gate.max_opposite_sides:
        return (f"{100 * opposite:.0f} % of the shared surface was seen from opposite sides "
                f"(acceptance.max_opposite_sides={gate.max_opposite_sides}): the clouds are back to "
                "back, the pose is wrong")
    if ambiguous is not None and ambiguous >= gate.max_ambiguity:
        return (f"the pose turned by 180 deg fits with {100 * ambiguous:.0f} % of its support "
                f"(acceptance.max_ambiguity={gate.max_ambiguity}): a symmetric scene, neither "
                "pose can be trusted")
    return ""


def search_region_failure(T: np.ndarray, region: SearchRegion) -> str:
    """Why the pose is outside the hint's search region (empty when inside). Horizontal distance
    only: hints are mostly 2D pose estimates on the ground, which say nothing of the sensor's height."""
    offset = float(np.linalg.norm(T[:2, 3] - region.centre[:2]))
    if offset <= region.radius:
        return ""
    return (f"the pose puts the source {offset:.1f} m from the hinted position, outside its "
            f"{region.radius:.1f} m search region")


REVERSE_MAX_DEG = 10.0  # the reverse registration agrees when within these
REVERSE_MAX_TAU = 3.0   # (translation in units of initial.inlier_threshold)


def reverse_failure(T: np.ndarray, returned: np.ndarray, inlier_threshold: float) -> str:
    """Why registering target to source (``returned``: its pose inverted) contradicts ``T`` (empty
    when it gives it back). Box-like rooms of different places can align with as much feature
    support as a true low-overlap pair, but the reverse search then lands elsewhere; a true pose
    comes back (measured: 59 of 59)."""
    if poses_close(T, returned, REVERSE_MAX_DEG, REVERSE_MAX_TAU * inlier_threshold):
        return ""
    return (f"registering target to source gives another pose ({rotation_error_deg(T, returned):.0f} deg, "
            f"{translation_error(T, returned):.2f} m away): a different place or an ambiguous "
            "scene (acceptance.reverse_check)")
