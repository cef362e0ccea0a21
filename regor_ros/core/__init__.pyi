"""The core's public face as a type checker sees it (generated: regor_ros.core.public_stub())."""
from .config import (
    CHOICES as CHOICES,
    PRESETS as PRESETS,
    FeatureConfig as FeatureConfig,
    RegorConfig as RegorConfig,
    coerce as coerce,
    param as param,
)
from .errors import (
    ConfigError as ConfigError,
    RegistrationError as RegistrationError,
)
from .cloud import (
    MAX_ABS_COORDINATE as MAX_ABS_COORDINATE,
    PreparedCloud as PreparedCloud,
)
from .gate.figures import (
    Figures as Figures,
    RivalFigures as RivalFigures,
    stack as stack,
)
from .gate.judge import (
    CHECKS as CHECKS,
    Verdict as Verdict,
    ambiguity as ambiguity,
    judge as judge,
    passes as passes,
)
from .geometry import (
    attached_pose as attached_pose,
    parse_numbers as parse_numbers,
    to_matrix as to_matrix,
    transform_points as transform_points,
    unique_rows as unique_rows,
)
from .kernels import (
    warm_up as warm_up,
)
from .matching import (
    match_features as match_features,
)
from .metrics import (
    ERROR_SIGMAS_99 as ERROR_SIGMAS_99,
    GROSS_THRESHOLDS as GROSS_THRESHOLDS,
    INLIER_THRESHOLDS as INLIER_THRESHOLDS,
    correct_mask as correct_mask,
    error_sigmas as error_sigmas,
    is_gross as is_gross,
    is_success as is_success,
    random_rigid_motion as random_rigid_motion,
    rotation_error_deg as rotation_error_deg,
    translation_error as translation_error,
)
from .pipeline import (
    Candidate as Candidate,
    Correspondences as Correspondences,
    RegistrationResult as RegistrationResult,
    for_clouds_seen_from as for_clouds_seen_from,
    prepare_cloud as prepare_cloud,
    register as register,
)
from .scan_history import (
    ALONE_REASONS as ALONE_REASONS,
    AccumulationLimits as AccumulationLimits,
    ScanHistory as ScanHistory,
)
from .search_region import (
    SearchRegion as SearchRegion,
)
from .sequence import (
    ScanSequence as ScanSequence,
)
from .stillness import (
    Stillness as Stillness,
    at_rest as at_rest,
    was_still as was_still,
)
from .summary import (
    Summary as Summary,
)
from .verification import (
    Verification as Verification,
    verify as verify,
)
from .viewpoint import (
    ORIGIN as ORIGIN,
    parse_viewpoint as parse_viewpoint,
)
