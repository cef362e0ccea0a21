"""regor-verify: check a given pose of a scan in a map (or in a second scan) with Regor's quality gate.

The pose comes from anywhere (a localization stack, a SLAM back end's loop closure, another
registration): it is refined locally and judged as regor-register judges its own. Exit status: 0
verified, 1 not verified (the reason and where the data put the pose on one line), 2 the input
could not be read (one-line reason on stderr).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..core import PRESETS, ConfigError, PreparedCloud, RegistrationError, RegorConfig, parse_viewpoint
from ..io.cloud_io import FORMATS, read_cloud
from .register_cli import DEFAULT_PRESET, PRESET_HELP, parse_overrides

EPILOG = f"""examples:
  regor-verify scan.pcd map.pcd pose.txt --map-trajectory map_tum.txt --preset outdoor
  regor-verify src.npy tgt.npy T.txt --preset indoor --json

POSE: a text file with the 4x4 T_target_source (16 numbers, row by row; it maps source points into
the target frame) or 'x y z qx qy qz qw' (7 numbers, quaternion scalar last).
formats: {', '.join(FORMATS)}"""


def pose_from_numbers(numbers, name: str) -> np.ndarray:
    """T_target_source from 16 numbers (the 4x4, row by row) or 7 (x y z qx qy qz qw);
    RegistrationError naming ``name`` otherwise (verify() checks that it is rigid)."""
    from scipy.spatial.transform import Rotation
    numbers = np.asarray(numbers, dtype=np.float64).ravel()
    if len(numbers) == 16:
        return numbers.reshape(4, 4)
    if len(numbers) == 7 and np.isfinite(numbers).all() and np.linalg.norm(numbers[3:]) > 1e-9:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rotation.from_quat(numbers[3:]).as_matrix(), numbers[:3]
        return T
    raise RegistrationError(f"{name}: expected 16 numbers (a 4x4 matrix) or 7 (x y z qx qy qz qw), "
                            f"got {len(numbers)}")


def read_pose(path: str) -> np.ndarray:
    """T_target_source from a file of 16 numbers (4x4) or 7 (x y z qx qy qz qw)."""
    try:
        numbers = np.loadtxt(path, comments="#", ndmin=1)
    except (OSError, ValueError) as exc:
        raise RegistrationError(f"{path}: not a pose ({exc})") from None
    return pose_from_numbers(numbers, path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-verify", description=__doc__.split("\n\n")[0], epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", help="the scan (or cloud) the pose places")
    parser.add_argument("target", help="the map, or a second scan")
    parser.add_argument("pose", help="file with the pose to check, T_target_source (see below)")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help=PRESET_HELP)
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter, e.g. --set verification.max_correction=0.3 (repeatable)")
    parser.add_argument("--map-trajectory", metavar="TUM",
                        help="the target is a map built along this trajectory (TUM: t x y z qx qy qz qw): the "
                             "free-space check also sees the map from where it was built (default: none)")
    parser.add_argument("--source-viewpoint", default="auto", metavar="'X,Y,Z'|none",
                        help="where the source sensor sat in its cloud's frame (default: the origin)")
    parser.add_argument("--target-viewpoint", default="auto", metavar="'X,Y,Z'|none",
                        help="where the target sensor sat; 'none' for a map (default: the origin, or none "
                             "with --map-trajectory)")
    parser.add_argument("--json", action="store_true", help="print the whole result as JSON (default: one line)")
    args = parser.parse_args(argv)
    from ..core import verify  # after parsing: --help and argument errors answer without loading it
    from ..io.map_file import load_map_file

    try:
        config = RegorConfig.preset(args.preset).replace(parse_overrides(args.set))
        pose = read_pose(args.pose)
        source = read_cloud(args.source)
        target_viewpoint = parse_viewpoint(args.target_viewpoint, "--target-viewpoint")
        target: PreparedCloud | np.ndarray
        if args.map_trajectory:
            if args.target_viewpoint != "auto":
                raise RegistrationError("--target-viewpoint: a map built along --map-trajectory has no single one")
            target = load_map_file(Path(args.target), config, args.map_trajectory, cache=False).prepared
            target_viewpoint = None
        else:
            target = read_cloud(args.target)
        result = verify(source, target, pose, config,
                        source_viewpoint=parse_viewpoint(args.source_viewpoint, "--source-viewpoint"),
                        **({} if args.map_trajectory else {"target_viewpoint": target_viewpoint}))
    except (ConfigError, RegistrationError) as exc:
        print(f"regor-verify: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"transform": result.transform.tolist(), **result.summary().as_json()}, indent=2))
    else:
        moved = f" (the data move it by {result.correction_m:.2f} m and {result.correction_deg:.1f} deg)"
        print(f"verified{moved}" if result.accepted else
              f"NOT verified: {result.reason}{moved if result.within_tolerance else ''}")
    return 0 if result.accepted else 1


if __name__ == "__main__":
    raise SystemExit(main())
