"""Does a sensor that turns during its sweep still get its fused pose published?

#73's real shaken walk (held out) had three fused queries withheld by free space, 0.3-3.8 deg off:
its shake is distortion inside each scan, which the benchmark's shaken sequences (each older
scan's odometry turned rigidly, regor-bench's map benchmark) do not make. This distorts every scan
of each fused query of the shared sequences as a sensor turning at a steady rate through its sweep
would leave it without deskew: a point taken at time t of the sweep (t in [0, 1]) is turned by
(t - 1/2) x DEGREES about an axis drawn per scan (seeded), through the sensor. A spinning sensor's
time is its azimuth (a scan that spans more than half a turn); a narrow sensor's, the order of its
points in the file. The newest scan is distorted too: the map sees all of it.

Usage: python lab/distorted_sweeps.py --out OUT.csv --degrees 0 4 8 --draws 3 SEQUENCE_FOLDER...
(each draw turns every scan about other axes); with --coherent, every scan of a sequence turns
about the same axis (a shake that keeps its rhythm across scans: they then agree with each other)
"""
import argparse
import csv
import sys
import zlib
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from regor_ros.bench.datasets import load_sequence
from regor_ros.core import (
    RegorConfig,
    ScanSequence,
    is_success,
    prepare_cloud,
    register,
    rotation_error_deg,
    translation_error,
    warm_up,
)

SPINNING_SPAN_DEG = 180.0   # a scan whose azimuths span more than this was swept by a spinning sensor
SEED = 73


def sweep_time(scan: np.ndarray) -> np.ndarray:
    """Each point's time in its sweep, in [0, 1]."""
    azimuth = np.degrees(np.arctan2(scan[:, 1], scan[:, 0]))
    if np.ptp(azimuth) > SPINNING_SPAN_DEG:
        return (azimuth + 180.0) / 360.0
    return np.arange(len(scan)) / max(len(scan) - 1, 1)


def random_axis(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return axis / np.linalg.norm(axis)


def distorted(scan: np.ndarray, degrees: float, axis: np.ndarray) -> np.ndarray:
    """``scan`` as a sensor turning by ``degrees`` through its sweep about ``axis`` leaves it."""
    turns = Rotation.from_rotvec(np.radians(degrees) * (sweep_time(scan) - 0.5)[:, None] * axis).as_matrix()
    return np.einsum("nij,nj->ni", turns, scan)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--degrees", nargs="+", type=float, required=True)
    parser.add_argument("--draws", type=int, default=1)
    parser.add_argument("--coherent", action="store_true")
    args = parser.parse_args(argv)
    warm_up()
    config = RegorConfig.preset("outdoor")
    rows = []
    for folder in args.folders:
        cloud, trajectory, queries = load_sequence(folder)
        prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
        for query, amount, draw in ((q, a, d) for q in queries if q.history is not None
                                    for a in args.degrees for d in range(args.draws)):
            named = zlib.crc32(f"{folder.name}/{query.id}".encode())
            rng = np.random.default_rng([SEED, draw, int(amount * 10), named])
            shared = random_axis(rng)
            scans = [distorted(scan, amount, shared if args.coherent else random_axis(rng))
                     for scan in query.history.scans]
            result = register(ScanSequence(scans, query.history.poses, query.history.viewpoint), prepared, config)
            rows.append({"sequence": folder.name, "query": query.id, "degrees": amount, "draw": draw,
                         "coherent": args.coherent, "scans": len(scans),
                         "correct": bool(is_success(result.transform, query.truth, "outdoor")),
                         "published": bool(result.accepted), "failed_check": result.verdict.failed,
                         "rotation_error_deg": rotation_error_deg(result.transform, query.truth),
                         "translation_error_m": translation_error(result.transform, query.truth),
                         "free_space_source": result.figures.free_space_source,
                         "free_space_target": result.figures.free_space_target,
                         "shake_bins": result.visibility.shake_bins})
            print(rows[-1], flush=True)
    with args.out.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print("| sequence | turn per sweep, deg | fused queries | correct | published correct | published WRONG "
          "| correct withheld (check) |\n|---|---|---|---|---|---|---|")
    for folder in args.folders:
        for amount in args.degrees:
            group = [r for r in rows if r["sequence"] == folder.name and r["degrees"] == amount]
            correct = [r for r in group if r["correct"]]
            withheld = ", ".join(sorted(r["failed_check"] for r in correct if not r["published"])) or "-"
            print(f"| {folder.name} | {amount:g} | {len(group)} | {len(correct)} | "
                  f"{sum(r['published'] for r in correct)} | {sum(r['published'] and not r['correct'] for r in group)} "
                  f"| {withheld} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
