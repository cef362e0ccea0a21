"""Visibility consistency of a pose: what one sensor saw through must stay empty in the other
cloud, and a surface both sensors saw was seen from the same side.

Every cloud was seen from a sensor. Along each ray the sensor measured, the space in front of
the return is empty. Under a correct pose the other cloud's surfaces never sit in that space
(beyond noise); a wrong pose that aligns walls and floors of box-like rooms, or a road, puts
the other cloud's surfaces right inside the rooms and streets this sensor saw through. And
surfaces are opaque: a wrong pose that puts two rooms back to back on a shared wall leaves the
other cloud behind this one's walls, where free space cannot see it, but the matched wall is then
seen from opposite sides.

The seen free space is a spherical range image around the viewpoint holding the nearest return
per bin. It is read conservatively, so that a correct pose is not blamed for sensing artefacts:
- a bin's free depth is the nearest return among it and its 8 neighbours, so a point that falls
  near a depth edge (foreground object, door frame) is measured against the nearer surface;
- a bin with no return is unknown, never free (glass, black surfaces, sky, beyond range);
- a point is in free space only when it is nearer than the free depth by a margin that grows with
  range (``margin + margin_ratio * depth``): keypoints are voxel centroids and depth noise grows
  with distance;
- and by the pose's own uncertainty at that point (``slack``): a pose known to within a degree
  places a point 30 m out half a metre off, so a correct pose is not blamed for its own error.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .geometry import parse_numbers

MIN_RANGE = 1e-3  # points this close to the viewpoint have no direction [m]
MAX_SPLAT_BINS = 8  # a footprint wider than 17 bins (a point right by the viewpoint) is capped
GRAZING_COSINE = 0.2  # a surface seen more obliquely than this (78 deg) has no reliable side
ORIGIN = (0.0, 0.0, 0.0)


def parse_viewpoint(text: str, name: str, auto=ORIGIN):
    """A viewpoint written by a user: 'auto' -> ``auto``, 'none' -> None (unknown), 'x, y, z' ->
    a tuple in metres; ConfigError otherwise."""
    word = str(text).strip().lower()
    if word == "auto":
        return auto
    if word == "none":
        return None
    return tuple(parse_numbers(word, 3, name, "'x, y, z' in metres, 'none' (unknown) or 'auto'"))


@dataclass
class RangeImage:
    """Nearest return per (elevation, azimuth) bin seen from ``viewpoint``, read as free depth."""

    viewpoint: np.ndarray      # (3,) sensor position in the cloud's frame
    free_depth: np.ndarray     # (rows, cols) float32: empty up to this range; 0 = unknown
    resolution_deg: float
    max_range: float           # farthest return [m]

    @classmethod
    def build(cls, points: np.ndarray, viewpoint, resolution_deg: float, footprint: float = 0.0,
              max_range: float = np.inf) -> RangeImage:
        """From the returns ``points`` seen from ``viewpoint``. With ``footprint`` (the spacing of
        downsampled points, a map's) each point covers the bins its footprint subtends, so a
        near surface sampled coarsely still hides what lies behind it; returns beyond
        ``max_range`` are left out."""
        viewpoint = np.asarray(viewpoint, dtype=np.float64).reshape(3)
        rows, cols = _shape(resolution_deg)
        ranges, index = _bins(points - viewpoint, resolution_deg, cols)
        near = ranges <= max_range
        ranges, index = ranges[near], index[near]
        # half-width in bins of each point's footprint; the 3x3 neighbourhood covers one bin
        width = np.ones(len(ranges), dtype=np.int64)
        if footprint > 0 and len(ranges):
            half = np.arctan(0.5 * footprint / np.maximum(ranges, MIN_RANGE))
            width = np.clip(np.ceil(half / np.radians(resolution_deg)).astype(np.int64), 1, MAX_SPLAT_BINS)
        # a point covers its footprint's bins; its free depth is read one bin wider (depth edges:
        # the nearer surface counts); a bin with no return is unknown, never free
        free = kernels.splatted_free_depth(index, ranges.astype(np.float32), width, rows, cols)
        return cls(viewpoint, free, float(resolution_deg),
                   float(ranges.max()) if len(ranges) else 0.0)

    def violations(self, points: np.ndarray, margin: float, margin_ratio: float):
        """(points that land on seen bins, of those the ones inside seen free space)."""
        seen, inside = self.classify(points, margin, margin_ratio)
        return int(seen.sum()), int(inside.sum())

    def classify(self, points: np.ndarray, margin: float, margin_ratio: float, slack=0.0):
        """Per point: (lands on a seen bin, lies inside seen free space); ``slack`` (a number or
        one per point) widens the margin by how far the pose may have misplaced each point."""
        # a writable array of its own: a read-only one (a broadcast view) is another type to the
        # compiled kernel, compiled afresh on the first registration
        slack = np.full(len(points), slack, dtype=np.float64) if np.ndim(slack) == 0 \
            else np.ascontiguousarray(slack, dtype=np.float64)
        return kernels.free_space_classes(np.ascontiguousarray(points, dtype=np.float64),
                                          np.asarray(self.viewpoint, dtype=np.float64),
                                          np.ascontiguousarray(self.free_depth, dtype=np.float32),
                                          float(np.radians(self.resolution_deg)), MIN_RANGE,
                                          float(margin), float(margin_ratio), slack)


def seen_and_inside(images, points: np.ndarray, margin: float, margin_ratio: float, slack=0.0):
    """(points on a bin any image has seen, of those the ones inside any image's free space): a
    cloud seen from several viewpoints (scans fused along odometry, a map's trajectory)."""
    seen, inside = np.zeros(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
    for image in images:
        s, i = image.classify(points, margin, margin_ratio, slack)
        seen |= s
        inside |= i
    return int(seen.sum()), int(inside.sum())


def _shape(resolution_deg: float):
    step = np.radians(resolution_deg)
    return int(np.ceil(np.pi / step)) + 1, int(np.ceil(2 * np.pi / step))


def _bins(offsets: np.ndarray, resolution_deg: float, cols: int):
    """Ranges and flat bin indices of points given relative to the viewpoint (too-close ones dropped)."""
    return kernels.spherical_bins(np.ascontiguousarray(offsets, dtype=np.float64),
                                  float(np.radians(resolution_deg)), int(cols), MIN_RANGE)


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
