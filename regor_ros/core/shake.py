"""How far the scans of a fused sequence disagree with each other: the bins by which their free
space is read wider.

Scans fused along odometry each keep their viewpoint, and the free-space check sees through every
one of them. A shaking sensor's scans carry their own deskew and odometry error: a wall one scan
saw lands a degree or two beside where the next one saw it, and at every depth edge (a door, a
pole, the sky) in front of what that one saw through. Against a map, a right pose then fails the
check for the sequence's shake, not for its own error.

So the sequence's consistency is measured, never assumed: each older scan against the newest (the
scan whose pose is registered), as the check judges a pose: its keypoints in the newest's seen free
space, and the newest's in its own. A range image reads each bin's free depth as the nearest return
within one bin; read ``blur`` bins wider, a surface another scan puts a few bins aside is no longer
in front of it. The shake is the fewest extra bins at which no scan sees through another as the
judge reads free space (judge.Rules.sees_through), up to MAX_SHAKE_BINS; the sequence's views,
and the map seen from where the pose puts them, are then read that much wider. It depends on the
sequence alone, never on a pose, so a wrong pose cannot buy a looser check; a steady sequence
passes at once, and nothing changes for it.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import open3d as o3d

from .range_image import RangeImage

if TYPE_CHECKING:
    from .gate.judge import Rules

MAX_SHAKE_BINS = 6   # wider than this, a scan's free space says little: read at most this wide


def seen_views(parts: list[np.ndarray], viewpoints: np.ndarray, resolution_deg: float, voxel: float,
               rules: Rules | None) -> tuple[tuple[RangeImage, ...], int]:
    """(the range images of the scans ``parts``, oldest first, in one frame, each seen from its row
    of ``viewpoints``; the extra bins they are read with): the fewest at which no older scan and
    the newest see through each other under the judge's ``rules`` (without them, or for a single
    scan, none)."""
    def images(blur: int) -> tuple[RangeImage, ...]:
        return tuple(RangeImage.build(p, v, resolution_deg, blur=blur) for p, v in zip(parts, viewpoints, strict=True))

    if rules is None or len(parts) < 2:
        return images(0), 0
    keypoints = [np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel).points)
                 for p in parts]
    for blur in range(MAX_SHAKE_BINS):
        views = images(blur)
        if not any(_sees_through(views[k], keypoints[-1], rules) or _sees_through(views[-1], keypoints[k], rules)
                   for k in range(len(parts) - 1)):
            return views, blur
    return images(MAX_SHAKE_BINS), MAX_SHAKE_BINS


def _sees_through(image: RangeImage, points: np.ndarray, rules: Rules) -> bool:
    """Whether ``image``'s sensor saw through too many of ``points`` for the judge."""
    acceptance = rules.acceptance
    return rules.sees_through(*image.violations(points, acceptance.free_space_margin,
                                                acceptance.free_space_margin_ratio))
