"""Rigid transforms as 4x4 matrices, and the text forms users write them in.

Every layer moves points and composes poses; this is the one place those helpers live, with the
one parser of the 'x y z ...' strings that parameters, the command line and files use.
"""
from __future__ import annotations

import numpy as np

from .errors import ConfigError


def to_matrix(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Stack (..., 3, 3) rotations and (..., 3) translations into (..., 4, 4) transforms."""
    T = np.zeros(rotation.shape[:-2] + (4, 4))
    T[..., :3, :3] = rotation
    T[..., :3, 3] = translation
    T[..., 3, 3] = 1.0
    return T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) points mapped by the 4x4 transform T."""
    return points @ T[:3, :3].T + T[:3, 3]


def moved(A: np.ndarray, B: np.ndarray, points: np.ndarray) -> float:
    """How far pose ``A`` puts ``points`` (source frame) from where pose ``B`` does: the RMS
    distance, which does not depend on where the source's frame is."""
    apart = transform_points(A, points) - transform_points(B, points)
    return float(np.sqrt(np.mean(np.sum(apart ** 2, axis=1))))


def evenly_spaced(points: np.ndarray, count: int) -> np.ndarray:
    """At most ``count`` of ``points``, evenly spaced through their order (a cheap, deterministic
    subsample for refinements that only need to represent the cloud)."""
    return points[np.unique(np.linspace(0, len(points) - 1, count).astype(np.int64))]


def column_bounds(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(each column's minimum, each column's maximum) of a non-empty (N, D) array: what
    min(axis=0) and max(axis=0) give, column by column, which numpy does an order faster on a
    tall narrow array (points, bins) than along its first axis."""
    columns = values.T
    return (np.array([column.min() for column in columns], dtype=values.dtype),
            np.array([column.max() for column in columns], dtype=values.dtype))


def unique_rows(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique rows of the integer array ``values``, the index of each one's first occurrence),
    rows in lexicographic order: np.unique(values, axis=0, return_index=True), which sorts
    structured rows, from the rows packed into one integer each (mixed radix over the columns'
    ranges, which keeps their order), which is faster."""
    if len(values) == 0:
        return values, np.zeros(0, np.int64)
    low, high = column_bounds(values)
    spans = high - low + 1
    if np.prod(spans.astype(np.float64)) >= 2.0 ** 62:
        return np.unique(values, axis=0, return_index=True)
    packed = np.zeros(len(values), np.int64)
    for column, span in zip((values - low).T, spans, strict=True):
        packed = packed * np.int64(span) + column
    _, first = np.unique(packed, return_index=True)
    return values[first], first


def attached_pose(T: np.ndarray, covariance: np.ndarray, T_frame_other: np.ndarray):
    """(pose, covariance) of a frame rigidly attached to the one ``T`` places (``T_frame_other``:
    its pose there, the robot base seen from the sensor). The covariance is over small motions in
    the target frame's axes about each pose's own position (pose_covariance's convention), so a
    turn of the sensor by dtheta also moves the other frame by dtheta x r, r being the lever
    arm between them."""
    moved = T @ T_frame_other
    lever = moved[:3, 3] - T[:3, 3]
    J = np.eye(6)
    J[:3, 3:] = -np.array([[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]])
    return moved, J @ covariance @ J.T


def parse_numbers(text: str, count: int, name: str, what: str) -> np.ndarray:
    """The ``count`` finite numbers written in ``text`` (separated by spaces or commas, brackets
    ignored); ConfigError naming the parameter ``name`` and ``what`` to give otherwise."""
    try:
        values = [float(v) for v in str(text).replace("[", " ").replace("]", " ").replace(",", " ").split()]
    except ValueError:
        values = []
    if len(values) != count or not np.isfinite(values).all():
        raise ConfigError(f"{name}={text!r}: give {what}")
    return np.asarray(values, dtype=np.float64)
