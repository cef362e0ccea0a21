"""regor-replay: how register_node would do on your own recording, before wiring anything.

Reads a rosbag2 (sqlite3 or MCAP; the rosbags library, no ROS install) and runs the node's own
localizer on it as fast as the CPU allows: scans fused along the bag's odometry as the node fuses
them, a relocalization in the map every --every seconds of the recording (default: every scan),
and with --tracked-topic the watchdog's check of the localization stack's pose on every scan
(DIR/watchdog.csv; lost, the robot is relocalized). Writes DIR/registrations.csv (the scan frame's
pose in the map frame, or the base's with --base-to-sensor; errors against --reference-topic where
given), DIR/summary.md and DIR/map.png
(the map from above, the reference trajectory and every pose: green where the reference agrees).
Exit status: 0 replayed, 2 the bag, a topic or the map cannot be used (one line).
"""
from __future__ import annotations

import argparse
import csv
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import PRESETS, ConfigError, RegistrationError, RegorConfig

EPILOG = """examples:
  regor-replay drive.mcap --map site.pcd --map-trajectory site_tum.txt --scan-topic /points \\
      --odom-topic /odom --reference-topic /ground_truth --preset outdoor --out replay/
  regor-replay bag_folder --map site.pcd --scan-topic /livox/lidar --every 5 --out replay/"""
REFERENCE_TOLERANCE_S = 0.1   # a reference pose counts for a scan when this close to its stamp
SCAN_TYPE = "sensor_msgs/msg/PointCloud2"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
REFERENCE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped", ODOMETRY_TYPE)
FIELDS = ["stamp", "accepted", "reason", "x", "y", "z", "qx", "qy", "qz", "qw", "seconds",
          "reference_rotation_error_deg", "reference_translation_error_m", "agrees"]
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


def replay(bag: Path, config: RegorConfig, settings, scan_topic: str, odom_topic: str | None,
           reference_topic: str | None, every: float, tracked_topic: str | None = None):
    """(registrations, reference poses (stamp, 4x4), counts, the map as prepared, the watchdog's
    checks) of one bag replayed through the node's localizer (its map loaded as the node's
    configure loads it)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from ..ros.localizer import Localizer
    from ..ros.messages import matrix_from_pose, stamp_nanoseconds, stamp_seconds
    from ..ros.pointcloud import cloud_to_xyz
    from ..ros.watchdog import TrackedPose
    outcomes, checks = {}, []
    localizer = Localizer(config, settings, logging.getLogger("regor-replay"),
                          lambda outcome: outcomes.__setitem__(outcome.source.serial, outcome),
                          lambda prepared, frame: None, checks.append)
    localizer.configure()
    registrations, reference, counts = [], [], {"scans": 0, "odometry": 0, "reference": 0, "tracked": 0}
    if not Path(bag).exists():
        raise ReplayError(f"{bag}: no such file or folder")
    # a bag written before rosbag2 stored its message definitions: the standard ones stand in
    reader = AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except Exception as exc:  # rosbags' errors for a missing, truncated or foreign file
        raise ReplayError(f"{bag}: cannot be read as a rosbag2 (sqlite3 or MCAP): {exc}") from None
    try:
        scans = _connections(reader, scan_topic, (SCAN_TYPE,), "--scan-topic")
        odometry = _connections(reader, odom_topic, (ODOMETRY_TYPE,), "--odom-topic")
        references = _connections(reader, reference_topic, REFERENCE_TYPES, "--reference-topic")
        tracked = _connections(reader, tracked_topic, REFERENCE_TYPES, "--tracked-topic")
        last = -np.inf
        try:
            for connection, _, raw in reader.messages(connections=scans + odometry + references + tracked):
                message = reader.deserialize(raw, connection.msgtype)
                stamp = stamp_seconds(message.header)
                if connection in odometry:
                    counts["odometry"] += 1
                    T_odom_scan = matrix_from_pose(message.pose.pose) @ settings.odometry_extrinsic()
                    localizer.context.add_odometry(stamp, T_odom_scan)
                elif connection in references:
                    counts["reference"] += 1
                    reference.append((stamp, _pose_of(message, connection.msgtype)))
                elif connection in tracked:
                    counts["tracked"] += 1
                    localizer.track_pose(TrackedPose(stamp, message.header.frame_id,
                                                     _pose_of(message, connection.msgtype)))
                else:
                    counts["scans"] += 1
                    try:
                        points = cloud_to_xyz(message)
                    except RegistrationError as exc:
                        raise ReplayError(f"{scan_topic}: a PointCloud2 at {stamp:.3f} s cannot be read: "
                                          f"{exc}") from None
                    due = stamp >= last + every
                    start = time.perf_counter()
                    answer = localizer.replay(message.header.frame_id, stamp_nanoseconds(message.header), points,
                                              due, check_it=bool(tracked))
                    if answer is not None:
                        last = stamp
                        outcome = outcomes.pop(answer.serial, None)
                        pose = None if outcome is None else outcome.result.transform
                        if outcome is not None and outcome.T_sensor_base is not None:
                            pose = pose @ outcome.T_sensor_base
                        reason = "" if answer.accepted else answer.text
                        registrations.append(Registration(stamp, answer.accepted, reason, pose,
                                                          time.perf_counter() - start))
        except ReplayError:
            raise
        except Exception as exc:  # a message the bag holds but cannot give back whole
            raise ReplayError(f"{bag}: reading stopped: {type(exc).__name__}: {exc}") from None
    finally:
        reader.close()
    if not counts["scans"]:
        raise ReplayError(f"{scan_topic}: no messages in the bag")
    return registrations, reference, counts, localizer.maps.prepared, checks


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
        row = {"stamp": f"{r.stamp:.6f}", "accepted": r.accepted, "reason": r.reason, "seconds": f"{r.seconds:.3f}"}
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


def watchdog_rows(checks) -> list[dict]:
    return [{"stamp": f"{c.scan_stamp:.6f}", "watchdog": c.state, "reason": c.reason, "failures_in_a_row": c.failures,
             "correction_m": "" if c.correction is None else c.correction[0],
             "correction_deg": "" if c.correction is None else c.correction[1]} for c in checks]


def summary(bag: Path, table: list[dict], counts: dict, every: float, checks=()) -> str:
    registered = [r for r in table if "x" in r]
    published = [r for r in table if r["accepted"]]
    checked = [r for r in published if "agrees" in r]
    lines = [f"# regor-replay of `{bag}`", "",
             f"- {counts['scans']} scans, {counts['odometry']} odometry messages, "
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
    if not counts["odometry"]:
        lines.append("- no odometry: every scan was registered alone (give --odom-topic to fuse scans)")
    reasons: dict[str, int] = {}
    for r in table:
        if not r["accepted"]:
            reason = r["reason"].split(": ", 1)[-1].split(" (")[0]
            reasons[reason] = reasons.get(reason, 0) + 1
    if reasons:
        lines += ["", "Withheld, by reason:", ""] + [f"- {n} x {reason}" for reason, n in
                                                     sorted(reasons.items(), key=lambda item: -item[1])]
    return "\n".join(lines) + "\n"


def picture(path: Path, surface: np.ndarray, table: list[dict], reference) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 8))
    sample = surface[:: max(1, len(surface) // 200_000)]
    ax.scatter(sample[:, 0], sample[:, 1], s=0.2, c="0.75", linewidths=0)
    if reference:
        track = np.array([T[:3, 3] for _, T in reference])
        ax.plot(track[:, 0], track[:, 1], c="0.3", lw=1, label="reference")
    for accepted, agrees, colour, label in ((True, True, "tab:green", "published, agrees"),
                                            (True, False, "tab:red", "published, does not agree"),
                                            (True, None, "tab:blue", "published (no reference)"),
                                            (False, None, "0.5", "withheld")):
        chosen = [r for r in table if "x" in r and r["accepted"] == accepted and r.get("agrees") == agrees]
        if chosen:
            ax.scatter([r["x"] for r in chosen], [r["y"] for r in chosen], s=14 if accepted else 6, c=colour,
                       marker="o" if accepted else "x", label=f"{label} ({len(chosen)})")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
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
    parser.add_argument("--odom-topic", help="nav_msgs/Odometry to fuse scans along (default: none, scans alone)")
    parser.add_argument("--reference-topic", help="poses to compare with (PoseStamped, PoseWithCovarianceStamped "
                                                  "or Odometry in the map frame; default: none)")
    parser.add_argument("--tracked-topic", help="the localization stack's pose (PoseWithCovarianceStamped, "
                                                "PoseStamped or Odometry in the map frame): the watchdog checks it "
                                                "on every scan (default: none)")
    parser.add_argument("--preset", choices=PRESETS, default="outdoor", help="(default: %(default)s)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a core or node parameter, e.g. --set accumulate_scans=3 (repeatable)")
    parser.add_argument("--every", type=float, default=0.0, metavar="SECONDS",
                        help="relocalize every this many seconds of the recording (default: every scan)")
    parser.add_argument("--base-to-sensor", metavar="'X,Y,Z,ROLL,PITCH,YAW'",
                        help="the sensor's mounting on the robot: poses are the base's (default: the scan frame's)")
    parser.add_argument("--out", required=True, type=Path, help="folder for registrations.csv, summary.md, map.png")
    args = parser.parse_args(argv)
    from ..ros.parameters import apply_changes, make_settings, typed_settings  # after parsing: --help at once
    from .register_cli import parse_overrides

    try:
        values = {"mode": "map", "map_file": str(args.map), "map_trajectory_file": str(args.map_trajectory or ""),
                  "registration": "on_demand"}
        if args.base_to_sensor:
            values.update(base_frame="base_link", base_to_sensor=args.base_to_sensor)
        config, settings = apply_changes(RegorConfig.preset(args.preset), make_settings(values),
                                         typed_settings(parse_overrides(args.set)))
        logging.basicConfig(level=logging.ERROR, format="regor-replay: %(message)s")
        registrations, reference, counts, prepared, checks = replay(
            args.bag, config, settings, args.scan_topic, args.odom_topic, args.reference_topic, args.every,
            args.tracked_topic)
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
    text = summary(args.bag, table, counts, args.every, checks)
    (args.out / "summary.md").write_text(text)
    picture(args.out / "map.png", prepared.map_view.surface, table, reference)
    print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
