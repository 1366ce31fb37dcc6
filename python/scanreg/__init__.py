"""scanreg: 2D/3D LiDAR scan registration that says how far to trust each estimate.

Conventions: poses are ``T_target_source`` (``p_T = R p_S + t``); tangent vectors are
translation-first and perturb on the right (``T @ exp(δ)``); see :mod:`scanreg.transform`.
"""

import importlib
from typing import TYPE_CHECKING, Any

from . import preprocess, simulate
from ._version import __version__
from .budget import MemoryBudgetExceeded, memory_budget, set_memory_budget
from .correlative import (
    CorrelativeGrid,
    CorrelativeResult,
    match_correlative,
    prepare_correlative,
)
from .degeneracy import Degeneracy
from .deskew import deskew
from .global_registration import GlobalHypothesis, GlobalRegistrationResult, register_global
from .local_map import LocalMap
from .ndt import NdtResult, NdtTarget, match_ndt, prepare_ndt
from .paired import PairedAlignment, align_paired
from .pipeline.localizer import Localizer, Relocalization
from .pipeline.odometry import FrameResult, Odometry, OdometryConfig
from .quality import Conditioning, ResidualStats, WeakDirection, transform_covariance
from .register import (
    RegistrationResult,
    RegistrationSettings,
    RegistrationTiming,
    SamplingCovariance,
    register,
    sampling_covariance,
)
from .target import PreparedTarget, prepare
from .threads import get_num_threads, set_num_threads
from .transform import SE2, SE3
from .trust import CovarianceEstimates
from .verdict import QualityReport, Verdict, VerdictThresholds

__all__ = [
    "SE2",
    "SE3",
    "Conditioning",
    "CorrelativeGrid",
    "CorrelativeResult",
    "CovarianceEstimates",
    "Degeneracy",
    "FrameResult",
    "GlobalHypothesis",
    "GlobalRegistrationResult",
    "LocalMap",
    "Localizer",
    "MemoryBudgetExceeded",
    "NdtResult",
    "NdtTarget",
    "Odometry",
    "OdometryConfig",
    "PairedAlignment",
    "PreparedTarget",
    "QualityReport",
    "RegistrationResult",
    "RegistrationSettings",
    "RegistrationTiming",
    "Relocalization",
    "ResidualStats",
    "SamplingCovariance",
    "SavedMap",
    "Verdict",
    "VerdictThresholds",
    "WeakDirection",
    "__version__",
    "align_paired",
    "deskew",
    "get_num_threads",
    "match_correlative",
    "match_ndt",
    "memory_budget",
    "prepare",
    "prepare_correlative",
    "prepare_ndt",
    "preprocess",
    "register",
    "register_global",
    "sampling_covariance",
    "set_memory_budget",
    "set_num_threads",
    "simulate",
    "transform_covariance",
]

# Submodules a user reaches as ``scanreg.io.…`` after a plain ``import scanreg``, loaded on first
# access: ``io`` and ``eval`` pull in readers and tables that most registration code never uses.
_LAZY_SUBMODULES = frozenset(
    {
        "batch",
        "config",
        "eval",
        "interop",
        "io",
        "pipeline",
        "place",
        "plot",
        "quality",
        "report",
        "robust",
        "verdict",
    }
)

#: Names loaded on first access for the same reason: ``scanreg.SavedMap`` reads map folders.
_LAZY_ATTRIBUTES = {"SavedMap": "saved_map"}

if TYPE_CHECKING:
    from . import (  # noqa: F401
        batch,
        config,
        eval,
        interop,
        io,
        pipeline,
        place,
        plot,
        quality,
        report,
        robust,
        verdict,
    )
    from .saved_map import SavedMap


def __getattr__(name: str) -> Any:
    if name in _LAZY_ATTRIBUTES:
        value = getattr(importlib.import_module(f".{_LAZY_ATTRIBUTES[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in _LAZY_SUBMODULES:
        module = importlib.import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    raise AttributeError(f"module 'scanreg' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _LAZY_SUBMODULES | set(_LAZY_ATTRIBUTES))
