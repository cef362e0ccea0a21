"""The watchdog, without ROS: a localization stack's pose (AMCL's, a scan matcher's) checked against
the newest scans, and when it is lost, the robot relocalized.

A stack that has gone wrong (the robot carried, slipped along a corridor, started in the wrong
place) goes on publishing its pose with confidence. At the node's verify_rate the newest scan,
fused along odometry as relocalization fuses it, is checked at the stack's pose for the scan's
stamp (core verify(): the gate after a local refinement). A verified pose is OK, and the
correction the data make to it is reported, not raised; a pose that fails is suspect; after
lost_after failures in a row the robot is lost and the node relocalizes globally, publishing the
pose it finds (pose_with_covariance, Nav2's /initialpose). A pose that cannot be checked (none,
not finite, in another frame than the map's, too far from the scan's stamp) gets its reason and
no verdict: it neither counts as a failure nor clears one.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core import Summary

VERIFIED, SUSPECT, LOST, UNCHECKED = "verified", "suspect", "lost", "unchecked"
POSES_KEPT = 200  # the stack's newest poses (a few seconds of a fast tracker): the scan's stamp is among them


@dataclass(frozen=True)
class TrackedPose:
    """The stack's pose of the robot (its base frame's, or the sensor's without a base frame)."""

    stamp: float
    frame_id: str
    transform: np.ndarray   # 4x4 T_frame_base


@dataclass(frozen=True)
class Check:
    """One check of the stack's pose, for status and /diagnostics."""

    state: str                # VERIFIED, SUSPECT, LOST or UNCHECKED
    reason: str               # why the pose is not verified, or why it was not checked
    scan_stamp: float         # the scan it was checked on
    pose_stamp: float | None  # the stack's pose it checked
    failures: int             # failed checks in a row, this one included
    correction: tuple[float, float] | None = None  # (m, deg) where the data put the pose
    summary: Summary | None = None  # core Verification.summary()

    def as_dict(self) -> dict:
        out = {"watchdog": self.state, "reason": self.reason, "scan_stamp": self.scan_stamp,
               "pose_stamp": self.pose_stamp, "failures_in_a_row": self.failures}
        if self.correction is not None:
            out.update(correction_m=self.correction[0], correction_deg=self.correction[1])
        if self.summary is not None:
            out["verification"] = self.summary.as_json()
        return out


class Watchdog:
    """The stack's newest poses, and the run of failed checks; the caller holds a lock around every call."""

    def __init__(self):
        self.poses: deque[TrackedPose] = deque(maxlen=POSES_KEPT)
        self.failures = 0

    def track(self, pose: TrackedPose) -> None:
        self.poses.append(pose)

    def pose_for(self, stamp: float, map_frame: str, max_age: float) -> tuple[TrackedPose | None, str]:
        """(the stack's pose nearest the scan's ``stamp``, '') or (None, why there is none to check)."""
        if not self.poses:
            return None, "no pose has arrived on tracked_pose"
        pose = min(self.poses, key=lambda p: abs(p.stamp - stamp))
        if abs(pose.stamp - stamp) > max_age:
            return None, (f"the tracked pose nearest the scan is {abs(pose.stamp - stamp):.2f} s from its stamp "
                          f"(max_pose_age={max_age:g} s)")
        if pose.frame_id != map_frame:
            return None, f"the tracked pose is in '{pose.frame_id}', the map in '{map_frame}' (no tf lookup here)"
        if not np.isfinite(pose.transform).all():
            return None, "the tracked pose is not finite (NaN or infinite)"
        return pose, ""

    def unchecked(self, reason: str, scan_stamp: float) -> Check:
        """A check that could not be made: no verdict, the run of failures unchanged."""
        return Check(UNCHECKED, reason, scan_stamp, None, self.failures)

    def judged(self, verification, scan_stamp: float, pose_stamp: float, lost_after: int) -> Check:
        """The check of a verify() result: verified clears the run of failures; a failure is
        suspect, and lost from ``lost_after`` in a row."""
        self.failures = 0 if verification.accepted else self.failures + 1
        state = VERIFIED if verification.accepted else LOST if self.failures >= lost_after else SUSPECT
        return Check(state, verification.reason, scan_stamp, pose_stamp, self.failures,
                     (verification.correction_m, verification.correction_deg), verification.summary())

    def found(self) -> None:
        """The robot was relocalized (a pose published): the stack starts again from it."""
        self.failures = 0
