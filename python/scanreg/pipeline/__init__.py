"""Pipelines built from scanreg's pieces: 3D LiDAR odometry (:class:`Odometry`) and 2D
scan-to-map odometry (:class:`Odometry2D`)."""

from .odometry import AdaptiveGate, FrameResult, FrameTiming, Odometry, OdometryConfig
from .odometry2d import Frame2D, FrameTiming2D, Odometry2D, OdometryConfig2D

__all__ = [
    "AdaptiveGate",
    "Frame2D",
    "FrameResult",
    "FrameTiming",
    "FrameTiming2D",
    "Odometry",
    "Odometry2D",
    "OdometryConfig",
    "OdometryConfig2D",
]
