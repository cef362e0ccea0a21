"""Measure the figures the gate judges a pose on (gate/figures.py), so a user and the calibration
see them. Two tests cost refinements, and each is measured only where it can change the verdict:
the surfaces' test against chance (a dozen refinements) for a pose whose feature matches fail
theirs and that passes every other check; then the rivals (a refinement each, a full one for a
rival that contends) for a pose that passes every check before the first they bear on, chance
included, so that the verdict and the check it names are what they would be with every figure
measured. A pose that fails such a check (a query from outside the map, mostly) is withheld
without them. Which is which, the judge's rules say (judge.Rules): nothing here compares a figure
with a threshold."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..cloud import PreparedCloud
from ..config import RegorConfig
from ..estimate import UNCONSTRAINED_VARIANCE, PointRefinement
from ..gravity import GravityPrior, inside_band
from ..metrics import rotation_error_deg, translation_error
from ..search_region import SearchRegion
from .evidence import Evidence, evidence, log10_false_alarms
from .figures import Figures
from .rivals import rivals
from .slide import weakest_support
from .surface_evidence import SurfaceEvidence, surface_evidence
from .visibility import VisibilityFigures, visibility_figures

if TYPE_CHECKING:
    from .judge import Rules


@dataclass
class Measured:
    """A pose's gate figures, with the visibility and evidence figures they were taken from."""

    figures: Figures
    visibility: VisibilityFigures  # with what the figures leave out: how many points each side saw
    evidence: Evidence
    surfaces: SurfaceEvidence | None = None  # the surfaces' test, when it was run
    rival_poses: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4, 4)))  # one per rival


def measure(refined: PointRefinement, source: PreparedCloud, target: PreparedCloud, matches: tuple, *,
            covariance: np.ndarray, uncertainty: tuple[float, float], hypotheses: int, places: list,
            config: RegorConfig, rules: Rules, refine: Callable[[np.ndarray], PointRefinement],
            prior: GravityPrior | None = None) -> Measured:
    """The figures of the refined pose T_target_source. ``matches`` are the feature matches
    (source points, target points, which of them agree with the pose within
    initial.inlier_threshold); ``uncertainty`` how well a right pose is known at this resolution
    (estimate.resolution_uncertainty: the free-space check's allowance); ``hypotheses`` how many
    poses the search compared (the evidence's trials) and ``places`` the poses of the distinct
    places it found, best first (rivals, with the pose's symmetric twins); ``refine`` the
    estimator's refinement of a pose, as the pose had it (a contending rival gets it). Under a gravity
    ``prior`` the pose's tilt and height are measured, and a rival, or a decoy, keeps to the prior."""
    T, voxel = refined.transform, config.features.voxel_size
    match_source, match_target, agree = matches
    final_source, final_target = source.points[refined.source_index], target.points[refined.target_index]
    overlap = (final_source, final_target, target.normals[refined.target_index])
    support = evidence(T, overlap, target.points,
                       target.neighbours, match_source, agree, voxel, config.initial.inlier_threshold,
                       config.features.fpfh_radius, hypotheses)
    visibility = visibility_figures(T, source, target, config.acceptance, refined.target_index, uncertainty)
    slide_support = weakest_support(T, overlap, voxel, config.features.fpfh_radius)[0]
    figures = Figures(
        num_inliers=len(final_source), fitness=len(final_source) / len(source),
        constrained=bool(np.linalg.eigvalsh(covariance).max() < UNCONSTRAINED_VARIANCE),
        surface_agreement=support.surface_agreement, log10_false_alarms=support.log10_false_alarms,
        independent_agreeing=support.independent_agreeing, feature_inliers=int(agree.sum()),
        weakest_support=slide_support,
        **visibility.as_figures(), **({} if prior is None else gravity_figures(T, prior, source, target)))
    surfaces = None
    # the surfaces can carry a pose the features do not: measured where nothing else withholds it
    if rules.surfaces_may_carry(figures):
        surfaces = surface_evidence(T, source, target, config, hypotheses, rules.chance_explains, prior)
        figures = dataclasses.replace(
            figures, surface_log10_false_alarms=surfaces.log10_false_alarms, surface_cells=surfaces.cells,
            surface_cells_agreeing=surfaces.agreeing, surface_chance=surfaces.chance)
    rival_poses = np.zeros((0, 4, 4))
    if rules.rivals_may_matter(figures):
        def against_chance(agreeing: int) -> float:
            return log10_false_alarms(agreeing, support.independent_matches, support.chance, hypotheses)
        rival_figures, rival_poses = rivals(T, overlap, matches, places, source, target, config, rules.contends,
                                            refine, prior, against_chance)
        figures = dataclasses.replace(figures, rivals=rival_figures)
    return Measured(figures, visibility, support, surfaces, rival_poses)


def gravity_figures(T: np.ndarray, prior: GravityPrior, source: PreparedCloud, target: PreparedCloud) -> dict:
    """The pose's tilt and its sensor's height against the prior (Figures' gravity fields), with
    the prior's own predicates: a pose held on the tilt cone's edge is not inside (held_at_edge)."""
    R = T[:3, :3]
    figures = {"tilt_deg": float(prior.tilt_deg(R)), "tilt_allowed_deg": prior.max_tilt_deg,
               "tilt_inside": bool(prior.tilt_inside(R) and not prior.held_at_edge(R))}
    band = prior.height_band(T[None], source, target)
    if band is not None:
        height, allowed, distance = (float(v[0]) for v in band)
        figures.update(height_offset=height, height_allowed=allowed, height_distance=distance,
                       height_inside=bool(inside_band(band)[0]))
    return figures


def region_figures(T: np.ndarray, region: SearchRegion) -> dict:
    """Where the pose puts the source's origin against the hint's search region (Figures' region
    fields). Horizontal distance only: hints are mostly 2D pose estimates on the ground, which say
    nothing of the sensor's height."""
    return {"region_offset": float(np.linalg.norm(T[:2, 3] - region.centre[:2])),
            "region_radius": float(region.radius)}


def reverse_figures(T: np.ndarray, returned: np.ndarray, inlier_threshold: float) -> dict:
    """How far registering target to source (``returned``: its pose inverted) lands from ``T``
    (Figures' reverse fields). Box-like rooms of different places can align with as much feature
    support as a true low-overlap pair, but the reverse search then lands elsewhere; a true pose
    comes back."""
    return {"reverse_turn_deg": float(rotation_error_deg(T, returned)),
            "reverse_offset_tau": float(translation_error(T, returned)) / inlier_threshold}
