"""ROS-free Regor registration core: ``register(source_xyz, target_xyz, RegorConfig.preset(...))``.

The names below are the core's public face: the node, the files layer and the tools import from
here, never from the modules behind it. Each name is loaded when first asked for (PEP 562), so a
tool that only needs the configuration answers ``--help`` without loading open3d, scipy's spatial
modules and the compiled kernels. To a type checker they are what they are: ``__init__.pyi``
imports each from its home (``public_stub()`` writes it; a test keeps it in step with _HOMES).
"""
import os
from importlib import import_module

# OpenMP threads waiting for the next kernel spin for some microseconds, not GNU's default of
# about a millisecond: on a robot computer's two cores shared with other processes the spinning
# threads took the cores the work needed (results/HISTORY.md, "Figures from the code"). GNU's
# runtime (numba's kernels, FAISS's) reads it when it loads, which is after this package is
# imported unless the process loaded it before; a user's own setting, or OMP_WAIT_POLICY, stands.
os.environ.setdefault("GOMP_SPINCOUNT", "10000")

_HOMES = {
    "config": ("CHOICES", "PRESETS", "FeatureConfig", "RegorConfig", "coerce", "param"),
    "errors": ("ConfigError", "RegistrationError"),
    "cloud": ("MAX_ABS_COORDINATE", "PreparedCloud"),
    "gate.figures": ("Figures", "RivalFigures", "stack"),
    "gate.judge": ("CHECKS", "Verdict", "ambiguity", "judge", "passes"),
    "geometry": ("attached_pose", "parse_numbers", "to_matrix", "transform_points", "unique_rows"),
    "kernels": ("warm_up",),
    "matching": ("match_features",),
    "metrics": ("ERROR_SIGMAS_99", "GROSS_THRESHOLDS", "INLIER_THRESHOLDS", "correct_mask", "error_sigmas",
                "is_gross", "is_success", "random_rigid_motion", "rotation_error_deg", "translation_error"),
    "pipeline": ("Candidate", "Correspondences", "RegistrationResult", "for_clouds_seen_from", "prepare_cloud",
                 "register"),
    "scan_history": ("ALONE_REASONS", "AccumulationLimits", "ScanHistory"),
    "search_region": ("SearchRegion",),
    "sequence": ("ScanSequence",),
    "stillness": ("Stillness", "at_rest", "was_still"),
    "summary": ("Summary",),
    "verification": ("Verification", "verify"),
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


def public_stub() -> str:
    """The text of __init__.pyi: every public name imported from its home, for type checkers."""
    lines = ['"""The core\'s public face as a type checker sees it (generated: regor_ros.core.public_stub())."""']
    for module, names in _HOMES.items():
        lines += [f"from .{module} import ("] + [f"    {name} as {name}," for name in names] + [")"]
    return "\n".join(lines) + "\n"
