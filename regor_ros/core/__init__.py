"""ROS-free Regor registration core: ``register(source_xyz, target_xyz, RegorConfig.preset(...))``."""
from .config import ConfigError, RegorConfig
from .features import PreparedCloud, RegistrationError
from .pipeline import Correspondences, RegistrationResult, prepare_cloud, register
from .search_region import SearchRegion
from .sequence import ScanSequence

__all__ = ["ConfigError", "Correspondences", "PreparedCloud", "RegistrationError",
           "RegistrationResult", "RegorConfig", "ScanSequence", "SearchRegion", "prepare_cloud", "register"]
