"""What a registration of the newest scan is given beside it, without ROS: the scans before it
fused along odometry (accumulate_scans; the worker waits up to odometry_wait for the odometry
that places the newest), or, with no odometry, the ones the scans show were taken at rest
(fuse_at_rest; the first registration waits up to rest_wait to gather them), its up direction
from the IMU (the gravity prior) and the hint of where it is (initial_guess)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core import ScanHistory, SearchRegion, at_rest
from .imu_up import ImuUp
from .inputs import Cloud
from .report import Report
from .shared import Shared


@dataclass(frozen=True)
class Hint:
    """Where the source is thought to be (an initial guess), in the frame it was given in."""

    frame_id: str
    region: SearchRegion


class SourceContext:
    """The scan history, the IMU's up and the hint in force (until a pose is accepted), under the
    shared lock."""

    def __init__(self, shared: Shared, report: Report):
        self.shared, self.report = shared, report
        self.history = ScanHistory(self._capacity())
        self.imu = ImuUp() if shared.settings.imu_topic else None
        self.hint: Hint | None = None
        self._waiting_since: float | None = None   # the worker waits for odometry since (monotonic), or None
        self._first_scan: float | None = None      # when the first scan arrived (monotonic), or None
        self._gathering = True                     # no source taken yet: the first may wait for scans at rest
        self._announced = False                    # the node said it is gathering

    def _capacity(self) -> int:
        """Scans kept for accumulation: twice the scans fused, so ones without odometry can be skipped."""
        return 2 * self.shared.settings.accumulation().scans + 2

    def add_scan(self, stamp: float, points: np.ndarray) -> None:
        """A source scan (the caller holds the lock)."""
        self.history.add_scan(stamp, points, self._capacity())
        if self._first_scan is None:
            self._first_scan = time.monotonic()

    def add_odometry(self, stamp: float, T_odom_scan: np.ndarray) -> None:
        with self.shared.lock:
            self.report.stats["odometry_messages"] += 1
            self.history.add_odometry(stamp, T_odom_scan)
            self.shared.lock.notify_all()   # a scan may be waiting for it (awaits_odometry)

    def awaits_odometry(self, stamp: float) -> float:
        """Seconds the worker still waits before taking the source stamped ``stamp`` (the caller
        holds the lock): it is to be fused, odometry has been received, but none at or after its
        stamp yet (a lidar-inertial odometry publishes a scan's pose after the scan). The clock
        starts when the worker could first have taken a source and runs on when a newer scan
        replaces the waiting one, so the worker never idles longer than odometry_wait (odometry
        that stopped costs that, once a registration)."""
        settings = self.shared.settings
        if settings.accumulation().scans < 2 or not self.history.has_odometry or self.history.covers(stamp):
            return 0.0
        if self._waiting_since is None:
            self._waiting_since = time.monotonic()
        return self.still_waiting()

    def awaits_rest(self) -> float:
        """Seconds the first source still waits for scans to fuse at rest (the caller holds the
        lock): with no odometry and fuse_at_rest, until accumulate_scans scans have arrived or
        rest_wait has passed since the first."""
        settings = self.shared.settings
        scans = settings.accumulation().scans
        if (not self._gathering or not settings.fuse_at_rest or scans < 2 or self.history.has_odometry
                or self._first_scan is None or len(self.history.scans) >= scans):
            self.report.health.gathering = ""
            return 0.0
        left = max(0.0, self._first_scan + settings.rest_wait - time.monotonic())
        self.report.health.gathering = (f"no odometry: gathering scans at rest before the first registration, "
                                        f"{len(self.history.scans)} of {scans}" if left > 0 else "")
        if left > 0 and not self._announced:
            self._announced = True
            self.report.logger.info(f"no odometry: gathering up to {scans} scans (accumulate_scans) for at most "
                                    f"rest_wait={settings.rest_wait:g} s, to fuse the ones taken at rest")
        return left

    def still_waiting(self) -> float:
        """Seconds left of a wait under way (for odometry, or for scans at rest), 0 when none (the
        caller holds the lock)."""
        odometry = 0.0 if self._waiting_since is None else \
            self._waiting_since + self.shared.settings.odometry_wait - time.monotonic()
        return max(0.0, odometry, self.awaits_rest())

    def end_wait(self) -> float:
        """The worker takes a job: the seconds it waited for odometry, and the clock stopped."""
        waited = 0.0 if self._waiting_since is None else time.monotonic() - self._waiting_since
        self._waiting_since = None
        return waited

    def add_imu(self, stamp: float, orientation_xyzw: np.ndarray | None, acceleration: np.ndarray,
                angular_velocity: np.ndarray | None = None) -> None:
        with self.shared.lock:
            if self.imu is not None:
                self.imu.add(stamp, orientation_xyzw, acceleration, angular_velocity)

    def set_hint(self, hint: Hint) -> None:
        with self.shared.lock:
            self.hint = hint
            self.shared.lock.notify_all()

    def gravity(self, config, settings, src: Cloud):
        """The configuration with the source's up direction from the IMU at the scan's stamp (or
        unknown when the IMU gave none: no prior rather than a stale one), and what it was."""
        if self.imu is None:
            return config, {"direction": config.gravity.source_up, "from": "gravity.source_up"}
        with self.shared.lock:
            up, where = self.imu.up_at(src.stamp, settings.imu_window, settings.imu_extrinsic()[:3, :3])
        text = "unknown" if up is None else " ".join(f"{v:.6f}" for v in up)
        return config.replace({"gravity.source_up": text}), {"direction": text, "from": where}

    def region(self, hint: Hint | None, target_frame: str) -> SearchRegion | None:
        """The hint's search region, or None; a hint in another frame is dropped with a warning."""
        if hint is None:
            return None
        if hint.frame_id and hint.frame_id != target_frame:
            with self.shared.lock:
                if self.hint is hint:
                    self.hint = None
            self.report.bad_input(f"initial_guess dropped: it is in '{hint.frame_id}', the target "
                                  f"cloud in '{target_frame}' (this node does not look up tf)")
            return None
        return hint.region

    def source_input(self, src: Cloud, settings, config):
        """(the scan alone, or fused with the scans before it along odometry (accumulate_scans), or
        without odometry with the ones taken at rest (fuse_at_rest, judged at ``config``'s voxel);
        the viewpoints to give register() and verify() with it; what was fused, for status). The
        fused scans carry their own viewpoints (the scan frame's origin)."""
        source_viewpoint, target_viewpoint = settings.viewpoints()
        limits = settings.accumulation()
        sequence, info = None, None
        if limits.scans >= 2:
            with self.shared.lock:
                self._gathering, self.report.health.gathering = False, ""
                sequence, info = self.history.sequence(src.stamp, limits, source_viewpoint)
                at_rest_may_fuse = sequence is None and settings.fuse_at_rest and not self.history.has_odometry
                recent = self.history.recent(src.stamp, limits) if at_rest_may_fuse else []
            if len(recent) >= 2:
                sequence, moved = at_rest(recent, config.features.voxel_size, config.features.normal_radius,
                                          source_viewpoint)
                if sequence is None:
                    info["reason"] = f"{info['alone']}, and the scans show motion ({moved}): registered alone"
                else:
                    info = {"scans_fused": len(sequence.scans), "without_odometry": 0, "at_rest": True,
                            "more_to_fuse": 0}
        if sequence is None:
            return src.points, {"source_viewpoint": source_viewpoint, "target_viewpoint": target_viewpoint}, info
        return sequence, {"target_viewpoint": target_viewpoint}, info
