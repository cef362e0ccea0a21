"""How much of a pose's support could chance explain? Figures that scale with the search.

A fixed count of agreeing feature matches, or a fixed fraction of keypoints within the search
tolerance, means one thing between two scans and another against a map many times larger: there
a wrong pose finds surfaces near every keypoint and a few matches that agree by chance. Two
figures that do not depend on how large the target is:

- **Surface agreement at the sensor's resolution.** Of the source keypoints the pose brings
  within the estimator's tolerance tau_e of the target (the overlap), the fraction within one
  keypoint spacing (the voxel) of the target's surface. Under a right pose the overlap lies *on*
  the target's surfaces, so nearly all of it (0.94-1.0 on the shared scan-to-map queries); under a
  wrong one its points sit anywhere up to tau_e from them (0.19-0.79), however dense the map. Judged on the pose
  refined at that resolution, so a right pose a degree off is not blamed for the search's step.
- **False alarms of the feature support (a-contrario).** Neighbouring keypoints share most of
  their FPFH neighbourhood, so agreeing matches are counted once per descriptor radius (the
  independent ones). If the matches' targets were unrelated to their sources, each would agree
  with a given pose with the probability that a random target keypoint lies within tau of a
  given one (the target's own density: 1 / its size, for a map); the number of false alarms is
  the hypotheses the search tried times the binomial tail of the observed count. The pose was
  fitted to those matches, so a rigid pose's minimal sample (three matches) agrees with it by
  construction and is no evidence: chance must explain the other agreeing matches among the other
  matches (the count of a-contrario RANSAC, Moisan & Stival 2004). More than one expected false
  alarm means chance alone would have found that much support in this search.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import betainc

from .. import kernels
from ..geometry import transform_points, unique_rows
from ..neighbour_grid import NeighbourGrid

DENSITY_SAMPLE = 2000  # target keypoints whose neighbourhoods estimate the chance of agreement
DENSITY_SEED = 0
MINIMAL_SAMPLE = 3     # point matches that fix a rigid pose: they agree with the pose fitted to them


@dataclass
class Evidence:
    """The figures above for one pose."""

    surface_agreement: float      # overlap within one voxel / overlap within tau_e (0 when no overlap)
    overlap: int                  # source keypoints within tau_e of the target
    independent_matches: int      # feature matches, one per descriptor radius of the source
    independent_agreeing: int     # of those, the ones that agree with the pose
    chance: float                 # probability that an unrelated match agrees with a pose
    log10_false_alarms: float     # log10(hypotheses tried x binomial tail of the agreeing count)


def on_surface(placed: np.ndarray, paired_target: np.ndarray, paired_normals: np.ndarray,
               resolution: float) -> np.ndarray:
    """Mask of the ``placed`` source keypoints within ``resolution`` of their paired target
    keypoint's tangent plane (a sparse scan samples a surface along its lines: the nearest keypoint
    may be a voxel away along the surface, the surface is not)."""
    return np.abs(np.einsum("ij,ij->i", placed - paired_target, paired_normals)) < resolution


def surface_agreement(T: np.ndarray, overlap_source: np.ndarray, overlap_target: np.ndarray,
                      overlap_normals: np.ndarray, resolution: float) -> float:
    """Fraction of the overlap (each source keypoint ``T`` brings within tau_e of a target keypoint,
    paired with that keypoint and its normal) on the target's surface at ``resolution``."""
    if not len(overlap_source):
        return 0.0
    return float(on_surface(transform_points(T, overlap_source), overlap_target, overlap_normals, resolution).mean())


def independent(points: np.ndarray, radius: float) -> np.ndarray:
    """Indices of ``points`` no two of which are closer than ``radius`` (greedy, in order): one
    per descriptor neighbourhood."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    # one representative per cell of the radius (the cells in lexicographic order), then the
    # greedy rule among representatives, in the order of the points
    cells, first = unique_rows(np.floor(points / radius).astype(np.int64))
    visit = np.argsort(first, kind="stable")
    kept = kernels.greedy_apart(np.ascontiguousarray(points[first], dtype=np.float64), np.ascontiguousarray(cells),
                                visit, float(radius))
    return np.sort(first[kept])


def chance_of_agreement(points: np.ndarray, neighbours: NeighbourGrid, tolerance: float) -> float:
    """Probability that a random keypoint of this cloud lies within ``tolerance`` of a given one
    of them: the mean neighbour count over a seeded sample, over the cloud's size."""
    rng = np.random.default_rng(DENSITY_SEED)
    sample = points[rng.choice(len(points), min(DENSITY_SAMPLE, len(points)), replace=False)]
    return float(np.mean(neighbours.count_within(sample, tolerance))) / len(points)


def log10_false_alarms(agreeing: int, trials: int, chance: float, tests: int) -> float:
    """log10 of the expected number of poses, among ``tests`` fitted to these matches, that
    chance alone gives at least ``agreeing`` of ``trials`` agreeing matches: beyond the minimal
    sample each pose was fitted to, ``agreeing - 3`` of the other ``trials - 3``."""
    beyond = agreeing - MINIMAL_SAMPLE
    if beyond <= 0:
        return float(np.log10(max(tests, 1)))
    return float(np.log10(max(tests, 1)) + log10_binomial_tail(beyond, trials - MINIMAL_SAMPLE, min(chance, 1.0)))


def log10_binomial_tail(at_least: int, trials: int, p: float) -> float:
    """log10 P(X >= at_least) for X ~ Binomial(trials, p), at_least >= 1: the regularised
    incomplete beta I_p(at_least, trials - at_least + 1), which is what scipy.stats' binomial
    survival function evaluates (the same bits, without importing scipy.stats, which is slow). More
    than ``trials`` (greedy independent subsets can outnumber their superset's) has probability 0."""
    if at_least > trials:
        return float("-inf")
    with np.errstate(divide="ignore"):   # a tail below the smallest double is log 0: -inf
        return float(np.log(betainc(at_least, trials - at_least + 1, p)) / np.log(10))


def evidence(T: np.ndarray, overlap: tuple[np.ndarray, np.ndarray, np.ndarray], target_points: np.ndarray,
             target_neighbours: NeighbourGrid, match_source: np.ndarray, agree: np.ndarray, resolution: float,
             match_tolerance: float, descriptor_radius: float, hypotheses: int) -> Evidence:
    """The figures of the pose ``T``: ``overlap`` its (source keypoints, target keypoints, their
    normals) paired within tau_e; ``match_source`` the feature matches' source keypoints,
    ``agree`` which of them the pose brings within ``match_tolerance`` of their target;
    ``hypotheses`` how many poses the search compared."""
    agreement = surface_agreement(T, *overlap, resolution)
    matches = independent(match_source, descriptor_radius)
    agreeing = independent(match_source[agree], descriptor_radius)
    chance = chance_of_agreement(target_points, target_neighbours, match_tolerance)
    return Evidence(agreement, len(overlap[0]), len(matches), len(agreeing), chance,
                    log10_false_alarms(len(agreeing), len(matches), chance, hypotheses))
