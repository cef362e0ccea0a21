"""Visibility consistency of a pose: what one sensor saw through must stay empty in the other
cloud, and a surface both sensors saw was seen from the same side.

Every cloud was seen from a sensor. Along each ray the sensor measured, the space in front of
the return is empty. Under a correct pose the other cloud's surfaces never sit in that space
(beyond noise); a wrong pose that aligns walls and floors of box-like rooms, or a road, puts
the other cloud's surfaces right inside the rooms and streets this sensor saw through. And
surfaces are opaque: a wrong pose that puts two rooms back to back on a shared wall leaves the
other cloud behind this one's walls, where free space cannot see it, but the matched wall is then
seen from opposite sides.

The seen free space each sensor contributes is a range image (range_image.py), read conservatively
so that a correct pose is not blamed for sensing artefacts; against a map, the conflicts the
world's change explains do not count (changed_world.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels
from ..cloud import PreparedCloud
from ..config import AcceptanceConfig
from ..geometry import transform_points
from ..range_image import MIN_RANGE, nearest_viewpoint, seen_and_inside
from .changed_world import unexplained_conflicts
from .figures import NOT_MEASURED, Figures

GRAZING_COSINE = 0.2  # a surface seen more obliquely than this (78 deg) has no reliable side


@dataclass
class VisibilityFigures:
    """Fraction of the other cloud's keypoints inside each sensor's seen free space, and of the
    matched surface points seen from opposite sides (None when a viewpoint it needs is unknown or
    too few points count)."""

    free_space_source: float | None  # target keypoints inside the source sensor's free space
    free_space_target: float | None  # source keypoints inside the target sensor's free space
    opposite_sides: float | None = None  # matched points the two sensors saw from opposite sides
    source_seen: int = 0               # target keypoints that landed on the source's seen bins
    target_seen: int = 0
    map_seen: float | None = None   # against a map: fraction of the scan's keypoints on bins the map fills
    shake_bins: int = 0             # a fused sequence's views were read this many bins wider (shake.py)
    map_changed: float | None = None  # against a map: fraction of the map's keypoints the scan saw in its free
    #                                  space, but where the scan saw the map's surfaces behind (changed_world.py)

    def as_figures(self) -> dict:
        """The figures the judge reads (gate/figures.py's names; NaN: not measured)."""
        def measured(value):
            return NOT_MEASURED if value is None else float(value)
        return {"free_space_source": measured(self.free_space_source),
                "free_space_target": measured(self.free_space_target),
                "opposite_sides": measured(self.opposite_sides)}


def _fraction(seen: int, inside: int, min_seen: int) -> float | None:
    return inside / seen if seen >= min_seen else None


def opposite_sides(sensor_a: np.ndarray, sensor_b: np.ndarray, points: np.ndarray,
                   normals: np.ndarray, min_seen: int) -> float | None:
    """Fraction of surface points (with unoriented normals) that the two sensors, in the points'
    frame, see from opposite sides; views at grazing angles do not count. A sensor is a (3,)
    position or one (N, 3) position per point."""
    to_a, to_b = sensor_a - points, sensor_b - points
    cos_a = (to_a * normals).sum(axis=1) / np.maximum(np.linalg.norm(to_a, axis=1), MIN_RANGE)
    cos_b = (to_b * normals).sum(axis=1) / np.maximum(np.linalg.norm(to_b, axis=1), MIN_RANGE)
    clear = (np.abs(cos_a) > GRAZING_COSINE) & (np.abs(cos_b) > GRAZING_COSINE)
    return _fraction(int(clear.sum()), int((clear & (cos_a * cos_b < 0)).sum()), min_seen)


def pose_slack(uncertainty: tuple[float, float] | None, sigmas: float):
    """How far the pose may misplace a point at distance r from the source's origin, as a
    function of r: ``sigmas`` standard deviations of ``uncertainty`` (translation [m], turn
    [rad]) as sigma_t + r sigma_turn (None: no allowance)."""
    if uncertainty is None or sigmas <= 0:
        return None
    translation, turn = uncertainty
    return lambda r: sigmas * (translation + turn * r)


def visibility_figures(T: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                       acceptance: AcceptanceConfig, matched_index: np.ndarray | None = None,
                       uncertainty: tuple[float, float] | None = None) -> VisibilityFigures:
    """The visibility figures of T_target_source; ``matched_index`` lists the target keypoints of
    its inlier pairs. Each side is a cloud's sensors (their range images), or, for a cloud with no
    viewpoint (a map), the map seen from the other cloud's sensors placed by the pose. With the
    pose's ``uncertainty`` (estimate.resolution_uncertainty) each point's free-space margin grows
    by it there (acceptance.free_space_sigmas)."""
    T_inv = np.linalg.inv(T)
    slack = pose_slack(uncertainty, acceptance.free_space_sigmas)
    source_side = _side(T_inv, source, target, acceptance, near_only=True, slack=slack)
    target_side = _side(T, target, source, acceptance, near_only=False, slack=slack)
    sides = None
    if (matched_index is not None and source.viewpoints is not None and target.viewpoints is not None
            and source.views and target.views):
        points, normals = target.points[matched_index], target.normals[matched_index]
        sides = opposite_sides(nearest_viewpoint(target.viewpoints, points),
                               nearest_viewpoint(transform_points(T, source.viewpoints), points),
                               points, normals, acceptance.free_space_min_seen)
    return VisibilityFigures(source_side[0], target_side[0], sides, source_side[1], target_side[1],
                             source_side[2] if source.map_view is not None else target_side[2],
                             max(source.shake_bins, target.shake_bins),
                             source_side[3] if target.map_view is not None else target_side[3])


def _side(T_seer_other: np.ndarray, seer: PreparedCloud, other: PreparedCloud, acceptance: AcceptanceConfig,
          near_only: bool, slack=None):
    """(fraction of ``other``'s keypoints inside ``seer``'s seen free space or None, how many
    landed on seen bins, fraction of them seen: for a map side, fraction inside that the world's
    change explains: when ``other`` is a map, changed_world.py). ``near_only``: test only the
    other's keypoints within the seer's sensor range (the other may be a large map). ``slack``
    (pose_slack) widens each point's margin by its distance from the source's origin."""
    margin, ratio = acceptance.free_space_margin, acceptance.free_space_margin_ratio
    min_seen = acceptance.free_space_min_seen
    # the source frame's origin in the seer's frame: the seer is the source when near_only
    source_origin = np.zeros(3) if near_only else T_seer_other[:3, 3]

    def widen(points: np.ndarray):
        return 0.0 if slack is None else slack(np.linalg.norm(points - source_origin, axis=1))

    if seer.views and seer.viewpoints is not None:
        points = other.points
        if near_only:
            reach = np.array([view.max_range for view in seer.views]) + margin
            points = other.points[kernels.within_any(other.points, transform_points(
                np.linalg.inv(T_seer_other), seer.viewpoints), reach)]
        points = transform_points(T_seer_other, points)
        if other.map_view is None:
            seen, inside = seen_and_inside(seer.views, points, margin, ratio, widen(points))
            return _fraction(seen, inside, min_seen), seen, None, None
        seen, inside, unexplained = unexplained_conflicts(seer.views, points, margin, ratio, widen(points),
                                                          other.map_view, np.linalg.inv(T_seer_other))
        if seen < min_seen:
            return None, seen, None, None
        return unexplained / seen, seen, None, (inside - unexplained) / seen
    if seer.map_view is not None and other.views and other.viewpoints is not None:
        # the map seen from where the pose puts the other cloud's sensors, out to their reach
        points = transform_points(T_seer_other, other.points)
        out_to = max(view.max_range for view in other.views) + margin
        images = seer.map_view.images(transform_points(T_seer_other, other.viewpoints), out_to, other.shake_bins)
        seen, inside = seen_and_inside(images, points, margin, ratio, widen(points))
        fraction_seen = seen / max(len(points), 1)
        counts = seen >= min_seen and fraction_seen >= acceptance.map_view_min_seen
        return (inside / seen if counts else None), seen, fraction_seen, None
    return None, 0, None, None


def free_space_figures(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, acceptance: AcceptanceConfig,
                       matched_index: np.ndarray | None = None,
                       uncertainty: tuple[float, float] | None = None) -> Figures:
    """The pose's visibility figures alone (every other figure not measured): what the judge's
    free-space checks read of a pose nobody measured further (FS-TCD's hypotheses, the search's
    other places: read without an uncertainty; a contending rival: with its own)."""
    return Figures(num_inliers=NOT_MEASURED, fitness=NOT_MEASURED, surface_agreement=NOT_MEASURED,
                   log10_false_alarms=NOT_MEASURED, independent_agreeing=NOT_MEASURED, feature_inliers=NOT_MEASURED,
                   **visibility_figures(T, source, target, acceptance, matched_index, uncertainty).as_figures())
