"""The node's health as diagnostic_msgs/DiagnosticArray on /diagnostics, for robot monitors, and the
watchdog's verdict on the localization stack's pose as a second status.

Localization stacks watch /diagnostics (rqt_robot_monitor, diagnostic aggregators), not a JSON
string. One status, refreshed at a steady rate: OK while the last pose was published, WARN while
the node is not active (ERROR when its configure failed: the reason), no input has arrived (on
source_cloud alone when the map is a file), the map is still being prepared or the last pose was withheld (with the
gate's reason) or a malformed cloud arrived, ERROR when the last input could not be registered.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

if TYPE_CHECKING:
    from ..core import Summary

STATUS_NAME = "regor_ros: registration"
WATCHDOG_NAME = "regor_ros: localization watchdog"
# the watchdog's states (ros/watchdog.py) as levels: a pose that could not be checked is stale
WATCHDOG_LEVELS = {"verified": DiagnosticStatus.OK, "suspect": DiagnosticStatus.WARN,
                   "lost": DiagnosticStatus.ERROR, "unchecked": DiagnosticStatus.STALE}


@dataclass
class Health:
    """What the node knows about its own state, updated by the worker thread."""

    preparing_map: bool = False
    last_error: str = ""                   # why the last input could not be registered
    last_bad_input: str = ""               # the last malformed cloud since the last registration
    last_summary: Summary | None = None    # RegistrationResult.summary() of the last registration
    counters: dict[str, int] = field(default_factory=dict)  # the node's counters, clouds received included
    alone_because: dict[str, int] = field(default_factory=dict)  # scans to fuse registered alone, by why
    map_info: dict[str, object] = field(default_factory=dict)  # map mode: the prepared map's size and time
    inputs: dict[str, str] = field(default_factory=dict)  # each input's QoS, as subscribed
    lifecycle: str = "unconfigured"        # the node's lifecycle state, or why configure failed
    map_from_file: bool = False            # the target is a map file, not target_cloud
    ready_after_s: float | None = None     # from the process's start to ready to register (imports included)
    watchdog: Any = None                   # the watchdog's latest Check (ros/watchdog.py), None before one
    gathering: str = ""                    # the first registration waits for scans at rest: how many so far

    def ready_line(self, kernels_s: float) -> str:
        """The log line of a node ready to register: how long after its start, and the parts."""
        after = "" if self.ready_after_s is None else f" {self.ready_after_s:.1f} s after the process started"
        map_s = self.map_info.get("map_preparation_seconds")
        return f"ready to register{after} (kernels {kernels_s:.2f} s" + (
            f", map {map_s:.1f} s)" if map_s is not None else ")")


def seconds_since_process_start() -> float | None:
    """How long this process has run, its imports included (Linux's /proc; None elsewhere)."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")   # field 22, starttime: ticks since boot
        return time.clock_gettime(time.CLOCK_BOOTTIME) - started
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _value(v) -> str:
    if isinstance(v, float):
        return "None" if v != v else f"{v:.4g}"   # NaN: not measured
    return str(v)


def diagnostic_status(health: Health, node_name: str) -> DiagnosticStatus:
    """The status and its key values for the current health."""
    level, message = DiagnosticStatus.OK, "pose published"
    inputs = ("source",) if health.map_from_file else ("source", "target")
    missing = [topic for topic in inputs if not health.counters.get(f"{topic}_clouds")]
    summary = health.last_summary
    if health.lifecycle.startswith("configure failed"):
        level, message = DiagnosticStatus.ERROR, health.lifecycle
    elif health.lifecycle != "active":
        level, message = DiagnosticStatus.WARN, f"{health.lifecycle}: not registering"
    elif health.last_error:
        level, message = DiagnosticStatus.ERROR, f"last input not registered: {health.last_error}"
    elif health.last_bad_input:
        level, message = DiagnosticStatus.WARN, f"bad input: {health.last_bad_input}"
    elif missing:
        level, message = DiagnosticStatus.WARN, "no input yet on " + " and ".join(f"{t}_cloud" for t in missing)
    elif health.preparing_map:
        level, message = DiagnosticStatus.WARN, "map not prepared yet"
    elif summary is None:
        level, message = DiagnosticStatus.WARN, health.gathering or "waiting for a registration"
    elif not summary.accepted:
        level, message = DiagnosticStatus.WARN, f"last pose withheld: {summary.reason}"
    values = {"lifecycle": health.lifecycle, **health.counters,
              **{f"registered alone: {why}": n for why, n in health.alone_because.items()},
              **health.inputs, **health.map_info}
    if health.ready_after_s is not None:
        values["ready after seconds"] = health.ready_after_s
    if summary is not None:
        figures = summary.figures
        values.update({
            "last verdict": "accepted" if summary.accepted else "rejected",
            "inliers": int(figures.num_inliers), "fitness": float(figures.fitness),
            "feature inliers": int(figures.feature_inliers),
            "worst free space": float(figures.worst_free_space),
            "opposite sides": float(figures.opposite_sides), "ambiguity": summary.ambiguity,
            **{f"seconds {stage}": seconds for stage, seconds in summary.timings.items()},
        })
    return DiagnosticStatus(level=level, name=STATUS_NAME, message=message, hardware_id=node_name,
                            values=[KeyValue(key=k, value=_value(v)) for k, v in values.items()])


def watchdog_status(check, node_name: str) -> DiagnosticStatus:
    """The watchdog's latest check: OK verified (the correction reported), WARN suspect, ERROR lost,
    STALE not checked (the reason)."""
    message = {"verified": "tracked pose verified", "suspect": f"tracked pose suspect: {check.reason}",
               "lost": f"lost ({check.failures} failed checks in a row): {check.reason}; relocalizing",
               "unchecked": f"tracked pose not checked: {check.reason}"}[check.state]
    values = {"failures in a row": check.failures, "scan stamp": check.scan_stamp, "pose stamp": check.pose_stamp}
    if check.correction is not None:
        values.update({"correction m": check.correction[0], "correction deg": check.correction[1]})
    return DiagnosticStatus(level=WATCHDOG_LEVELS[check.state], name=WATCHDOG_NAME, message=message,
                            hardware_id=node_name, values=[KeyValue(key=k, value=_value(v)) for k, v in values.items()])


def diagnostic_array(health: Health, node_name: str, stamp) -> DiagnosticArray:
    statuses = [diagnostic_status(health, node_name)]
    if health.watchdog is not None:
        statuses.append(watchdog_status(health.watchdog, node_name))
    array = DiagnosticArray(status=statuses)
    array.header.stamp = stamp
    return array
