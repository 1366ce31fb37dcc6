"""Pipelines built from scanreg's pieces: 3D LiDAR odometry (:class:`Odometry`), localization
in a prior map (:class:`Localizer`, 3D; :class:`Localizer2D`, 2D, with global relocalization),
2D scan-to-map odometry (:class:`Odometry2D`) and 2D mapping with loop closure on a pose graph
(:class:`Mapper`; needs ``scanreg[mapping]``)."""

from .localizer import Localizer, Relocalization
from .localizer2d import GlobalFix, LocalizationConfig2D, Localizer2D
from .mapping import LoopRecord, Mapper, MappingConfig, MappingResult, run_mapping
from .odometry import AdaptiveGate, FrameResult, FrameTiming, Odometry, OdometryConfig
from .odometry2d import Frame2D, FrameTiming2D, Odometry2D, OdometryConfig2D

__all__ = [
    "AdaptiveGate",
    "Frame2D",
    "FrameResult",
    "FrameTiming",
    "FrameTiming2D",
    "GlobalFix",
    "LocalizationConfig2D",
    "Localizer",
    "Localizer2D",
    "LoopRecord",
    "Mapper",
    "MappingConfig",
    "MappingResult",
    "Odometry",
    "Odometry2D",
    "OdometryConfig",
    "OdometryConfig2D",
    "Relocalization",
    "run_mapping",
]
