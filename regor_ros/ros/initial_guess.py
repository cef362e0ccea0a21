"""The initial_guess input: a PoseWithCovarianceStamped (RViz's "2D Pose Estimate", a localizer's
estimate) turned into the core's search region."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped

from ..core import SearchRegion


def region_of_guess(msg: PoseWithCovarianceStamped, sigmas: float, min_radius: float,
                  max_radius: float) -> SearchRegion:
    """Centre at the hinted position; radius ``sigmas`` standard deviations of its least certain
    direction (from the position block of the covariance), within [min_radius, max_radius]. A
    covariance that is not a covariance (negative, NaN) counts as the widest radius."""
    p = msg.pose.pose.position
    position = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)[:3, :3]
    eigen = np.linalg.eigvalsh(0.5 * (position + position.T)) if np.isfinite(position).all() else None
    if eigen is None or eigen.min() < -1e-9:
        radius = max_radius
    else:
        radius = float(np.clip(sigmas * np.sqrt(max(eigen.max(), 0.0)), min_radius, max_radius))
    return SearchRegion.checked((p.x, p.y, p.z), radius)
