"""The cloud model: raw points with the sensor positions they were seen from (SeenCloud), a cloud
prepared for registration (PreparedCloud: a static target, a map, is prepared once and reused for
every source), and the checks a raw cloud and a viewpoint pass before either is made.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from .errors import RegistrationError
from .geometry import transform_points

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

    from .config import FeatureConfig
    from .feature_index import FeatureIndex
    from .map_view import MapView
    from .neighbour_grid import NeighbourGrid
    from .range_image import RangeImage

# Coordinates beyond this are treated as garbage (float32 overflow, uninitialised buffers).
MAX_ABS_COORDINATE = 1e6


@dataclass
class PreparedCloud:
    """Keypoints (every voxel-downsampled point), their unit FPFH features, a kd-tree over the
    points, a search index over the features and (built when first asked) each keypoint's
    nearest neighbours within a threshold."""

    points: np.ndarray    # (N, 3) float64, metres
    normals: np.ndarray   # (N, 3) unit normals (for the pose covariance)
    features: np.ndarray  # (N, 33) float32, L2-normalised
    tree: cKDTree
    index: FeatureIndex
    config: FeatureConfig  # the settings it was prepared with
    input_size: int        # finite points in the raw cloud
    views: tuple[RangeImage, ...] = ()  # what its sensor saw from each known viewpoint
    map_view: MapView | None = None  # a cloud with no viewpoint (a map): seen from any position
    normals_toward_sensors: bool = False  # its normals face its sensors (else the solver's signs)
    shake_bins: int = 0   # its views are read this many bins wider: its scans' own disagreement (shake.py)
    ground_removed: bool = False  # its largest plane left its keypoints (features.ground_removed_between)

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def neighbours(self) -> NeighbourGrid:
        """The refinements' nearest-keypoint search (imported here: it loads the compiled kernels,
        which a cloud's checks do not need)."""
        from .neighbour_grid import NeighbourGrid
        return NeighbourGrid(self.points)

    @property
    def viewpoints(self) -> np.ndarray | None:
        """(k, 3) sensor positions in the cloud's frame, or None when unknown."""
        return np.array([v.viewpoint for v in self.views]) if self.views else None


@dataclass
class SeenCloud:
    """Raw points in one frame with the sensor positions they were seen from: one part per
    position (a scan; several for scans fused along odometry), or one part and no viewpoint (a
    map, an accumulated submap)."""

    parts: list[np.ndarray]              # (N_i, 3) each
    viewpoints: np.ndarray | None     # (len(parts), 3), or None when unknown

    @classmethod
    def single(cls, points, viewpoint: np.ndarray | None) -> SeenCloud:
        """One scan seen from ``viewpoint`` (None: unknown)."""
        return cls([points], None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(1, 3))

    @property
    def points(self) -> np.ndarray:
        """Every part's points in one array."""
        return np.vstack(self.parts)

    def moved(self, T: np.ndarray) -> SeenCloud:
        """The same cloud in another frame (``T`` maps this frame into it)."""
        return SeenCloud([transform_points(T, p) for p in self.parts],
                         None if self.viewpoints is None else transform_points(T, self.viewpoints))


def clean_points(xyz, name: str = "cloud") -> np.ndarray:
    """Validate a raw cloud and drop non-finite points; raise RegistrationError on bad input."""
    try:
        arr = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name}: not a numeric array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise RegistrationError(f"{name}: expected an (N, 3) array of x, y, z, got shape {arr.shape}")
    if len(arr) == 0:
        raise RegistrationError(f"{name}: the cloud is empty")
    finite = np.isfinite(arr).all(axis=1)
    sane = finite & (np.abs(arr) < MAX_ABS_COORDINATE).all(axis=1)
    if not sane.any():
        if finite.any():
            raise RegistrationError(f"{name}: every point has a coordinate beyond "
                                    f"{MAX_ABS_COORDINATE:g} m; is the unit metres?")
        raise RegistrationError(f"{name}: every point is NaN or infinite")
    return arr[sane]


def check_viewpoint(viewpoint, name: str) -> np.ndarray | None:
    """The sensor position as a (3,) array, or None when unknown; RegistrationError if malformed."""
    if viewpoint is None:
        return None
    try:
        vp = np.asarray(viewpoint, dtype=np.float64)
    except (TypeError, ValueError):
        raise RegistrationError(f"{name} viewpoint: expected (x, y, z) or None, got {viewpoint!r}") from None
    if vp.shape != (3,) or not np.isfinite(vp).all():
        raise RegistrationError(f"{name} viewpoint: expected three finite numbers (x, y, z) or None, "
                                f"got {viewpoint!r}")
    return vp
