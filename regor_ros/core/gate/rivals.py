"""The rivals of a pose, and how far the evidence prefers the pose to each.

A box-like room, a corridor or a road turned around passes every other check, and so can another
place that looks alike (a second room of the same hotel, the next bay of a shelf). Three families
of rival, each refined like the pose:
- the pose turned by 180 degrees about each principal axis of its overlap, through its centroid;
- the pose turned by a quarter, a half and three quarters about the direction most of the
  overlap's surfaces face (a floor, a wall): a box room repeats at quarter turns about it, about
  an axis that need not pass near the overlap (measured on the studyroom's turns: 1-2.5 deg from
  the true turn's axis, 0.4-1.9 m from the overlap's centre). Its translation is where the
  feature matches vote beyond chance under the turned rotation: at a symmetric place the matches
  that found the pose point to its twin as well, and the votes of unrelated matches, densest
  where the two clouds' middles meet, are counted out (they outvote a small overlap's few);
- the best RIVAL_PLACES other places the search itself found (initial.distinct_candidates): the
  runner-up of the search is the pose the features liked next, whatever made it look alike.

A rival counts when it is another answer (places.another_answer: it moves the source by the
search's distinct-place distance) and would pass on its own what any pose must (judge.rival_chances:
the visibility checks, the inlier, fitness and feature-match minimums). How far the pose
leads it is judged in independent units, not by a fitted ratio: the feature matches that agree with
one of the two and not the other, one per descriptor radius (evidence.independent); a match both
agree with says nothing about which is right (a rival a few degrees off shares most of them: the
two are then told apart, as in McNemar's test, by the matches only one explains). Were both poses
equally right, each such match would fall to either with even odds; the rival's ``lead_chance`` is
the probability that such a tie gives the pose at least its lead (a binomial tail). A large one
means the evidence cannot tell the two apart (gate/judge.py's ambiguity).
"""
from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from .. import kernels
from ..cloud import PreparedCloud
from ..config import RegorConfig
from ..estimate import PointRefinement, agreeing, point_refine, point_refine_all, resolution_uncertainty
from ..geometry import column_bounds, evenly_spaced, moved, to_matrix
from ..gravity import GravityPrior, clamp_of
from ..initial import same_place
from ..metrics import rotation_error_deg
from .evidence import independent, log10_binomial_tail
from .figures import RivalFigures
from .visibility import free_space_figures

RIVAL_POINTS = 1000   # evenly spaced source keypoints on which the pose and its rivals are compared
QUARTER_TURNS_DEG = (90.0, 180.0, 270.0)
CHANCE_PAIRINGS = 4   # random pairings of the matches that give a vote's background
RIVAL_PLACES = 3      # the search's best other places refined as rivals: the runner-ups it ranked
FACING_DEG = 15.0     # a surface faces the dominant direction when its normal is within this of it
FACING_ROUNDS = 5     # re-estimates of the dominant direction from the normals facing it
_NEIGHBOUR_CELLS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


def half_turns(points: np.ndarray) -> np.ndarray:
    """(3, 4, 4): turns by 180 degrees about each principal axis of ``points``, through their
    centroid: the symmetries of a box-like room, a corridor or a road."""
    centre = points.mean(axis=0)
    axes = np.linalg.svd(points - centre, full_matrices=False)[2]
    rotations = 2.0 * axes[:, :, None] * axes[:, None, :] - np.eye(3)
    return to_matrix(rotations, centre - rotations @ centre)


def dominant_direction(normals: np.ndarray) -> np.ndarray:
    """The direction most of these unit normals face, sign ignored: the scatter's main axis,
    then re-estimated from the normals within FACING_DEG of it (the other walls' normals would
    tilt it)."""
    axis = np.linalg.eigh(normals.T @ normals)[1][:, -1]
    for _ in range(FACING_ROUNDS):
        facing = normals[np.abs(normals @ axis) > np.cos(np.radians(FACING_DEG))]
        if len(facing) < 3:
            break
        axis = np.linalg.eigh(facing.T @ facing)[1][:, -1]
    return axis


@lru_cache(maxsize=4)
def _shuffles(n: int) -> np.ndarray:
    """CHANCE_PAIRINGS random orders of n matches, the same for every turn of a pose (seeded)."""
    shuffles = np.random.default_rng(0).permuted(np.tile(np.arange(n), (CHANCE_PAIRINGS, 1)), axis=1)
    shuffles.flags.writeable = False
    return shuffles


def voted_translation(rotation: np.ndarray, source: np.ndarray, target: np.ndarray, cell: float) -> np.ndarray:
    """The translation the matches (source[i], target[i]) agree on under ``rotation`` beyond
    chance: each match's translation binned at ``cell`` and pooled with its 26 neighbours; the bin
    whose votes most exceed what the same points paired at random cast there (CHANCE_PAIRINGS
    shuffles: the votes' background, densest where the clouds' centres line up, where it outvotes
    a small overlap's matches); the median of its votes."""
    turned = source @ rotation.T
    votes = target - turned
    background = (target[_shuffles(len(target))] - turned).reshape(-1, 3)
    keys = np.floor(np.vstack([votes, background]) / cell).astype(np.int64)
    low, high = column_bounds(keys)
    keys -= low - 1          # a free bin on every side, so neighbours do not wrap
    span = high - low + 3

    def linear(k):
        return (k[..., 0] * span[1] + k[..., 1]) * span[2] + k[..., 2]

    flat = linear(keys)
    own, chance = flat[:len(votes)], flat[len(votes):]
    offsets = linear(_NEIGHBOUR_CELLS) - linear(np.zeros(3, dtype=np.int64))
    counted = kernels.pooled_counts(own, own, offsets)

    def expected(count_of_chance):
        # a bin the shuffles left empty may hold one vote of chance: no bin wins on an empty background
        return (count_of_chance + 1) / CHANCE_PAIRINGS

    # the bin with most votes sets the bar: a bin whose votes would not pass it even on the
    # emptiest background is not looked up in the background (the same winner, for less)
    most = np.argmax(counted)
    bar = excess(counted[most], expected(np.isin(chance - own[most], offsets).sum()))
    scores = np.full(len(own), -np.inf)
    contenders = excess(counted, expected(0)) >= bar
    scores[contenders] = excess(counted[contenders],
                                expected(kernels.pooled_counts(own[contenders], chance, offsets)))
    best = own[np.argmax(scores)]
    return np.median(votes[np.isin(own - best, offsets)], axis=0)


def excess(counted: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """How far each count exceeds its Poisson mean ``expected`` (> 0): the likelihood ratio's
    statistic, 2 (k ln(k / mean) - (k - mean)), negative below the mean. It ranks as the tail's
    probability does without its underflow (a map's peaks are 10^-300 unlikely)."""
    k = counted.astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        statistic = 2.0 * (np.where(k > 0, k * np.log(k / expected), 0.0) - (k - expected))
    return np.where(k >= expected, statistic, -statistic)


def quarter_turns(T: np.ndarray, overlap_normals: np.ndarray, matches: tuple[np.ndarray, np.ndarray],
                  cell: float) -> np.ndarray:
    """(3, 4, 4): ``T`` turned by QUARTER_TURNS_DEG about the overlap's dominant surface direction,
    each at the translation the feature matches vote for beyond chance."""
    axis = dominant_direction(overlap_normals)
    turned = Rotation.from_rotvec(np.radians(QUARTER_TURNS_DEG)[:, None] * axis).as_matrix() @ T[:3, :3]
    return np.array([to_matrix(R, voted_translation(R, matches[0], matches[1], cell)) for R in turned])


def lead_chance(own: int, rival: int) -> float:
    """Probability that a tie (each of the own + rival independent matches that agree with only
    one of the poses falling to either with even odds) gives the pose at least ``own`` of them."""
    if own <= 0:
        return 1.0
    return float(10.0 ** log10_binomial_tail(own, own + rival, 0.5))


def rivals(T: np.ndarray, overlap: tuple, matches: tuple, places: list,
           source: PreparedCloud, target: PreparedCloud, config: RegorConfig, contends: Callable[[float], bool],
           refine: Callable[[np.ndarray], PointRefinement], prior: GravityPrior | None = None,
           against_chance=None) -> tuple[RivalFigures, np.ndarray]:
    """(the rivals' figures, their refined poses) of ``T``: ``overlap`` its (source keypoints,
    target keypoints, target normals) paired within tau_e, ``matches`` the feature matches
    (source points, target points, which of them agree with ``T``) and ``places`` the poses of
    the distinct places the search found, best first. Each is refined with the estimator's
    iterations (estimation.max_iterations: a place that falls back onto the pose must get there),
    and inliers are counted, on the same RIVAL_POINTS source keypoints (for speed). Under a
    gravity prior, a turn that tips the source over, or lifts its sensor out of the height band,
    is no rival (a road seen upside down). A rival that contends (``contends`` its lead chance: it
    may make the pose ambiguous) is then judged as the pose is: ``refine`` gives it the estimator's
    full refinement (every keypoint, planes, settled), its figures are taken again there, and its
    free space is read with the allowance a right pose has at this resolution, as the pose's is. A
    rival read more coarsely than the pose would lose to it on the coarseness alone. ``against_chance``
    gives log10 of the false alarms of a count of independent agreeing matches, as the pose's
    evidence counts them (None: not measured)."""
    _, final_target, target_normals = overlap
    if len(final_target) < 3:
        return RivalFigures.of([]), np.zeros((0, 4, 4))
    est, tau = config.estimation, config.initial.inlier_threshold
    radius = config.features.fpfh_radius
    sample = evenly_spaced(source.points, RIVAL_POINTS)

    def sample_inliers(pose: np.ndarray) -> int:
        return len(point_refine(pose, sample, target.neighbours, est.inlier_threshold, 0).source_index)

    own = sample_inliers(T)
    match_source, match_target, agree_with_T = matches
    own_matches = int(agree_with_T.sum())

    def agreement(pose: np.ndarray) -> tuple[np.ndarray, float]:
        agree = agreeing(pose, match_source, match_target, tau)
        return agree, lead_chance(len(independent(match_source[agree_with_T & ~agree], radius)),
                                  len(independent(match_source[agree & ~agree_with_T], radius)))

    others = [pose for pose in places if not same_place(pose, T, tau)][:RIVAL_PLACES]
    starts = np.concatenate([half_turns(final_target) @ T,
                             quarter_turns(T, target_normals, (match_source, match_target), tau),
                             np.reshape(others, (-1, 4, 4))])
    if prior is not None:
        starts = starts[prior.allows(starts, source, target)]
    rows, poses = [], []
    for refined in point_refine_all(starts, sample, target.neighbours, est.inlier_threshold, est.max_iterations,
                                    clamp_of(prior)):
        agree, chance = agreement(refined.transform)
        inliers, uncertainty = len(refined.source_index), None
        # free space is what costs (a map seen from the rival's place); a rival the pose clearly
        # leads makes nothing ambiguous whatever it shows, so it is neither refined further nor
        # measured, nor its own matches against chance
        worst = opposite = false_alarms = None
        if contends(chance):
            refined = refine(refined.transform)
            uncertainty = resolution_uncertainty(refined.transform, source.points[refined.source_index],
                                                 config.features.voxel_size)
            agree, chance = agreement(refined.transform)
            inliers = sample_inliers(refined.transform)
        if contends(chance):
            visibility = free_space_figures(refined.transform, source, target, config.acceptance,
                                            refined.target_index, uncertainty)
            worst, opposite = visibility.worst_free_space, visibility.opposite_sides
            if against_chance is not None:
                false_alarms = against_chance(len(independent(match_source[agree], radius)))
        rows.append((inliers / max(own, 1), int(agree.sum()) / max(own_matches, 1),
                     worst, opposite, rotation_error_deg(refined.transform, T), chance,
                     moved(refined.transform, T, sample) / tau, false_alarms))
        poses.append(refined.transform)
    return RivalFigures.of(rows), np.array(poses).reshape(-1, 4, 4)
