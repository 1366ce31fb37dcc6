"""scanreg: 2D/3D LiDAR scan registration that says how far to trust each estimate.

Conventions: poses are ``T_target_source`` (``p_T = R p_S + t``); tangent vectors are
translation-first and perturb on the right (``T @ exp(δ)``); see :mod:`scanreg.transform`.
"""

from . import preprocess, simulate
from ._core import __version__
from .correlative import (
    CorrelativeGrid,
    CorrelativeResult,
    match_correlative,
    prepare_correlative,
)
from .deskew import deskew
from .local_map import LocalMap
from .ndt import NdtResult, NdtTarget, match_ndt, prepare_ndt
from .paired import PairedAlignment, align_paired
from .pipeline.localizer import Localizer, Relocalization
from .pipeline.odometry import FrameResult, Odometry, OdometryConfig
from .quality import Conditioning, ResidualStats, WeakDirection
from .register import RegistrationResult, RegistrationSettings, RegistrationTiming, register
from .target import PreparedTarget, prepare
from .transform import SE2, SE3

__all__ = [
    "SE2",
    "SE3",
    "Conditioning",
    "CorrelativeGrid",
    "CorrelativeResult",
    "FrameResult",
    "LocalMap",
    "Localizer",
    "NdtResult",
    "NdtTarget",
    "Odometry",
    "OdometryConfig",
    "PairedAlignment",
    "PreparedTarget",
    "RegistrationResult",
    "RegistrationSettings",
    "RegistrationTiming",
    "Relocalization",
    "ResidualStats",
    "WeakDirection",
    "__version__",
    "align_paired",
    "deskew",
    "match_correlative",
    "match_ndt",
    "prepare",
    "prepare_correlative",
    "prepare_ndt",
    "preprocess",
    "register",
    "simulate",
]
