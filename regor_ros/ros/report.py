"""What the node reports of its work, without ROS: the counters, the health /diagnostics shows,
warnings about bad input (throttled per kind), and each registration's outcome: the status fields,
the line a relocalize call answers with, and the pose that goes out."""
from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core import RegistrationError, attached_pose
from .diagnostics import Health
from .inputs import Cloud

if TYPE_CHECKING:
    from ..core import RegistrationResult, SearchRegion

WARN_THROTTLE_S = 5.0


@dataclass(frozen=True)
class PublishedPose:
    """The pose that goes out: the sensor's in the target frame, or its base's with a base_frame."""

    transform: np.ndarray   # 4x4
    covariance: np.ndarray  # 6x6 over (x, y, z, roll, pitch, yaw)


@dataclass(frozen=True)
class Outcome:
    """One registration, for the node to publish."""

    source: Cloud
    result: RegistrationResult
    target_frame: str
    status: dict       # the status message's fields beside the result's own
    pose: PublishedPose | None  # None when withheld
    T_sensor_base: np.ndarray | None  # with a base_frame, its pose in the sensor frame (the candidates')
    answer: str        # what happened, in a line (a relocalize call's reply)


class Report:
    """The node's counters and health, under the node's ``lock``; ``logger`` has info / warning /
    error (rclpy's or logging's)."""

    def __init__(self, lock: threading.Condition, logger, map_from_file: bool):
        self.lock, self.logger = lock, logger
        self.stats = {"source_clouds": 0, "target_clouds": 0, "odometry_messages": 0, "registrations": 0,
                      "accepted_poses": 0, "dropped_stale": 0, "bad_inputs": 0, "map_preparations": 0,
                      "registrations_fused": 0, "registrations_alone": 0, "registrations_fused_at_rest": 0}
        # why scans meant to be fused were registered alone: kind (core ALONE_REASONS) -> count
        self.alone_because: dict[str, int] = {}
        self.health = Health(counters=self.stats, alone_because=self.alone_because, map_from_file=map_from_file)
        self._warned: dict[str, float] = {}   # kind of bad input -> when it was last logged

    def bad_input(self, text: str) -> None:
        """Count and warn, at most once per WARN_THROTTLE_S for each kind of problem (the text
        with its numbers blanked), so a flood of one bad kind cannot hide another."""
        kind = re.sub(r"[-+.\de]*\d[-+.\de]*", "#", text)
        now = time.monotonic()
        with self.lock:
            self.stats["bad_inputs"] += 1
            self.health.last_bad_input = text
            if now - self._warned.get(kind, -WARN_THROTTLE_S) < WARN_THROTTLE_S:
                return
            self._warned[kind] = now
        self.logger.warning(text)

    def not_registered(self, exc: Exception) -> str:
        """A registration that raised: the input's fault (RegistrationError) is bad input, anything
        else an error the node survives; the line a relocalize call answers with."""
        if isinstance(exc, RegistrationError):
            self.health.last_error = str(exc)
            self.bad_input(f"registration skipped: {exc}")
            return f"registration skipped: {exc}"
        self.health.last_error = f"{type(exc).__name__}: {exc}"
        self.logger.error(f"registration failed: {type(exc).__name__}: {exc}")
        return f"registration failed: {type(exc).__name__}: {exc}"

    def registered(self, result: RegistrationResult, accumulation: dict | None) -> None:
        """Count a registration, fused or alone (and why) when scans are to be fused, and keep its
        summary (the caller holds the lock)."""
        self.stats["registrations"] += 1
        if accumulation is not None:
            alone = accumulation.get("alone")
            self.stats["registrations_alone" if alone else "registrations_fused"] += 1
            self.stats["registrations_fused_at_rest"] += int(bool(accumulation.get("at_rest")))
            if alone:
                self.alone_because[alone] = self.alone_because.get(alone, 0) + 1
        self.stats["accepted_poses"] += int(result.accepted)
        self.health.last_error = self.health.last_bad_input = ""
        self.health.last_summary = result.summary()

    def status(self, src: Cloud, target: Cloud | None, target_frame: str, settings, config, extra: dict,
               region: SearchRegion | None) -> dict:
        """The status message's fields beside the result's own (the caller holds the lock)."""
        return {"source_stamp": src.stamp, "source_frame": src.frame_id,
                "target_stamp": None if target is None else target.stamp,
                "target_frame": target_frame, "pose_of": settings.base_frame or src.frame_id,
                "mode": settings.mode, **self.stats, "registered_alone_because": dict(self.alone_because),
                **self.health.inputs, **extra,
                "target_up": config.gravity.target_up,
                **(self.health.map_info if settings.mode == "map" else {}),
                "search_region": None if region is None else {
                    "centre": [float(v) for v in region.centre], "radius": region.radius}}

    def outcome(self, src: Cloud, result: RegistrationResult, target_frame: str, status: dict,
                settings, accumulation: dict | None) -> Outcome:
        """The registration as it goes out: logged, the pose (the robot's, composed with its
        mounting, with a base_frame) when accepted or publish_rejected, and the answer's line."""
        figures = (f"{result.num_inliers} inliers, fitness {result.fitness:.2f}, "
                   f"{result.timings['total']:.2f} s")
        if accumulation and accumulation.get("alone"):
            figures += f"; {accumulation['reason']}"
        if result.accepted:
            alone = ", which single it out among the other answers" if result.verdict.singled_out else ""
            figures = f"carried by its {result.verdict.carried_by}{alone}, {figures}"
            self.logger.info(f"pose accepted: {figures}")
            answer = f"pose published ({figures})"
        else:
            if accumulation and accumulation.get("more_to_fuse"):
                figures += (f"; {accumulation['scans_fused']} of {settings.accumulation().scans} scans fused: up to "
                            f"{accumulation['more_to_fuse']} more are fused as they arrive with odometry")
            self.logger.warning(f"pose rejected: {result.reason} ({figures})")
            answer = (f"pose published although rejected: {result.reason}" if settings.publish_rejected
                      else f"pose withheld: {result.reason} ({figures})")
        base = np.linalg.inv(settings.base_extrinsic()) if settings.base_frame else None
        pose = None
        if result.accepted or settings.publish_rejected:
            # the robot's pose, for Nav2: the sensor's composed with its mounting
            pose = (PublishedPose(result.transform, result.covariance) if base is None
                    else PublishedPose(*attached_pose(result.transform, result.covariance, base)))
        return Outcome(src, result, target_frame, status, pose, base, answer)
