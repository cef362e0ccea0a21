"""The scans a robot received and its odometry: which to fuse with the newest one, and where each was.

Odometry is accurate over a short stretch, so only the latest scans are fused: at most
``scans`` of them, none older than ``max_age`` and none whose sensor was farther than
``max_distance`` (by odometry) from the newest one's. A scan is placed by the odometry at its
stamp, interpolated between the two messages around it, or the nearest message within
``tolerance``; a scan with no odometry near its stamp is not fused (it is counted, so a user
sees why fewer scans were fused). Stamps decide, not arrival order: a lidar-inertial odometry
publishes a scan's pose after it has processed the scan, so the caller waits for odometry that
``covers`` the newest scan's stamp before asking for the sequence (the node for a bounded time,
a replay by reading ahead in the recording).

When the newest scan is registered alone, ``info["alone"]`` says why, as one of ALONE_REASONS
(counted by kind, so a user sees which to fix), and ``info["reason"]`` with the figures.
"""
from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .sequence import ScanSequence
from .viewpoint import ORIGIN

ODOMETRY_SECONDS = 60.0  # odometry kept: more than any accumulation window

# why the newest scan was registered alone, by kind
NO_ODOMETRY = "no odometry received"
ODOMETRY_BEHIND = "no odometry at or after the scan's stamp"     # late past the wait, or stopped
ODOMETRY_AHEAD = "the scan is older than the odometry kept"
ODOMETRY_GAP = "a gap in the odometry at the scan's stamp"
NOTHING_TO_FUSE = "no earlier scan to fuse"                        # the first, or all too old
MOVED_TOO_FAR = "the scan before it is beyond accumulate_max_distance"
ALONE_REASONS = (NO_ODOMETRY, ODOMETRY_BEHIND, ODOMETRY_AHEAD, ODOMETRY_GAP, NOTHING_TO_FUSE, MOVED_TOO_FAR)


@dataclass
class AccumulationLimits:
    """How many recent scans are fused into one source, and over how much motion."""

    scans: int = 1               # scans fused, the newest included (1: the scan alone)
    max_distance: float = 10.0   # metres the sensor may have moved from the oldest fused scan
    max_age: float = 10.0        # seconds the oldest fused scan may be older than the newest
    tolerance: float = 0.05      # seconds between a scan and the odometry that places it


class ScanHistory:
    """Recent scans (stamp, points) and odometry poses (stamp, T_odom_scan), both in stamp order."""

    def __init__(self, capacity: int):
        self.scans: deque[tuple[float, np.ndarray]] = deque(maxlen=max(capacity, 1))
        self._odometry_stamps: list[float] = []
        self._odometry: list[np.ndarray] = []

    def add_scan(self, stamp: float, points: np.ndarray, capacity: int | None = None) -> None:
        """Keep the scan; ``capacity`` (when given) becomes the number of scans kept from now on."""
        if capacity is not None and capacity != self.scans.maxlen:
            self.scans = deque(self.scans, maxlen=max(capacity, 1))
        self.scans.append((stamp, points))

    def add_odometry(self, stamp: float, pose: np.ndarray) -> None:
        """Messages may arrive out of order; ones older than ODOMETRY_SECONDS are forgotten."""
        i = bisect.bisect(self._odometry_stamps, stamp)
        self._odometry_stamps.insert(i, stamp)
        self._odometry.insert(i, pose)
        drop = bisect.bisect_left(self._odometry_stamps, self._odometry_stamps[-1] - ODOMETRY_SECONDS)
        del self._odometry_stamps[:drop], self._odometry[:drop]

    def covers(self, stamp: float) -> bool:
        """Odometry has arrived for ``stamp`` or later: what can place a scan stamped then has been
        received (odometry comes in stamp order from one source)."""
        return bool(self._odometry_stamps) and self._odometry_stamps[-1] >= stamp

    @property
    def has_odometry(self) -> bool:
        """Any odometry received: only then is a scan worth waiting for."""
        return bool(self._odometry_stamps)

    def _why_unplaced(self, stamp: float, tolerance: float) -> tuple[str, str]:
        """(kind, the reason with its figures) for a scan that pose_at cannot place."""
        stamps = self._odometry_stamps
        if not stamps:
            return NO_ODOMETRY, f"{NO_ODOMETRY}: registered alone"
        if stamps[-1] < stamp:
            return ODOMETRY_BEHIND, (f"{ODOMETRY_BEHIND} (the newest is {stamp - stamps[-1]:.3f} s before it): "
                                     "registered alone")
        if stamps[0] > stamp:
            return ODOMETRY_AHEAD, f"{ODOMETRY_AHEAD} (it starts {stamps[0] - stamp:.3f} s later): registered alone"
        i = bisect.bisect_left(stamps, stamp)
        return ODOMETRY_GAP, (f"{ODOMETRY_GAP} ({stamps[i] - stamps[i - 1]:.3f} s between the messages around it, "
                              f"more than 2 x odometry_tolerance={tolerance:g} s): registered alone")

    def pose_at(self, stamp: float, tolerance: float) -> np.ndarray | None:
        """T_odom_scan at ``stamp``: interpolated between the messages around it when they are at
        most 2 x tolerance apart, else the nearest within tolerance; None when there is none."""
        stamps = self._odometry_stamps
        i = bisect.bisect_left(stamps, stamp)
        if i < len(stamps) and stamps[i] == stamp:
            return self._odometry[i]
        if 0 < i < len(stamps) and stamps[i] - stamps[i - 1] <= 2 * tolerance:
            a, b = self._odometry[i - 1], self._odometry[i]
            w = (stamp - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
            pose = np.eye(4)
            pose[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))(w).as_matrix()
            pose[:3, 3] = (1 - w) * a[:3, 3] + w * b[:3, 3]
            return pose
        near = [j for j in (i - 1, i) if 0 <= j < len(stamps) and abs(stamps[j] - stamp) <= tolerance]
        return self._odometry[min(near, key=lambda j: abs(stamps[j] - stamp))] if near else None

    def _window(self, newest: float, max_age: float) -> list[tuple[float, np.ndarray]]:
        """The (stamp, points) kept up to ``newest`` and at most ``max_age`` older, oldest first."""
        return [(s, p) for s, p in self.scans if newest - max_age <= s <= newest]

    def recent(self, newest: float, limits: AccumulationLimits) -> list[np.ndarray]:
        """The scans up to the one stamped ``newest``, oldest first: at most ``limits.scans``, none
        older than ``limits.max_age`` before it (what a sensor at rest may fuse: stillness.at_rest)."""
        return [p for _, p in self._window(newest, limits.max_age)][-limits.scans:]

    def sequence(self, newest: float, limits: AccumulationLimits,
                 viewpoint=ORIGIN) -> tuple[ScanSequence | None, dict]:
        """The scans to fuse, ending with the one stamped ``newest``, and what was decided (for
        status: ``more_to_fuse`` says how many more scans the next registrations fuse as they
        arrive with odometry, up to ``limits.scans``). None when fewer than two scans can be
        fused: register the newest alone (``info["alone"]`` says why). ``viewpoint``: the sensor
        in each scan's frame."""
        candidates = self._window(newest, limits.max_age)
        if not candidates or candidates[-1][0] != newest:
            return None, {"scans_fused": 1, "without_odometry": 0, "more_to_fuse": 0, "alone": NOTHING_TO_FUSE,
                          "reason": "the scan is not in the history"}
        newest_pose = self.pose_at(newest, limits.tolerance)
        if newest_pose is None:
            kind, reason = self._why_unplaced(newest, limits.tolerance)
            return None, {"scans_fused": 1, "without_odometry": 1, "more_to_fuse": 0, "alone": kind,
                          "reason": reason}
        scans: list[np.ndarray] = []
        poses, without, span, too_far = [], 0, 0.0, False
        for stamp, points in reversed(candidates):
            if len(scans) == limits.scans:
                break
            pose = newest_pose if stamp == newest else self.pose_at(stamp, limits.tolerance)
            if pose is None:
                without += 1
                continue
            distance = float(np.linalg.norm(pose[:3, 3] - newest_pose[:3, 3]))
            if distance > limits.max_distance:
                too_far = True
                break
            scans.append(points)
            poses.append(pose)
            span = max(span, distance)
        info: dict = {"scans_fused": len(scans), "without_odometry": without, "span_m": round(span, 3),
                      "more_to_fuse": limits.scans - len(scans)}
        if len(scans) < 2:
            alone = MOVED_TOO_FAR if too_far else NOTHING_TO_FUSE
            info.update(alone=alone, reason=f"{alone}: registered alone")
            return None, info
        return ScanSequence(scans[::-1], poses[::-1], viewpoint), info
