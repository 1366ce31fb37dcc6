"""Pipelines built from scanreg's pieces: 3D LiDAR odometry (:class:`Odometry`), localization
in a prior map (:class:`Localizer`) and 2D scan-to-map odometry (:class:`Odometry2D`)."""

from .localizer import Localizer, Relocalization
from .odometry import AdaptiveGate, FrameResult, FrameTiming, Odometry, OdometryConfig
from .odometry2d import Frame2D, FrameTiming2D, Odometry2D, OdometryConfig2D

__all__ = [
    "AdaptiveGate",
    "Frame2D",
    "FrameResult",
    "FrameTiming",
    "FrameTiming2D",
    "Localizer",
    "Odometry",
    "Odometry2D",
    "OdometryConfig",
    "OdometryConfig2D",
    "Relocalization",
]
