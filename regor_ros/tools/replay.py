"""regor-replay: how register_node would do on your own recording, before wiring anything.

Reads a rosbag2 (sqlite3 or MCAP; the rosbags library, no ROS install) and runs the node's own
localizer on it as fast as the CPU allows: scans fused along the bag's odometry as the node fuses
them, the gravity prior from the bag's IMU as the node's imu_topic gives it, a relocalization in
the map every --every seconds of the recording (default: every scan), and with --tracked-topic the
watchdog's check of the localization stack's pose on every scan (DIR/watchdog.csv; lost, the robot
is relocalized). Stamps decide, not the order messages were logged in: a lidar-inertial odometry
logs a scan's pose after the scan, and it still places that scan. Writes DIR/registrations.csv
(the scan frame's pose in the map frame, or the base's with --base-to-sensor; errors against
--reference-topic or --reference-file where given; how many scans were fused, or why alone),
DIR/summary.md and DIR/map.png (the map from above, the reference trajectory and every pose:
green where the reference agrees).
Exit status: 0 replayed, 2 the bag, a topic or the map cannot be used (one line; nothing written).
"""
from __future__ import annotations

import argparse
import csv
import logging
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import PRESETS, ConfigError, RegistrationError, RegorConfig
from .register_cli import DEFAULT_PRESET, PRESET_HELP, parse_overrides

EPILOG = """examples:
  regor-replay drive.mcap --map site.pcd --map-trajectory site_tum.txt --scan-topic /points \\
      --odom-topic /odom --reference-topic /ground_truth --preset outdoor --out replay/
  regor-replay bag_folder --map site.pcd --scan-topic /livox/lidar --imu-topic /livox/imu \\
      --set gravity.target_up="0 0 1" --reference-file site_ground_truth.csv --every 5 --out replay/"""
REFERENCE_TOLERANCE_S = 0.1   # a reference pose counts for a scan when this close to its stamp
READ_AHEAD_TOLERANCES = 2.0   # messages up to this many odometry_tolerance after a scan may place it (pose_at)
PROGRESS_PERIOD_S = 10.0
PICTURE_MARGIN_M = 5.0        # map.png shows at least this much around the robot's path
SCAN_TYPE = "sensor_msgs/msg/PointCloud2"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
IMU_TYPE = "sensor_msgs/msg/Imu"
REFERENCE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped", ODOMETRY_TYPE)
FIELDS = ["stamp", "accepted", "reason", "x", "y", "z", "qx", "qy", "qz", "qw", "seconds", "scans_fused",
          "registered_alone_because", "source_up_from", "reference_rotation_error_deg",
          "reference_translation_error_m", "agrees"]
WATCHDOG_FIELDS = ["stamp", "watchdog", "reason", "failures_in_a_row", "correction_m", "correction_deg"]


class ReplayError(Exception):
    """A bag, topic or map that cannot be replayed; the message says which and why."""


@dataclass
class Registration:
    stamp: float
    accepted: bool
    reason: str
    pose: np.ndarray | None   # 4x4 in the map frame (None: not registered)
    seconds: float
    scans_fused: int          # 1 alone, 0 when scans are not fused (accumulate_scans=1)
    alone: str                # why a scan meant to be fused was registered alone (core ALONE_REASONS), or ''
    failed: str               # the gate's check that withheld it (Verdict.failed), or '' (published, or an error)
    up_from: str              # where the gravity prior's up came from (the IMU, or why none), '' without one


def _pose_of(message, msgtype: str) -> np.ndarray:
    from ..ros.messages import matrix_from_pose
    return matrix_from_pose(message.pose if msgtype.endswith("PoseStamped") else message.pose.pose)


def _connections(reader, topic: str | None, types: tuple[str, ...], role: str):
    if topic is None:
        return []
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        listed = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise ReplayError(f"{role} {topic!r} is not in the bag (its topics: {listed})")
    if found[0].msgtype not in types:
        raise ReplayError(f"{role} {topic!r} holds {found[0].msgtype}, not {' or '.join(types)}")
    return found


@dataclass(frozen=True)
class Topics:
    """The bag's topics a replay reads: the scans, and beside them what the node subscribes to."""

    scan: str
    odometry: str | None = None    # nav_msgs/Odometry, as the node's odometry
    reference: str | None = None   # poses to score against
    tracked: str | None = None     # the localization stack's pose, as the node's tracked_pose
    imu: str | None = None         # sensor_msgs/Imu, as the node's imu_topic


def open_bag(bag: Path):
    """An opened rosbags reader, or ReplayError saying why the path is not a readable rosbag2."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    bag = Path(bag)
    if not bag.exists():
        raise ReplayError(f"{bag}: no such file or folder")
    if bag.is_dir() and not (bag / "metadata.yaml").is_file():
        recordings = sorted(p.name for p in bag.glob("*") if p.suffix in (".mcap", ".db3"))
        hint = f"; give one of its recordings instead: {', '.join(recordings)}" if recordings else ""
        raise ReplayError(f"{bag}: a folder without metadata.yaml, not a rosbag2{hint}")
    # a bag written before rosbag2 stored its message definitions: the standard ones stand in
    reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except Exception as exc:  # rosbags' errors for a missing, truncated or foreign file
        raise ReplayError(f"{bag}: cannot be read as a rosbag2 (sqlite3 or MCAP): {exc}") from None
    return reader


class Progress:
    """A line on stderr every PROGRESS_PERIOD_S of a long replay: scans done, published, time left."""

    def __init__(self, total: int, stream=sys.stderr):
        self.total, self.stream = total, stream
        self.start = self.last = time.monotonic()

    def update(self, done: int, published: int) -> None:
        now = time.monotonic()
        if now - self.last < PROGRESS_PERIOD_S or not done:
            return
        self.last = now
        left = (now - self.start) / done * (self.total - done)
        print(f"regor-replay: {done} of {self.total} scans, {published} published, "
              f"about {left // 60:.0f} min {left % 60:02.0f} s left", file=self.stream, flush=True)


def _side_messages(reader, connections: dict, settings) -> list[tuple[float, str, object]]:
    """Every message beside the scans as (stamp, kind, what the localizer takes), in stamp order:
    a replay hands them over by stamp, not by when they were logged."""
    from ..ros.messages import imu_reading, matrix_from_pose, stamp_seconds
    from ..ros.watchdog import TrackedPose
    kind_of = {c.id: kind for kind, found in connections.items() for c in found}
    side: list[tuple[float, str, object]] = []
    if not kind_of:
        return side   # (rosbags reads every topic when given none)
    for connection, _, raw in reader.messages(connections=[c for found in connections.values() for c in found]):
        message = reader.deserialize(raw, connection.msgtype)
        stamp, kind = stamp_seconds(message.header), kind_of[connection.id]
        if kind == "odometry":
            value = matrix_from_pose(message.pose.pose) @ settings.odometry_extrinsic()
        elif kind == "imu":
            value = imu_reading(message)
        elif kind == "tracked":
            value = TrackedPose(stamp, message.header.frame_id, _pose_of(message, connection.msgtype))
        else:
            value = _pose_of(message, connection.msgtype)
        side.append((stamp, kind, value))
    side.sort(key=lambda item: item[0])
    return side


def replay(bag: Path, config: RegorConfig, settings, topics: Topics, every: float,
           reference_file: Path | None = None, progress: bool = False):
    """(registrations, reference poses (stamp, 4x4), counts, the map as prepared, the watchdog's
    checks) of one bag replayed through the node's localizer (its map loaded as the node's
    configure loads it, once the bag and its topics are known to be usable).

    Stamps decide, as they do for the node: before a scan is registered, every message beside it
    stamped up to odometry_wait after it (what the node waits for; at least the READ_AHEAD_TOLERANCES
    x odometry_tolerance odometry is interpolated over) has been handed over, however late it was
    logged (a lidar-inertial odometry logs a scan's pose after the scan)."""
    from ..ros.localizer import Localizer
    from ..ros.messages import stamp_nanoseconds, stamp_seconds
    from ..ros.pointcloud import cloud_to_xyz
    reader = open_bag(bag)
    try:
        scans = _connections(reader, topics.scan, (SCAN_TYPE,), "--scan-topic")
        side_connections = {
            "odometry": _connections(reader, topics.odometry, (ODOMETRY_TYPE,), "--odom-topic"),
            "reference": _connections(reader, topics.reference, REFERENCE_TYPES, "--reference-topic"),
            "tracked": _connections(reader, topics.tracked, REFERENCE_TYPES, "--tracked-topic"),
            "imu": _connections(reader, topics.imu, (IMU_TYPE,), "--imu-topic")}
        total = sum(c.msgcount for c in scans)
        if not total:
            raise ReplayError(f"{topics.scan}: no messages in the bag")
        reference = read_reference(reference_file) if reference_file else []
        try:
            side = _side_messages(reader, side_connections, settings)
        except Exception as exc:  # a message the bag holds but cannot give back whole
            raise ReplayError(f"{bag}: reading stopped: {type(exc).__name__}: {exc}") from None
        counts = {"scans": total, **{kind: sum(k == kind for _, k, _ in side) for kind in side_connections}}
        reference += [(stamp, np.asarray(value)) for stamp, kind, value in side if kind == "reference"]  # scored only
        side = [item for item in side if item[1] != "reference"]
        outcomes: dict = {}
        checks: list = []
        localizer = Localizer(config, settings, logging.getLogger("regor-replay"),
                              lambda outcome: outcomes.__setitem__(outcome.source.serial, outcome),
                              lambda prepared, frame: None, checks.append)
        localizer.configure()
        registrations: list[Registration] = []
        handed, done, last = 0, 0, -np.inf
        ahead = max(settings.odometry_wait, READ_AHEAD_TOLERANCES * settings.odometry_tolerance)
        meter = Progress(total) if progress else None
        try:
            for connection, _, raw in reader.messages(connections=scans):
                message = reader.deserialize(raw, connection.msgtype)
                stamp = stamp_seconds(message.header)
                while handed < len(side) and side[handed][0] <= stamp + ahead:
                    _hand_over(localizer, side[handed])
                    handed += 1
                try:
                    points = cloud_to_xyz(message)
                except RegistrationError as exc:
                    raise ReplayError(f"{topics.scan}: a PointCloud2 at {stamp:.3f} s cannot be read: "
                                      f"{exc}") from None
                due = stamp >= last + every
                start = time.perf_counter()
                answer = localizer.replay(message.header.frame_id, stamp_nanoseconds(message.header), points,
                                          due, check_it=bool(side_connections["tracked"]))
                if answer is not None:
                    last = stamp
                    registrations.append(_registration(stamp, answer, outcomes.pop(answer.serial, None),
                                                       time.perf_counter() - start))
                done += 1
                if meter is not None:
                    meter.update(done, sum(r.accepted for r in registrations))
        except ReplayError:
            raise
        except Exception as exc:  # a message the bag holds but cannot give back whole
            raise ReplayError(f"{bag}: reading stopped: {type(exc).__name__}: {exc}") from None
    finally:
        reader.close()
    counts["reference"] = len(reference)
    return registrations, reference, counts, localizer.maps.prepared, checks


def _hand_over(localizer, item) -> None:
    """One message beside the scans, to the localizer as the node's subscriptions hand it."""
    stamp, kind, value = item
    if kind == "odometry":
        localizer.context.add_odometry(stamp, value)
    elif kind == "imu":
        localizer.context.add_imu(*value)
    else:
        localizer.track_pose(value)


def _registration(stamp: float, answer, outcome, seconds: float) -> Registration:
    pose = None if outcome is None else outcome.result.transform
    if outcome is not None and outcome.T_sensor_base is not None:
        pose = pose @ outcome.T_sensor_base
    accumulation = (outcome.status.get("accumulation") if outcome is not None else None) or {}
    return Registration(stamp, answer.accepted, "" if answer.accepted else answer.text, pose, seconds,
                        accumulation.get("scans_fused", 1) if accumulation else 0, accumulation.get("alone", ""),
                        "" if outcome is None else outcome.result.verdict.failed,
                        "" if outcome is None else _up_from(outcome.status.get("source_up")))


def _up_from(source_up: dict | None) -> str:
    """The source's up as the registration took it: where from, or '' when the prior was off."""
    if not source_up or (source_up["direction"] == "unknown" and source_up["from"] == "gravity.source_up"):
        return ""
    return source_up["from"] if source_up["direction"] != "unknown" else f"none: {source_up['from']}"


def read_reference(path: Path) -> list[tuple[float, np.ndarray]]:
    """Reference poses from a file: TUM (t x y z qx qy qz qw per line) or a CSV whose header names
    the columns stamp (or t, timestamp), x, y, z, qx, qy, qz, qw."""
    from ..io.cloud_io import CloudFileError
    from ..io.map_file import read_trajectory, trajectory_of_rows
    path = Path(path)
    try:
        stamps, poses = read_trajectory(path) if path.suffix.lower() != ".csv" else \
            trajectory_of_rows(_reference_csv_rows(path), path)
    except CloudFileError as exc:
        raise ReplayError(f"--reference-file {exc}") from None
    return list(zip(stamps.tolist(), poses, strict=True))


def _reference_csv_rows(path: Path) -> np.ndarray:
    """The rows (stamp x y z qx qy qz qw) of a reference CSV, by its header's column names."""
    if not path.is_file():
        raise ReplayError(f"--reference-file {path}: no such file")
    with open(path, newline="") as f:
        table = list(csv.DictReader(f))
    names = {name.strip().lower(): name for name in (table[0].keys() if table else [])}
    stamp_name = next((names[n] for n in ("stamp", "t", "timestamp", "time") if n in names), None)
    missing = [n for n in ("x", "y", "z", "qx", "qy", "qz", "qw") if n not in names]
    if stamp_name is None or missing:
        raise ReplayError(f"--reference-file {path}: a CSV needs the columns stamp, x, y, z, qx, qy, qz, qw "
                          f"(missing: {', '.join(missing + ([] if stamp_name else ['stamp']))})")
    try:
        rows = np.array([[float(r[stamp_name])] + [float(r[names[n]]) for n in ("x", "y", "z", "qx", "qy", "qz", "qw")]
                         for r in table])
    except ValueError as exc:
        raise ReplayError(f"--reference-file {path}: not a number: {exc}") from None
    return rows.reshape(-1, 8)


def nearest_reference(stamp: float, reference: list[tuple[float, np.ndarray]]) -> np.ndarray | None:
    if not reference:
        return None
    stamps = np.array([s for s, _ in reference])
    k = int(np.argmin(np.abs(stamps - stamp)))
    return reference[k][1] if abs(stamps[k] - stamp) <= REFERENCE_TOLERANCE_S else None


def rows(registrations: list[Registration], reference, config: RegorConfig) -> list[dict]:
    from scipy.spatial.transform import Rotation

    from ..core import rotation_error_deg, translation_error
    out = []
    for r in registrations:
        row = {"stamp": f"{r.stamp:.6f}", "accepted": r.accepted, "reason": r.reason, "seconds": f"{r.seconds:.3f}",
               "scans_fused": r.scans_fused, "registered_alone_because": r.alone, "source_up_from": r.up_from}
        if r.pose is not None:
            row.update(zip("x y z".split(), r.pose[:3, 3], strict=True))
            row.update(zip("qx qy qz qw".split(), Rotation.from_matrix(r.pose[:3, :3]).as_quat(), strict=True))
            truth = nearest_reference(r.stamp, reference)
            if truth is not None:
                turn, shift = rotation_error_deg(r.pose, truth), translation_error(r.pose, truth)
                row.update(reference_rotation_error_deg=turn, reference_translation_error_m=shift,
                           agrees=bool(turn < config.verification.max_correction_deg
                                       and shift < config.verification.max_correction))
        out.append(row)
    return out


def withheld_kinds(registrations: list[Registration]) -> list[tuple[str, int, str]]:
    """(kind, count, one example) of the relocalizations not published, most first: the gate's
    check that withheld them, or the reason with its figures blanked (not registered at all)."""
    kinds: dict[str, list[str]] = {}
    for r in registrations:
        if not r.accepted:
            kind = r.failed or re.sub(r"[-+]?\d[\d.e+-]*", "#", r.reason.split(" (")[0])
            kinds.setdefault(kind, []).append(r.reason)
    return [(kind, len(reasons), reasons[0]) for kind, reasons in sorted(kinds.items(), key=lambda kv: -len(kv[1]))]


def watchdog_rows(checks) -> list[dict]:
    return [{"stamp": f"{c.scan_stamp:.6f}", "watchdog": c.state, "reason": c.reason, "failures_in_a_row": c.failures,
             "correction_m": "" if c.correction is None else c.correction[0],
             "correction_deg": "" if c.correction is None else c.correction[1]} for c in checks]


def summary(bag: Path, registrations: list[Registration], table: list[dict], counts: dict, every: float,
            checks=()) -> str:
    registered = [r for r in table if "x" in r]
    published = [r for r in table if r["accepted"]]
    checked = [r for r in published if "agrees" in r]
    lines = [f"# regor-replay of `{bag}`", "",
             f"- {counts['scans']} scans, {counts['odometry']} odometry messages, {counts['imu']} IMU messages, "
             f"{counts['reference']} reference poses",
             f"- {len(table)} relocalizations ({'every scan' if every <= 0 else f'every {every:g} s'}); "
             f"{len(registered)} registered, **{len(published)} published**",
             f"- median {np.median([float(r['seconds']) for r in table]):.2f} s per relocalization"]
    if counts["reference"]:
        agreeing = sum(r["agrees"] for r in checked)
        lines.append(f"- against the reference: **{agreeing} of {len(checked)} published poses agree**, "
                     f"{len(checked) - agreeing} do not")
    if checks:
        states = {state: sum(c.state == state for c in checks)
                  for state in ("verified", "suspect", "lost", "unchecked")}
        lines.append(f"- the watchdog, {len(checks)} checks of the stack's pose: " +
                     ", ".join(f"{n} {state}" for state, n in states.items()))
    meant = [r for r in registrations if r.scans_fused]
    if meant:
        fused = [r for r in meant if not r.alone]
        alone: dict[str, int] = {}
        for r in meant:
            if r.alone:
                alone[r.alone] = alone.get(r.alone, 0) + 1
        lines.append(f"- scans fused along odometry: {len(fused)} relocalizations fused "
                     f"{_span([r.scans_fused for r in fused])} scans, {len(meant) - len(fused)} registered alone" +
                     ("" if not alone else ": " + ", ".join(f"{n} {why}" for why, n in
                                                            sorted(alone.items(), key=lambda kv: -kv[1]))))
    if not counts["odometry"] and meant:
        lines.append("- no odometry: every scan was registered alone (give --odom-topic to fuse scans)")
    kinds = withheld_kinds(registrations)
    if kinds:
        lines += ["", "Withheld, by kind (one example each):", ""] + [f"- {n} x {kind}: {example}"
                                                                     for kind, n, example in kinds]
    return "\n".join(lines) + "\n"


def _span(values: list[int]) -> str:
    return "no" if not values else f"{min(values)}" if min(values) == max(values) else f"{min(values)}-{max(values)}"


def picture(path: Path, surface: np.ndarray, table: list[dict], reference) -> None:
    """The map from above, framed on the robot (the reference and every pose; the map's 1-99 %
    extent when there is neither, so stray far points never shrink the robot to a corner), the
    poses, and the reference line drawn over them."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    track = np.array([T[:2, 3] for _, T in reference]).reshape(-1, 2)
    posed = np.array([[r["x"], r["y"]] for r in table if "x" in r], dtype=float).reshape(-1, 2)
    robot = np.vstack([track, posed])
    lo, hi = ((robot.min(axis=0), robot.max(axis=0)) if len(robot) else
              (np.percentile(surface[:, :2], 1, axis=0), np.percentile(surface[:, :2], 99, axis=0)))
    pad = max(PICTURE_MARGIN_M, 0.1 * float((hi - lo).max()))
    lo, hi = lo - pad, hi + pad
    fig, ax = plt.subplots(figsize=(8, 8))
    inside = surface[((surface[:, :2] >= lo) & (surface[:, :2] <= hi)).all(axis=1)]
    sample = inside[:: max(1, len(inside) // 200_000)]
    ax.scatter(sample[:, 0], sample[:, 1], s=0.4, c="0.6", linewidths=0, zorder=1, label="map")
    for accepted, agrees, colour, label in ((True, True, "tab:green", "published, agrees"),
                                            (True, False, "tab:red", "published, does not agree"),
                                            (True, None, "tab:blue", "published (no reference)"),
                                            (False, None, "tab:orange", "withheld (the pose it found)")):
        chosen = [r for r in table if "x" in r and r["accepted"] == accepted
                  and (not accepted or r.get("agrees") == agrees)]
        if chosen:
            ax.scatter([r["x"] for r in chosen], [r["y"] for r in chosen], s=16 if accepted else 10, c=colour,
                       marker="o" if accepted else "x", zorder=2, label=f"{label} ({len(chosen)})")
    if len(track):
        ax.plot(track[:, 0], track[:, 1], c="black", lw=1.2, zorder=3, label="reference")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("the map from above, with the poses replayed")
    ax.legend(loc="best", fontsize=8, markerscale=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-replay", description=__doc__.split("\n\n")[0], epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", type=Path, help="the rosbag2: its folder, or its .db3 / .mcap file")
    parser.add_argument("--map", required=True, type=Path, help="the map file (.pcd, .ply, .npy, .xyz, .bin)")
    parser.add_argument("--map-trajectory", type=Path, help="the map's TUM trajectory (default: none)")
    parser.add_argument("--scan-topic", required=True, help="the sensor_msgs/PointCloud2 topic")
    parser.add_argument("--odom-topic", help="nav_msgs/Odometry to fuse scans along, as the node's odometry "
                                             "(default: none, scans alone)")
    parser.add_argument("--imu-topic", help="sensor_msgs/Imu giving the scan's up at its stamp, as the node's "
                                            "imu_topic: the gravity prior (give the map's up with --set "
                                            "gravity.target_up='0 0 1'; default: none)")
    parser.add_argument("--reference-topic", help="poses to compare with (PoseStamped, PoseWithCovarianceStamped "
                                                  "or Odometry in the map frame; default: none)")
    parser.add_argument("--reference-file", type=Path,
                        help="poses to compare with, from a file: TUM (t x y z qx qy qz qw) or CSV with the "
                             "columns stamp, x, y, z, qx, qy, qz, qw (in the map frame; default: none)")
    parser.add_argument("--tracked-topic", help="the localization stack's pose (PoseWithCovarianceStamped, "
                                                "PoseStamped or Odometry in the map frame): the watchdog checks it "
                                                "on every scan (default: none)")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help=PRESET_HELP)
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a core or node parameter, e.g. --set accumulate_scans=3 (repeatable)")
    parser.add_argument("--every", type=float, default=0.0, metavar="SECONDS",
                        help="relocalize every this many seconds of the recording (default: every scan)")
    parser.add_argument("--base-to-sensor", metavar="'X,Y,Z,ROLL,PITCH,YAW'",
                        help="the sensor's mounting on the robot: poses are the base's (default: the scan frame's)")
    parser.add_argument("--out", required=True, type=Path, help="folder for registrations.csv, summary.md, map.png")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = parser.parse_args(argv)
    from ..ros.parameters import apply_changes, make_settings, typed_settings  # after parsing: --help at once

    try:
        values = {"mode": "map", "map_file": str(args.map), "map_trajectory_file": str(args.map_trajectory or ""),
                  "registration": "on_demand", "imu_topic": args.imu_topic or ""}
        if args.base_to_sensor:
            values.update(base_frame="base_link", base_to_sensor=args.base_to_sensor)
        config, settings = apply_changes(RegorConfig.preset(args.preset), make_settings(values),
                                         typed_settings(parse_overrides(args.set)))
        logging.basicConfig(level=logging.ERROR, format="regor-replay: %(message)s")
        topics = Topics(args.scan_topic, args.odom_topic, args.reference_topic, args.tracked_topic, args.imu_topic)
        registrations, reference, counts, prepared, checks = replay(
            args.bag, config, settings, topics, args.every, args.reference_file, progress=not args.quiet)
    except (ConfigError, RegistrationError, ReplayError) as exc:
        print(f"regor-replay: {exc}", file=sys.stderr)
        return 2
    table = rows(registrations, reference, config)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "registrations.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(table)
    if checks:
        with open(args.out / "watchdog.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=WATCHDOG_FIELDS)
            writer.writeheader()
            writer.writerows(watchdog_rows(checks))
    text = summary(args.bag, registrations, table, counts, args.every, checks)
    (args.out / "summary.md").write_text(text)
    picture(args.out / "map.png", prepared.map_view.surface, table, reference)
    print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
