"""How firmly do the surfaces pin the pose's position? A slide along repeated structure.

Shelves of books, a row of cabinets, a corridor's doors: surfaces that face every way but one.
Along that direction the position rests on the few surfaces that face it (the shelves' dividers),
and where those repeat, the pose slid by one repetition fits as well: every other check passes,
free space is not violated, the overlap lies on the surfaces and the features agree (3DMatch's
studyroom, normals facing the sensors: published poses slid along a bookshelf by one bay, each
with a hundred agreeing matches). The figure: the overlap's surface normals summed as n n^T, each
independent neighbourhood (one per descriptor radius, as the evidence counts) weighing one. Its
smallest eigenvalue is how many neighbourhoods' worth of surface face the direction the surfaces
pin least. Under one, not a single neighbourhood faces it: the position along it rests on slivers
of several, which one repeated structure imitates. A unit, not a fitted count.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .. import kernels
from ..geometry import transform_points
from .evidence import independent, on_surface


def weakest_support(T: np.ndarray, overlap: tuple, resolution: float, radius: float) -> tuple[float, np.ndarray]:
    """(neighbourhoods' worth of surface facing the least pinned direction, that direction in the
    target frame) for the pose ``T``: ``overlap`` its (source keypoints, target keypoints, their
    normals) paired within tau_e; only pairs on the target's surface at ``resolution`` count,
    grouped one neighbourhood per ``radius``. (0, no direction) when none is."""
    overlap_source, overlap_target, overlap_normals = overlap
    placed = transform_points(T, overlap_source)
    on = on_surface(placed, overlap_target, overlap_normals, resolution)
    if not on.any():
        return 0.0, np.zeros(3)
    points, normals = placed[on], overlap_normals[on]
    centres = points[independent(points, radius)]
    cell = cKDTree(centres).query(points, workers=kernels.threads())[1]
    weight = 1.0 / np.bincount(cell, minlength=len(centres))[cell]   # each neighbourhood weighs one
    eigenvalues, eigenvectors = np.linalg.eigh((normals * weight[:, None]).T @ normals)
    return float(max(eigenvalues[0], 0.0)), eigenvectors[:, 0]
