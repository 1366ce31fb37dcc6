"""Pipelines built from scanreg's pieces: 2D scan-to-map odometry (:class:`Odometry2D`)."""

from .odometry2d import Frame2D, FrameTiming2D, Odometry2D, OdometryConfig2D

__all__ = ["Frame2D", "FrameTiming2D", "Odometry2D", "OdometryConfig2D"]
