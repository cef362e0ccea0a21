"""The node's inputs and what its worker does next, without ROS: the newest cloud per topic, what
has been registered, and the next job (prepare a map, or register a source against a target).

Only the newest message per topic is kept, so a slow registration drops stale inputs (counted)
instead of queueing them. In map mode a new map is prepared before any query is registered:
queries that arrive meanwhile wait (the newest is kept), never meeting a half-built map. The
caller holds one lock around every call.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Cloud:
    frame_id: str
    stamp_ns: int        # the message's stamp [ns], exact: the outputs carry it
    points: np.ndarray
    serial: int          # increases with every message received on its topic

    @property
    def stamp(self) -> float:
        """[s], as messages.stamp_seconds reads a header (odometry's and the IMU's stamps)"""
        return self.stamp_ns // 10**9 + 1e-9 * (self.stamp_ns % 10**9)


@dataclass(frozen=True)
class MapKey:
    """What a prepared map was made from: a file (and its trajectory) or a target message (its
    serial and viewpoint), and the feature settings; a map is prepared again when this changes."""

    features: Any
    file: str = ""                 # the map file, or '' for a target message
    trajectory: str = ""           # the file's trajectory, '' for none
    serial: int = 0                # the target message's serial
    viewpoint: Any = None          # the target message's viewpoint

    @classmethod
    def of_file(cls, path: str, trajectory: str, features) -> MapKey:
        return cls(features, file=path, trajectory=trajectory or "")

    @classmethod
    def of_message(cls, serial: int, viewpoint, features) -> MapKey:
        return cls(features, serial=serial, viewpoint=viewpoint)


@dataclass(frozen=True)
class PrepareMap:
    key: MapKey                # what the map is made from (InputBuffer.map_key)
    target: Cloud | None    # the target message, or None for a map file


@dataclass(frozen=True)
class Register:
    source: Cloud
    target: Cloud | None    # None against the prepared map


@dataclass(frozen=True)
class CheckPose:
    """The watchdog's check of the stack's pose on the newest source (ros/watchdog.py)."""

    source: Cloud


Job = PrepareMap | Register | CheckPose


class InputBuffer:
    """The newest source and target, the serials registered, and a relocalize call waiting."""

    def __init__(self):
        self.source: Cloud | None = None
        self.target: Cloud | None = None
        self.serials = {"source": 0, "target": 0}
        self.done = {"source": 0, "target": 0}     # serials last registered
        self.relocalize_after: int | None = None  # a relocalize call waits for a source after this serial

    def store(self, which: str, frame_id: str, stamp_ns: int, points: np.ndarray, mode: str) -> bool:
        """Keep the newest cloud of ``which`` ("source" or "target"); True when it replaced one that
        was never registered (a stale input dropped; in map mode a target is a map, never stale)."""
        self.serials[which] += 1
        previous = self.source if which == "source" else self.target
        stale = (previous is not None and previous.serial > self.done[which]
                 and (which == "source" or mode == "pairs"))
        cloud = Cloud(frame_id, stamp_ns, points, self.serials[which])
        if which == "source":
            self.source = cloud
        else:
            self.target = cloud
        return stale

    def map_key(self, settings, features) -> MapKey | None:
        """What the map must be prepared from now: the file, or the newest target message (with
        the target viewpoint), and the feature settings; None while there is no map."""
        if settings.map_file:
            return MapKey.of_file(settings.map_file, settings.map_trajectory_file, features)
        if self.target is None:
            return None
        return MapKey.of_message(self.target.serial, settings.viewpoints()[1], features)

    def next_job(self, settings, features, prepared_key: MapKey | None, map_ready: bool) -> Job | None:
        """The worker's next job, or None. ``prepared_key`` is what the map in use was made from
        and ``map_ready`` whether there is one."""
        if settings.mode == "map":
            key = self.map_key(settings, features)
            if key is not None and key != prepared_key:
                return PrepareMap(key, None if settings.map_file else self.target)
        src, tgt = self.source, self.target
        if src is None or src.serial == self.done["source"]:
            return None
        if settings.registration == "on_demand" and (
                self.relocalize_after is None or src.serial <= self.relocalize_after):
            return None
        if settings.mode == "map":
            return Register(src, None) if map_ready else None
        if tgt is None or tgt.serial == self.done["target"]:
            return None
        tolerance = settings.max_stamp_difference
        if tolerance and abs(src.stamp - tgt.stamp) > tolerance:
            return None
        return Register(src, tgt)

    def taken(self, job: Register) -> None:
        """The worker took ``job``: its clouds are registered."""
        self.done["source"] = job.source.serial
        if job.target is not None:
            self.done["target"] = job.target.serial
