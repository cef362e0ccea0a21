"""ROS-free Regor registration core: ``register(source_xyz, target_xyz, RegorConfig.preset(...))``.

The names below are the core's public face: the node, the files layer and the tools import from
here, never from the modules behind it.
"""
from .config import CHOICES, PRESETS, FeatureConfig, RegorConfig, param
from .errors import ConfigError, RegistrationError
from .features import MAX_ABS_COORDINATE, PreparedCloud
from .geometry import attached_pose, parse_numbers, to_matrix, transform_points
from .kernels import warm_up
from .matching import match_features
from .metrics import (
                      ERROR_SIGMAS_99,
                      INLIER_THRESHOLDS,
                      correct_mask,
                      error_sigmas,
                      is_success,
                      random_rigid_motion,
                      rotation_error_deg,
                      translation_error,
)
from .pipeline import Candidate, Correspondences, RegistrationResult, for_clouds_seen_from, prepare_cloud, register
from .scan_history import AccumulationLimits, ScanHistory
from .search_region import SearchRegion
from .sequence import ScanSequence
from .verification import Rival, ambiguity
from .visibility import ORIGIN, parse_viewpoint

__all__ = ["AccumulationLimits", "CHOICES", "Candidate", "ConfigError", "Correspondences", "ERROR_SIGMAS_99",
           "FeatureConfig", "INLIER_THRESHOLDS", "MAX_ABS_COORDINATE", "ORIGIN", "PRESETS", "PreparedCloud",
           "RegistrationError", "RegistrationResult", "RegorConfig", "Rival", "ScanHistory", "ScanSequence",
           "SearchRegion", "ambiguity", "attached_pose", "correct_mask", "error_sigmas", "for_clouds_seen_from",
           "is_success", "match_features", "param", "parse_numbers", "parse_viewpoint", "prepare_cloud",
           "random_rigid_motion", "register", "rotation_error_deg", "to_matrix", "transform_points",
           "translation_error", "warm_up"]
