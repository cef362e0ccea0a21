"""Fast DDS transport settings for large clouds in the node's own process.

With Fast DDS's default transports a cloud bigger than the 0.5 MB shared-memory segment travels
as UDP fragments through small socket buffers; the package's profile
(config/fastdds_large_data.xml) gives shared memory a 64 MB segment and UDP 16 MB buffers. The
node loads it itself unless the user chose a profile or another middleware, so ``ros2 run``
receives big clouds without an environment set up beforehand.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PROFILE_VARIABLES = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")  # Fast DDS 3, 2
FAST_DDS_RMWS = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")
PROFILE_NAME = "fastdds_large_data.xml"


def use_large_data_profile() -> str | None:
    """Point Fast DDS at the package's profile, before rclpy.init; the path used, or None when
    the user set a profile, another middleware runs, or the profile is not installed."""
    if any(os.environ.get(v) for v in PROFILE_VARIABLES):
        return None
    if os.environ.get("RMW_IMPLEMENTATION", FAST_DDS_RMWS[0]) not in FAST_DDS_RMWS:
        return None
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    try:
        path = Path(get_package_share_directory("regor_ros")) / "config" / PROFILE_NAME
    except PackageNotFoundError:
        return None
    if not path.is_file():
        return None
    os.environ[profile_variable()] = str(path)
    return str(path)


def profile_variable() -> str:
    """The variable the installed Fast DDS reads: FASTRTPS_... for Fast DDS 2 (libfastrtps,
    Humble and Jazzy), FASTDDS_... for Fast DDS 3 (libfastdds, Kilted on), which warns that the
    old name is deprecated."""
    folders = [Path(p) for p in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p]
    folders.append(Path(sys.prefix) / "lib")
    if any(next(folder.glob("libfastrtps.so*"), None) for folder in folders if folder.is_dir()):
        return PROFILE_VARIABLES[1]
    return PROFILE_VARIABLES[0]
