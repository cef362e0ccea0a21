"""A robot's map from files: the cloud, the sensor poses it was built from, and its prepared cache.

Localizers load their map from a path (hdl_global_localization, lidar_localization_ros2); SLAM
packages save the map as a point cloud and their trajectory in TUM format. The map is prepared
once and the result cached in a cache folder ($XDG_CACHE_HOME/regor_ros), one file for each map,
trajectory and feature settings, so the next start loads it instead of preparing it again.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import PRESETS, PreparedCloud, RegorConfig, prepare_cloud, to_matrix
from .cloud_io import CloudFileError, read_cloud, sane_rows
from .map_cache import CacheError, file_digest, load_map, map_key, save_map

CACHE_SUFFIX = ".regor-cache.npz"
SURFACE_SAMPLE = 3000   # keypoints whose neighbourhoods decide whether the map is made of surfaces


def default_cache_dir() -> Path:
    """Where caches go unless map_cache_dir says otherwise (XDG cache home)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "regor_ros"


def read_trajectory(path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (K,), poses (K, 4, 4)) of a TUM trajectory: ``t tx ty tz qx qy qz qw`` per line
    (Hamilton quaternion, scalar last), ``#`` comments; raises CloudFileError."""
    path = Path(path)
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except ValueError as exc:
        raise CloudFileError(f"{path}: not a TUM trajectory (t x y z qx qy qz qw per line): {exc}") from None
    return trajectory_of_rows(rows, path)


def trajectory_of_rows(rows: np.ndarray, where) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, poses) of rows ``t x y z qx qy qz qw``, or a CloudFileError naming ``where`` (the
    file they came from) and the row that is not a pose."""
    if rows.ndim != 2 or rows.shape[0] == 0 or rows.shape[1] != 8 or not np.isfinite(rows).all():
        raise CloudFileError(f"{where}: expected rows of 8 numbers (t x y z qx qy qz qw), got shape {rows.shape}")
    norms = np.linalg.norm(rows[:, 4:8], axis=1)
    if (norms < 1e-6).any():
        raise CloudFileError(f"{where}: line {int(np.argmax(norms < 1e-6)) + 1} has a zero quaternion")
    rotations = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    poses = np.array([to_matrix(R, t) for R, t in zip(rotations, rows[:, 1:4], strict=True)])
    return rows[:, 0], poses


def write_trajectory(path, poses: np.ndarray, stamps: np.ndarray | None = None) -> None:
    """Write (K, 4, 4) poses as a TUM trajectory (stamps 0..K-1 unless given)."""
    stamps = np.arange(len(poses), dtype=np.float64) if stamps is None else stamps
    quaternions = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    np.savetxt(path, np.column_stack([stamps, poses[:, :3, 3], quaternions]), fmt="%.9f",
               header="t x y z qx qy qz qw")


def cache_file(map_file: Path, key: str, cache_dir: Path | None) -> Path:
    """Where the prepared map for ``key`` (map_cache.map_key: the map's and trajectory's content
    and the feature settings) is cached: one file a key in the cache folder, never beside the
    user's map, so runs with other settings keep their own and none rewrites another's."""
    return (cache_dir or default_cache_dir()) / f"{map_file.stem}-{key[:16]}{CACHE_SUFFIX}"


def read_map(map_file: Path) -> np.ndarray:
    """The points of a map file, or a CloudFileError saying why they are not plausibly a map:
    mostly garbage (random bytes, a wrong format) or a trajectory (TUM rows). Whether they form
    surfaces is asked of the prepared map (check_surfaces)."""
    points = read_cloud(map_file)   # refuses a file of mostly NaN, infinite or far points
    if map_file.suffix.lower() in (".txt", ".xyz") and _is_trajectory(map_file):
        raise CloudFileError(f"{map_file}: rows of t x y z qx qy qz qw: a TUM trajectory, not a map "
                             "(give it as map_trajectory_file)")
    return points[sane_rows(points)]


def _is_trajectory(path: Path) -> bool:
    try:
        rows = np.loadtxt(path, ndmin=2, comments=("#", "//"))
    except ValueError:
        return False
    return rows.shape[1] == 8 and bool(np.allclose(np.linalg.norm(rows[:, 4:8], axis=1), 1.0, atol=1e-3))


def check_surfaces(prepared: PreparedCloud, map_file: Path) -> None:
    """A CloudFileError unless the prepared map's keypoints form surfaces at the feature scale: a
    normal, and so a feature, needs a surface around the keypoint; a path or scattered points
    have none (nor a map in the wrong units). Asked of the keypoints and their kd-tree, which
    preparation built anyway."""
    features = prepared.config
    rng = np.random.default_rng(0)
    sample = prepared.points[rng.choice(len(prepared), min(SURFACE_SAMPLE, len(prepared)), replace=False)]
    neighbours = float(np.median(prepared.tree.query_ball_point(sample, features.normal_radius,
                                                                return_length=True) - 1))
    line = 2.0 * np.floor(features.normal_radius / features.voxel_size)  # a line sampled at the voxel size
    if neighbours <= line:
        raise CloudFileError(
            f"{map_file}: {prepared.input_size} points whose keypoints have a median of {neighbours:g} neighbours "
            f"within features.normal_radius={features.normal_radius} m; a line gives {line:g} and a surface more: "
            "not a map of surfaces (a path, scattered points, or the wrong units?)" + _scale_hint(prepared, sample))


def _scale_hint(prepared: PreparedCloud, sample: np.ndarray) -> str:
    """Which preset's scale fits a map too sparse for the one in use: the finest whose voxel is at
    least the map's point spacing (the median distance between neighbouring keypoints), so that
    its keypoints have neighbours on their surface."""
    spacing = float(np.median(prepared.tree.query(sample, k=2)[0][:, 1]))
    voxels = sorted((RegorConfig.preset(p).features.voxel_size, p) for p in PRESETS)
    fits = [(voxel, name) for voxel, name in voxels if voxel >= spacing]
    in_use = prepared.config.voxel_size
    if fits and fits[0][0] > in_use:
        return (f"; its points are about {spacing:.3g} m apart: the {fits[0][1]} preset's scale fits "
                f"(features.voxel_size={fits[0][0]:g} m)")
    if not fits:
        return f"; its points are about {spacing:.3g} m apart: try features.voxel_size of at least that"
    return ""


@dataclass
class MapFromFile:
    prepared: PreparedCloud
    info: dict[str, Any] = field(default_factory=dict)  # for status: the files and what the cache did


def load_map_file(map_file, config: RegorConfig, trajectory_file=None, cache: bool = True,
                  cache_dir=None, warn: Callable[[str], None] = print) -> MapFromFile:
    """The prepared map of ``map_file`` (any format read_cloud reads), from its cache when one
    matches the file, the trajectory and the feature settings (cache_file); otherwise prepared and
    cached. An unreadable cache is rebuilt with a warning. Raises RegistrationError (a
    CloudFileError for files, and for a file that is not plausibly a map: read_map,
    check_surfaces) with a message a user can act on."""
    map_file = Path(map_file).expanduser()
    trajectory_file = Path(trajectory_file).expanduser() if trajectory_file else None
    for path in (map_file, trajectory_file):
        if path is not None and not path.is_file():
            raise CloudFileError(f"{path}: no such file")
    info: dict[str, Any] = {"map_file": str(map_file), "map_trajectory_file": str(trajectory_file or "")}
    path = None
    if cache:
        key = map_key(file_digest(map_file), file_digest(trajectory_file), config.features)
        path = cache_file(map_file, key, Path(cache_dir).expanduser() if cache_dir else None)
        if path.is_file():
            try:
                prepared = load_map(path, key, config.features)
            except CacheError as exc:
                warn(f"map cache not used, the map is prepared again: {exc}")
            else:
                info.update(map_cache="loaded", map_cache_file=str(path), map_cache_bytes=path.stat().st_size)
                return MapFromFile(prepared, info)
    points = read_map(map_file)
    trajectory = read_trajectory(trajectory_file)[1] if trajectory_file else None
    prepared = prepare_cloud(points, config, "map", trajectory=trajectory)
    del points   # the raw map: not needed while the cache is written
    check_surfaces(prepared, map_file)   # a map refused writes nothing
    info["map_cache"] = "off"
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            size = save_map(prepared, path, key)
        except OSError as exc:
            warn(f"map cache not written to {path}: {exc}")
            info["map_cache"] = "not written"
        else:
            info.update(map_cache="built", map_cache_file=str(path), map_cache_bytes=size)
    return MapFromFile(prepared, info)

