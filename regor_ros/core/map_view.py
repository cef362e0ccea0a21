"""The map seen from a position: the free-space check's side for a cloud with no single viewpoint.

A map is aggregated along a trajectory, so no one sensor's range image records what was seen
through. Two views stand in for it:
- from the candidate sensor position: if the pose is right, the source sensor sits in the map's
  free space and sees the map's surfaces, so no source point may float in front of the nearest
  map surface in its direction (a wrong pose puts the scan's walls and cars into the map's
  streets and rooms, or the sensor inside a building it sees from within);
- from the map's own sensor poses near the candidate, when its trajectory is known: space those
  sensors really saw through.
The surfaces are the map voxel-downsampled with its ground kept; each point covers the bins its
voxel subtends, so a coarsely sampled near wall still hides what lies behind it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from . import kernels
from .range_image import RangeImage

TRAJECTORY_VIEWS = 3      # nearest map sensor poses whose views are used for one candidate
VIEW_SPACING = 5.0        # in voxels: sensor positions closer than this to a kept one see about the same
MAX_CACHED_VIEWS = 256    # trajectory views kept (about 0.26 MB each at 1 deg)


def thinned(positions: np.ndarray, spacing: float) -> np.ndarray:
    """The positions in order, dropping each one closer than ``spacing`` to the last kept."""
    kept: list[np.ndarray] = []
    for p in positions:
        if not kept or np.linalg.norm(p - kept[-1]) >= spacing:
            kept.append(p)
    return np.array(kept, dtype=np.float64).reshape(-1, 3)


def trajectory_positions(trajectory) -> np.ndarray:
    """(K, 3) sensor positions from (K, 3) positions or (K, 4, 4) poses (T_map_sensor)."""
    array = np.asarray(trajectory, dtype=np.float64)
    if array.ndim == 3 and array.shape[1:] == (4, 4):
        array = array[:, :3, 3]
    if array.ndim != 2 or array.shape[1] != 3 or not np.isfinite(array).all():
        raise ValueError(f"expected (K, 3) positions or (K, 4, 4) poses, got shape {array.shape}")
    return array


@dataclass
class MapView:
    """What a sensor would see of the map from any position."""

    surface: np.ndarray      # (M, 3) map points at the keypoints' voxel size, ground kept
    footprint: float         # their spacing [m]
    resolution_deg: float
    trajectory: np.ndarray   # (K, 3) the map's sensor positions, thinned; (0, 3) when unknown
    trajectory_tree: cKDTree | None  # over them; None when unknown
    _cache: dict[tuple[int, int], tuple[float, RangeImage]] = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, surface: np.ndarray, voxel: float, resolution_deg: float,
              trajectory: np.ndarray | None = None) -> MapView:
        """The map's surface at ``resolution_deg``, seen from its trajectory thinned to every few voxels."""
        positions = np.zeros((0, 3)) if trajectory is None else thinned(trajectory, VIEW_SPACING * voxel)
        return cls(surface, voxel, resolution_deg, positions,
                   cKDTree(positions) if len(positions) else None)

    @cached_property
    def surface_tree(self) -> cKDTree:
        """A kd-tree over the surface, built when first asked (only a pose that puts the map into a
        scan's free space needs it: gate/changed_world.py)."""
        return cKDTree(self.surface)

    def holds(self, points: np.ndarray, tolerance: float) -> np.ndarray:
        """Per point: whether the map's surface lies within ``tolerance`` [m] of it."""
        if not len(points):
            return np.zeros(0, dtype=bool)
        distance, _ = self.surface_tree.query(points, distance_upper_bound=tolerance, workers=kernels.threads())
        return distance <= tolerance

    def image(self, position: np.ndarray, reach: float, blur: int = 0) -> RangeImage:
        """The map seen from ``position`` out to ``reach``, read ``blur`` bins wider (RangeImage.build)."""
        near = kernels.within_any(self.surface, np.asarray(position, dtype=np.float64).reshape(1, 3),
                                  np.array([reach], dtype=np.float64))
        return RangeImage.build(self.surface[near], position, self.resolution_deg, self.footprint, reach, blur)

    def images(self, positions: np.ndarray, reach: float, blur: int = 0) -> list[RangeImage]:
        """The map seen from the candidate sensor positions (thinned as the trajectory is: scans
        fused along a slow walk see about the same), and from the map's own sensor poses nearest
        to them (up to TRAJECTORY_VIEWS each, within ``reach``); read ``blur`` bins wider for a
        shaking sequence's points (shake.py)."""
        images = [self.image(p, reach, blur) for p in thinned(positions, VIEW_SPACING * self.footprint)]
        if self.trajectory_tree is not None:
            k = min(TRAJECTORY_VIEWS, len(self.trajectory))
            distances, index = self.trajectory_tree.query(positions, k=k)
            chosen = np.unique(np.asarray(index).reshape(-1)[np.asarray(distances).reshape(-1) <= reach])
            images += [self._trajectory_image(int(i), reach, blur) for i in chosen]
        return images

    def _trajectory_image(self, i: int, reach: float, blur: int) -> RangeImage:
        cached = self._cache.get((i, blur))
        if cached is not None and cached[0] >= reach:
            return cached[1]
        if len(self._cache) >= MAX_CACHED_VIEWS:
            self._cache.pop(next(iter(self._cache)))
        image = self.image(self.trajectory[i], reach, blur)
        self._cache[(i, blur)] = (reach, image)
        return image
