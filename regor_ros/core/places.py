"""When two poses are one place of the search and when they are two.

Hypotheses closer than this are one candidate place (the refinement pulls one onto the other);
a rival refined to within it of a pose has fallen back onto the pose. numpy only: the gate's
judge reads it, and the calibration loads the judge before any kernel.
"""
from __future__ import annotations

import numpy as np

DISTINCT_ANGLE_DEG = 10.0
DISTINCT_TRANSLATION_FRACTION = 5.0  # of the inlier threshold


def distinct(angle_deg, offset_tau):
    """Whether poses ``angle_deg`` apart in rotation and ``offset_tau`` inlier thresholds apart in
    translation are two places (arrays broadcast; NaN, not measured, is not distinct)."""
    with np.errstate(invalid="ignore"):
        return (np.asarray(angle_deg) >= DISTINCT_ANGLE_DEG) | (np.asarray(offset_tau) >= DISTINCT_TRANSLATION_FRACTION)
