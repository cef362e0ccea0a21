"""Evidence from geometry against chance: does the pose lay the source on the target's surfaces
far better than a wrong pose there would?

The feature test (evidence.py) counts agreeing descriptor matches; a sparse scan with a narrow
field of view has few of those even under a right pose (2-4 independent ones on the shared
scan-to-map data, 10^2-10^3 expected false alarms). Its surfaces, though, lie on the map's. A
count of that alone is no evidence: the refinement pulls any pose onto nearby surfaces, so a
wrong pose also puts most of its overlap on them (0.5-0.9 of it on the shared maps). So the chance
is measured where the pose is, with the same refinement: decoys, the pose moved by a random turn
and shift from beyond the refinement's reach and refined as the estimator refines. A decoy that
comes back toward the pose found the pose again; the others are wrong poses of this place
(a slide along a corridor, a turn onto a wall), and the best of them, by the fraction of its
overlap on the surfaces, is the null: each of the pose's independent overlap cells (one per
descriptor radius) lies on the target's surface at the keypoint spacing with that probability.
False alarms, as for the features: the hypotheses the search tried times the binomial tail of the
cells on the surfaces, beyond the three a rigid fit takes for free. Either test may carry a pose
(judge.py); neither is fitted.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..cloud import PreparedCloud
from ..config import RegorConfig
from ..estimate import plane_refine, plane_thresholds, point_refine
from ..geometry import evenly_spaced, to_matrix, transform_points
from ..gravity import GravityPrior, clamp_of
from ..metrics import rotation_error_deg, translation_error
from .evidence import independent, log10_false_alarms, on_surface

DECOYS = 12                 # wrong poses refined per test: the null's sample
DECOY_TURN_DEG = (10.0, 40.0)   # each decoy's turn about a random axis through the overlap's centre
DECOY_SHIFT_TAU = (2.0, 6.0)    # and its shift, in estimation.inlier_threshold: beyond the refinement's reach
DECOY_MIN_CELLS = 10        # a decoy that overlaps fewer cells tells nothing of the chance
DECOY_POINTS = 1000         # evenly spaced source keypoints each decoy is refined on (for speed)
DECOY_STREAM = 3            # keeps the decoys' draws apart from other seeded draws of the same seed


@dataclass
class SurfaceEvidence:
    """The test's figures for one pose."""

    cells: int                 # independent cells of the overlap (source keypoints within tau_e of the target)
    agreeing: int              # of them, on the target's surface at the keypoint spacing
    chance: float              # the best distinct decoy's fraction of cells on the surface (NaN: no decoy)
    decoys: int                # decoys that did not come back to the pose
    log10_false_alarms: float  # NaN without a decoy


def cells_on_surface(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, tolerance: float,
                     resolution: float, radius: float) -> tuple[int, int]:
    """(independent cells of the overlap, of them on the surface): the source keypoints ``T``
    brings within ``tolerance`` of a target keypoint, one per ``radius``, and those within
    ``resolution`` of that keypoint's tangent plane, one per ``radius``. (Greedy picks can find
    more places among the keypoints on the surface than among all; no more agree than there are.)"""
    placed = transform_points(T, source.points)
    distance, nearest = target.neighbours.nearest_within(placed, tolerance)
    near = np.isfinite(distance)
    on = on_surface(placed[near], target.points[nearest[near]], target.normals[nearest[near]], resolution)
    cells = len(independent(placed[near], radius))
    return cells, min(len(independent(placed[near][on], radius)), cells)


def surface_evidence(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                     hypotheses: int, chance_explains: Callable[[float], bool],
                     prior: GravityPrior | None = None) -> SurfaceEvidence:
    """The test of the refined pose ``T``; ``hypotheses`` the poses the search compared. The
    decoys are refined one by one, and the test stops once chance explains the cells
    (``chance_explains``, given log10 of the false alarms: the best decoy so far is enough to fail
    it, more can only raise the chance)."""
    est, voxel, radius = config.estimation, config.features.voxel_size, config.features.fpfh_radius
    cells, agreeing = cells_on_surface(T, source, target, est.inlier_threshold, voxel, radius)
    fractions: list[float] = []
    false_alarms = float("nan")
    for decoy in decoys(T, source, target, config, prior):
        decoy_cells, decoy_agreeing = cells_on_surface(decoy, source, target, est.inlier_threshold, voxel, radius)
        if decoy_cells < DECOY_MIN_CELLS:
            continue
        fractions.append(decoy_agreeing / decoy_cells)
        # counted as the feature test counts: the best decoy's fraction is each cell's chance
        false_alarms = log10_false_alarms(agreeing, cells, max(fractions), hypotheses)
        if chance_explains(false_alarms):
            break
    return SurfaceEvidence(cells, agreeing, max(fractions, default=float("nan")), len(fractions), false_alarms)


def decoys(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
           prior: GravityPrior | None = None):
    """The refined decoys of ``T`` that do not come back to it, one at a time: each starts at a
    seeded turn of DECOY_TURN_DEG and shift of DECOY_SHIFT_TAU estimation.inlier_threshold from
    it and is refined as the estimator refines (point level, then planes when configured; on
    DECOY_POINTS keypoints, inside the gravity prior's cone), and one that ends within the least
    of those of the pose came back."""
    est, tolerance = config.estimation, config.estimation.inlier_threshold
    sample = evenly_spaced(source.points, DECOY_POINTS)
    clamp = clamp_of(prior)
    rng = np.random.default_rng([DECOY_STREAM, config.seed])
    centre = transform_points(T, source.points).mean(axis=0)
    for _ in range(DECOYS):
        axis = rng.normal(size=3)
        turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(rng.uniform(*DECOY_TURN_DEG))).as_matrix()
        direction = rng.normal(size=3)
        shift = direction / np.linalg.norm(direction) * rng.uniform(*DECOY_SHIFT_TAU) * tolerance
        start = to_matrix(turn, centre - turn @ centre + shift) @ T
        decoy = point_refine(start, sample, target.neighbours, tolerance, est.max_iterations, clamp).transform
        if est.plane_refinement:
            decoy = plane_refine(decoy, sample, target.neighbours, target.normals,
                                 plane_thresholds(tolerance, config.features.voxel_size),
                                 config.features.voxel_size, clamp)
        came_back = (rotation_error_deg(decoy, T) <= DECOY_TURN_DEG[0]
                     and translation_error(decoy, T) <= DECOY_SHIFT_TAU[0] * tolerance)
        if not came_back:
            yield decoy
