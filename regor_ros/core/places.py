"""When two poses are one place of the search and when they are two answers.

Hypotheses closer than DISTINCT_ANGLE_DEG and DISTINCT_TRANSLATION_FRACTION inlier thresholds are
one candidate place (the refinement pulls one onto the other). A rival of a published pose is
another answer only when it puts the source elsewhere, by that same distance in RMS over the
source's points: a rival a dozen degrees off about the overlap, moving the source by a few
decimetres, is the same answer less well pinned, not a second one (and a pose's translation
alone depends on where the source's frame happens to be: a fragment's camera metres from the
overlap). numpy only: the gate's judge reads it, and the calibration loads the judge before any
kernel.
"""
from __future__ import annotations

import numpy as np

DISTINCT_ANGLE_DEG = 10.0
DISTINCT_TRANSLATION_FRACTION = 5.0  # of the inlier threshold


def another_answer(moved_tau, angle_deg):
    """Whether rivals that move the source by ``moved_tau`` inlier thresholds (RMS over its
    points) from where the pose puts it are other answers than the pose (arrays broadcast). A
    rival recorded without it (a CSV from before it was measured: NaN) is judged by its turn,
    DISTINCT_ANGLE_DEG, as it was then."""
    moved, angle = np.asarray(moved_tau, dtype=float), np.asarray(angle_deg, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(moved), angle >= DISTINCT_ANGLE_DEG, moved >= DISTINCT_TRANSLATION_FRACTION)
