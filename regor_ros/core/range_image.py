"""What one sensor saw through: the seen free space as a spherical range image around the viewpoint
holding the nearest return per bin, the sensor model the visibility checks read.

It is read conservatively, so that a correct pose is not blamed for sensing artefacts:
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
from scipy.spatial import cKDTree

from . import kernels

MIN_RANGE = 1e-3  # points this close to the viewpoint have no direction [m]
MAX_SPLAT_BINS = 8  # a footprint wider than 17 bins (a point right by the viewpoint) is capped


@dataclass
class RangeImage:
    """Nearest return per (elevation, azimuth) bin seen from ``viewpoint``, read as free depth."""

    viewpoint: np.ndarray      # (3,) sensor position in the cloud's frame
    free_depth: np.ndarray     # (rows, cols) float32: empty up to this range; 0 = unknown
    resolution_deg: float
    max_range: float           # farthest return [m]

    @classmethod
    def build(cls, points: np.ndarray, viewpoint, resolution_deg: float, footprint: float = 0.0,
              max_range: float = np.inf, blur: int = 0) -> RangeImage:
        """From the returns ``points`` seen from ``viewpoint``. With ``footprint`` (the spacing of
        downsampled points, a map's) each point covers the bins its footprint subtends, so a
        near surface sampled coarsely still hides what lies behind it; returns beyond
        ``max_range`` are left out. ``blur`` reads each bin's free depth that many bins wider
        (the directions a shaking sequence's scans disagree by: shake.py)."""
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
        free = kernels.splatted_free_depth(index, ranges.astype(np.float32), width, rows, cols, int(blur))
        return cls(viewpoint, free, float(resolution_deg),
                   float(ranges.max()) if len(ranges) else 0.0)

    def violations(self, points: np.ndarray, margin: float, margin_ratio: float):
        """(points that land on seen bins, of those the ones inside seen free space)."""
        seen, inside = self.classify(points, margin, margin_ratio)
        return int(seen.sum()), int(inside.sum())

    def returns_along(self, points: np.ndarray) -> np.ndarray:
        """Where the sensor's return lies along each point's direction (its bin's free depth out
        from the viewpoint): what the sensor saw behind a point inside its free space. Points
        nearer than MIN_RANGE have no direction; give none."""
        offsets = np.asarray(points, dtype=np.float64) - self.viewpoint
        ranges, index = _bins(offsets, self.resolution_deg, self.free_depth.shape[1])
        depth = self.free_depth.ravel()[index].astype(np.float64)
        return self.viewpoint + offsets * (depth / ranges)[:, None]

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


def nearest_viewpoint(viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each of ``points``, the nearest of ``viewpoints`` (K, 3): the sensor that saw it, most
    likely (one viewpoint: that one, for every point)."""
    if len(viewpoints) == 1:
        return viewpoints[0]
    return viewpoints[cKDTree(viewpoints).query(points, workers=kernels.threads())[1]]
