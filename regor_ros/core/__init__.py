"""ROS-free Regor registration core: ``register(source_xyz, target_xyz, RegorConfig.preset(...))``.

The names below are the core's public face: the node, the files layer and the tools import from
here, never from the modules behind it. Each name is loaded when first asked for (PEP 562), so a
tool that only needs the configuration answers ``--help`` without loading open3d, scipy's spatial
modules and the compiled kernels.
"""
import os
from importlib import import_module

# OpenMP threads waiting for work sleep instead of spinning: GNU's runtime spins first, and on a
# robot computer's two cores shared with other processes a spinning thread takes the core the work
# needs (a 3DMatch pair beside one busy process: about 2 s instead of 0.8 s). The runtimes (numba's
# kernels, FAISS's) read it when they load, which is after this package is imported unless the
# process loaded them before; a user's own setting stands.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

_HOMES = {
    "config": ("CHOICES", "PRESETS", "FeatureConfig", "RegorConfig", "param"),
    "errors": ("ConfigError", "RegistrationError"),
    "cloud": ("MAX_ABS_COORDINATE", "PreparedCloud"),
    "gate.figures": ("Figures", "RivalFigures", "stack"),
    "gate.judge": ("CHECKS", "Verdict", "ambiguity", "judge", "passes"),
    "geometry": ("attached_pose", "parse_numbers", "to_matrix", "transform_points", "unique_rows"),
    "kernels": ("warm_up",),
    "matching": ("match_features",),
    "metrics": ("ERROR_SIGMAS_99", "INLIER_THRESHOLDS", "correct_mask", "error_sigmas", "is_success",
                "random_rigid_motion", "rotation_error_deg", "translation_error"),
    "pipeline": ("Candidate", "Correspondences", "RegistrationResult", "for_clouds_seen_from", "prepare_cloud",
                 "register"),
    "scan_history": ("AccumulationLimits", "ScanHistory"),
    "search_region": ("SearchRegion",),
    "sequence": ("ScanSequence",),
    "viewpoint": ("ORIGIN", "parse_viewpoint"),
}
_HOME_OF = {name: module for module, names in _HOMES.items() for name in names}
__all__ = sorted(_HOME_OF)


def __getattr__(name: str):
    if name not in _HOME_OF:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_HOME_OF[name]}", __name__), name)
    globals()[name] = value   # asked once: later lookups are plain attribute reads
    return value


def __dir__():
    return __all__
