"""A map from another day: which of a scan's free-space conflicts with the map the world's change
explains.

A map is aggregated from scans taken before the one registered against it, often on another day:
leaves fall, snow lies, cars and doors move. Under a right pose, a surface that has since vanished
(foliage, a parked car) sits in space the scan now sees through, and the free-space check reads it
as surfaces passing through each other. What tells the two apart is what the scan saw *behind*
the conflict. Where the world changed, the scan's ray passes where the vanished surface was and
ends on a surface that is still there, which the map holds too (its sensors saw it from other
positions, or through a canopy's gaps). Under a wrong pose the ray ends wherever the scan's own
geometry puts it, on nothing the map holds, since the two clouds disagree there. So a conflict
counts against the pose only where the scan's return behind it lies on none of the map's surfaces.

"Lies on" is read at the map's keypoint spacing, the resolution its surfaces are known at. The
return is read from the conflicting point's bin, so at range it may lie a bin aside of where the
sensor measured it: a return the map holds may then read as not held, never the other way, and the
conflict counts. Only a map can have changed in this sense: two clouds registered as a pair are taken as seen at one
time, and their conflicts all count.
"""
from __future__ import annotations

import numpy as np

from ..geometry import transform_points
from ..map_view import MapView
from ..range_image import RangeImage


def unexplained_conflicts(images: tuple[RangeImage, ...], points: np.ndarray, margin: float, margin_ratio: float,
                          slack, world: MapView, T_world_scan: np.ndarray) -> tuple[int, int, int]:
    """(map ``points`` on a bin any of the scan's ``images`` has seen, of those the ones inside
    any image's free space, and of those the ones some image's return behind lies on none of
    ``world``'s surfaces): range_image.seen_and_inside, with the change the map explains left out.
    ``points`` and the images are in the scan's frame, ``T_world_scan`` takes it to the map's."""
    seen = np.zeros(len(points), dtype=bool)
    inside = np.zeros(len(points), dtype=bool)
    unexplained = np.zeros(len(points), dtype=bool)
    for image in images:
        on_bin, conflict = image.classify(points, margin, margin_ratio, slack)
        seen |= on_bin
        inside |= conflict
        if conflict.any():
            index = np.flatnonzero(conflict)
            behind = image.returns_along(points[index])
            held = world.holds(transform_points(T_world_scan, behind), world.footprint)
            unexplained[index[~held]] = True
    return int(seen.sum()), int(inside.sum()), int(unexplained.sum())
