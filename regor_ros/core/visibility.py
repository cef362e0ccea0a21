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
so that a correct pose is not blamed for sensing artefacts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .range_image import MIN_RANGE

GRAZING_COSINE = 0.2  # a surface seen more obliquely than this (78 deg) has no reliable side


@dataclass
class VisibilityFigures:
    """Fraction of the other cloud's keypoints inside each sensor's seen free space, and of the
    matched surface points seen from opposite sides (None when a viewpoint it needs is unknown or
    too few points count)."""

    source_violation: float | None  # target keypoints inside the source sensor's free space
    target_violation: float | None  # source keypoints inside the target sensor's free space
    opposite_sides: float | None = None  # matched points the two sensors saw from opposite sides
    source_seen: int = 0               # target keypoints that landed on the source's seen bins
    target_seen: int = 0
    map_seen: float | None = None   # against a map: fraction of the scan's keypoints on bins the map fills

    @property
    def both_sides(self) -> bool:
        """Each cloud was checked against the other sensor's free space."""
        return self.source_violation is not None and self.target_violation is not None

    @property
    def worst(self) -> float | None:
        """The larger free-space fraction (None when neither side is known)."""
        known = [v for v in (self.source_violation, self.target_violation) if v is not None]
        return max(known) if known else None

    def as_dict(self):
        return {"source_violation": self.source_violation, "target_violation": self.target_violation,
                "opposite_sides": self.opposite_sides, "source_seen": self.source_seen,
                "target_seen": self.target_seen, "map_seen": self.map_seen, "worst": self.worst,
                "both_sides": self.both_sides}


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
