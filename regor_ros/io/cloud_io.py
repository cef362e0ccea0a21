"""Read point clouds from files: .ply, .pcd, .xyz/.txt, .npy and KITTI .bin, as (N, 3) float64."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core import MAX_ABS_COORDINATE, RegistrationError

FORMATS = (".ply", ".pcd", ".xyz", ".txt", ".npy", ".bin")
MIN_SANE_SHARE = 0.5   # a cloud file is mostly finite points within MAX_ABS_COORDINATE (organised ones have NaN holes)


class CloudFileError(RegistrationError):
    """A file that cannot be read as a point cloud; the message names the file and the reason."""


def _open3d(path: Path) -> np.ndarray:
    import open3d as o3d
    with open(path, "rb") as f:
        if not f.read(1):
            raise CloudFileError(f"{path}: the file is empty")
    # open3d's own warnings about a bad file would print before, and beside, the reason given here
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(str(path), format="auto",  # type: ignore[arg-type]  # (str: any open3d)
                                        print_progress=False)
    points = np.asarray(cloud.points, dtype=np.float64)
    if len(points) == 0:
        raise CloudFileError(f"{path}: no points could be read (not a valid {path.suffix} point cloud?)")
    return points


def _text(path: Path) -> np.ndarray:
    try:
        data = np.loadtxt(path, ndmin=2, comments=("#", "//"), delimiter=None)
    except ValueError as exc:
        raise CloudFileError(f"{path}: not a table of numbers ({exc})") from None
    if data.size == 0:
        raise CloudFileError(f"{path}: the file has no points")
    if data.shape[1] < 3:
        raise CloudFileError(f"{path}: rows have {data.shape[1]} columns, need x y z")
    return data[:, :3]


def _npy(path: Path) -> np.ndarray:
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        # numpy reads unknown bytes as a pickle and advises allow_pickle: never for a cloud
        why = "unrecognised contents" if "pickle" in str(exc) else str(exc)
        raise CloudFileError(f"{path}: not a numpy .npy array file ({why})") from None
    if data.ndim != 2 or data.shape[1] < 3:
        raise CloudFileError(f"{path}: array of shape {data.shape}, need (N, 3) or more columns")
    if len(data) == 0:
        raise CloudFileError(f"{path}: no points (an empty array)")
    try:
        return np.asarray(data[:, :3], dtype=np.float64)
    except (TypeError, ValueError):
        raise CloudFileError(f"{path}: an array of {data.dtype}, not numbers") from None


def _kitti_bin(path: Path) -> np.ndarray:
    raw = np.fromfile(path, dtype="<f4")
    if raw.size == 0 or raw.size % 4:
        raise CloudFileError(f"{path}: {raw.size * 4} bytes is not a whole number of KITTI points "
                             "(x, y, z, intensity as float32)")
    with np.errstate(invalid="ignore", over="ignore"):  # garbage bytes: NaN and inf, refused by the caller
        return raw.reshape(-1, 4)[:, :3].astype(np.float64)


READERS = {".ply": _open3d, ".pcd": _open3d, ".xyz": _text, ".txt": _text, ".npy": _npy,
           ".bin": _kitti_bin}


def read_cloud(path) -> np.ndarray:
    """(N, 3) points of a cloud file, chosen by extension; raises CloudFileError."""
    path = Path(path)
    reader = READERS.get(path.suffix.lower())
    if reader is None:
        raise CloudFileError(f"{path}: unknown format {path.suffix or '(no extension)'}; "
                             f"use one of {', '.join(FORMATS)}")
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
    points = reader(path)
    sane = sane_rows(points)
    if sane.mean() < MIN_SANE_SHARE:
        raise CloudFileError(f"{path}: {int((~sane).sum())} of {len(points)} points read are NaN, infinite or "
                             f"beyond {MAX_ABS_COORDINATE:g} m: not a point cloud (random bytes, another format?)")
    return points


def sane_rows(points: np.ndarray) -> np.ndarray:
    """Mask of the points that are finite and within MAX_ABS_COORDINATE (the rest: holes of an
    organised cloud, or garbage)."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(points).all(axis=1) & (np.abs(points) < MAX_ABS_COORDINATE).all(axis=1)
