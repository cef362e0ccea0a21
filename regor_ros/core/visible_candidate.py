"""Verification picks, not only rejects: another place the search found, when the first fails free space.

The search ranks its hypotheses by feature support, and at low overlap a wrong place often ranks
first: a pose that puts one cloud's walls into space the other sensor saw through. The search
also returns the other distinct places it found (initial.distinct_candidates), and the right one
is often among them: on 100 3DLoMatch pairs (normals facing the sensors) 12 of the 28 wrong
winners had the truth among their next eight places, refined, each time with little free space
violated (0.00-0.04) where the winner had 0.12-0.32. Each such place is refined as the estimator's
pose is, and the one that passes the free-space check with the most point-level inliers replaces
the winner; the whole gate then judges it as it would have judged the winner, so the pick adds
no way around any check.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .initial import same_place


def visible_candidate(T: np.ndarray, candidates: list, count: int, refine_all: Callable,
                      plausible: Callable[[np.ndarray], bool], inlier_threshold: float):
    """Of the first ``count`` ``candidates`` ([(pose, support)], best first) at another place than
    ``T`` (initial.same_place), each refined (``refine_all``: poses (b, 4, 4) -> their refinements,
    each with ``transform`` and ``source_index``; one batch, as the gate's rivals are refined), the
    one that is ``plausible`` with the most inliers; None when none is."""
    best = None
    others = [pose for pose, _ in candidates if not same_place(pose, T, inlier_threshold)][:count]
    for refined in refine_all(np.reshape(others, (-1, 4, 4))) if others else []:
        if same_place(refined.transform, T, inlier_threshold) or not plausible(refined.transform):
            continue
        if best is None or len(refined.source_index) > len(best.source_index):
            best = refined
    return best
