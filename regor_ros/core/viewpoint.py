"""Where a cloud was seen from: the sensor's position in the cloud's frame, as users write it.

A viewpoint is a point in metres, or None when the cloud has no single one (aggregated along a
trajectory); RGB-D fragments and LiDAR scans in their sensor frames sit at the origin.
"""
from __future__ import annotations

from .geometry import parse_numbers

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
