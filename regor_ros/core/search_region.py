"""A relocalization hint: search only the part of the target the source can overlap.

Robots often know roughly where they are (an operator's "2D Pose Estimate", a localizer that
lost track). With the source frame's origin (the robot, or its sensor) believed within
``radius`` of ``centre`` in the target frame, only target keypoints within ``radius`` plus the
source's own reach around that point can match; the rest of the map is left out of the search,
and a pose that puts the origin outside the region (horizontally) is not accepted. Only the
position is used: the search stays global in orientation, which a hint often gets wrong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .cloud import PreparedCloud
from .errors import RegistrationError

REACH_PERCENTILE = 99


@dataclass
class SearchRegion:
    """Where the source frame's origin is believed to be, in the target frame."""

    centre: np.ndarray  # (3,) metres
    radius: float       # metres

    @classmethod
    def checked(cls, centre, radius) -> SearchRegion:
        """A region from user input; RegistrationError says what is wrong with it."""
        c = np.asarray(centre, dtype=np.float64)
        if c.shape != (3,) or not np.isfinite(c).all():
            raise RegistrationError(f"search region: centre must be three finite numbers, got {centre!r}")
        if not np.isfinite(radius) or radius < 0:
            raise RegistrationError(f"search region: radius must be a finite distance >= 0, got {radius!r}")
        return cls(c, float(radius))


def restrict(target: PreparedCloud, region: SearchRegion, source: PreparedCloud) -> PreparedCloud:
    """The target keypoints that the source can overlap from inside the region: within its radius
    plus the source's reach of the centre, with their own feature index: the cost follows the
    region, not the map. The reach is the REACH_PERCENTILE of the source keypoints' distances from
    its origin: a LiDAR's few farthest returns (often 2-3 times the rest) would otherwise widen
    the region to the whole map."""
    reach = float(np.percentile(np.linalg.norm(source.points, axis=1), REACH_PERCENTILE))
    keep = np.asarray(target.tree.query_ball_point(region.centre, region.radius + reach), dtype=np.int64)
    if len(keep) < target.config.min_points:
        raise RegistrationError(
            f"search region: only {len(keep)} target keypoints within {region.radius + reach:.1f} m of "
            f"({', '.join(f'{v:.1f}' for v in region.centre)}); is the hint in the target's frame?")
    keep.sort()
    points, features, config = target.points[keep], target.features[keep], target.config
    return PreparedCloud(points, target.normals[keep], features, cKDTree(points),
                         target.index.restricted(keep, features), config, target.input_size,
                         target.views, target.map_view, target.normals_toward_sensors, target.shake_bins,
                         target.ground_removed)
