"""Does regor-replay give the same poses whatever order a robot logged its messages in, and what do
odometry and an IMU buy a recording?

Each shared sequence with consecutive scans (revisit/, maps/, xseason/) is written as a robot's
rosbag2 (regor_ros.bench.robot_recording) several ways: odometry logged after its scan with the
scan's stamp (as a lidar-inertial odometry logs it), with it, before it, as 50 Hz wheel odometry,
none; and a 200 Hz IMU reporting no orientation, its up the truth's tilted by 3 deg in a random
direction each scan (the map's z as the map's up). Each is replayed with regor-replay's own entry
point, every scan relocalized, scored against the truth on /truth. Writes a table (markdown) and
the per-scan rows (CSV, gzip) to --out.

    python lab/replay_orders.py --data ../shared/data --out results/replay_orders
"""
from __future__ import annotations

import argparse
import csv
import gzip
import tempfile
from pathlib import Path

import numpy as np

from regor_ros.bench.robot_recording import Recording, load_recorded_sequence, write_recording
from regor_ros.tools.replay import main as replay

SEQUENCES = ("revisit/avia_hku2_loop", "maps/fastlio_avia_hku2", "maps/scaloam_mulran_kaist03",
             "xseason/eth_gazebo_summer_winter")
IMU = {"imu_rate": 200.0, "imu_tilt_deg": 3.0}
VARIANTS = {   # name: (how the robot logged it, regor-replay's extra arguments)
    "LIO odometry after its scan": (Recording(odometry="after"), ["--odom-topic", "/odom"]),
    "odometry with its scan": (Recording(odometry="with"), ["--odom-topic", "/odom"]),
    "odometry before its scan": (Recording(odometry="before"), ["--odom-topic", "/odom"]),
    "50 Hz wheel odometry, after": (Recording(odometry="after", odometry_rate=50.0), ["--odom-topic", "/odom"]),
    "no odometry": (Recording(odometry=None), []),
    "no odometry, IMU (3 deg)": (Recording(odometry=None, **IMU),
                                 ["--imu-topic", "/imu", "--set", "gravity.target_up=0 0 1"]),
    "LIO odometry after, IMU (3 deg)": (Recording(odometry="after", **IMU),
                                        ["--odom-topic", "/odom", "--imu-topic", "/imu",
                                         "--set", "gravity.target_up=0 0 1"]),
}
SAME_POSE = ("LIO odometry after its scan", "odometry with its scan", "odometry before its scan")


def run(folder: Path, sequence, name: str, variant: str, work: Path) -> list[dict]:
    recording, extra = VARIANTS[variant]
    tag = f"{name.replace('/', '_')}_{list(VARIANTS).index(variant)}"
    bag = write_recording(work / tag, sequence, recording)
    out = work / f"{tag}_out"
    code = replay([str(bag), "--map", str(folder / "map.npy"), "--map-trajectory", str(folder / "map_trajectory.txt"),
                   "--scan-topic", "/points", "--reference-topic", "/truth", "--preset", "outdoor",
                   "--set", "map_cache=false", "--quiet", "--out", str(out), *extra])
    assert code == 0, (name, variant)
    with open(out / "registrations.csv") as f:
        return [{"sequence": name, "variant": variant, **row} for row in csv.DictReader(f)]


def tally(rows: list[dict]) -> dict:
    published = [r for r in rows if r["accepted"] == "True"]
    return {"scans": len(rows), "published": len(published),
            "wrong": sum(r["agrees"] != "True" for r in published),
            "alone": sum(r["scans_fused"] == "1" for r in rows),
            "median_s": float(np.median([float(r["seconds"]) for r in rows]))}


def same_poses(rows: list[dict], name: str) -> bool:
    """The three orders of one sequence: the same verdicts and poses, row for row."""
    by = {v: [(r["accepted"], r["x"], r["y"], r["z"], r["qw"]) for r in rows
              if r["sequence"] == name and r["variant"] == v] for v in SAME_POSE}
    return by[SAME_POSE[0]] == by[SAME_POSE[1]] == by[SAME_POSE[2]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as work:
        for name in SEQUENCES:
            sequence = load_recorded_sequence(args.data / name)   # read once, written each way
            for variant in VARIANTS:
                rows += run(args.data / name, sequence, name, variant, Path(work))
                print(name, variant, tally([r for r in rows if r["sequence"] == name and r["variant"] == variant]),
                      flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with gzip.open(args.out / "registrations.csv.gz", "wt", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = ["| sequence | recording | scans | published | wrong | registered alone | median s |",
             "|---|---|---|---|---|---|---|"]
    for name in SEQUENCES:
        for variant in VARIANTS:
            t = tally([r for r in rows if r["sequence"] == name and r["variant"] == variant])
            lines.append(f"| {name} | {variant} | {t['scans']} | {t['published']} | {t['wrong']} | {t['alone']} | "
                         f"{t['median_s']:.2f} |")
    lines += ["", "Odometry logged before, with and after its scans gives the same verdicts and poses: " +
              ", ".join(f"{name} {'yes' if same_poses(rows, name) else 'NO'}" for name in SEQUENCES)]
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
