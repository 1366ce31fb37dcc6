"""Pipelines built from scanreg's pieces: 3D LiDAR odometry (:class:`Odometry`), localization
in a prior map (:class:`Localizer`, 3D; :class:`Localizer2D`, 2D, with global relocalization),
2D scan-to-map odometry (:class:`Odometry2D`), mapping with loop closure on a pose graph
(:class:`Mapper` 2D, :class:`Mapper3D` 3D; needs ``scanreg[mapping]``) and 3D localization in a
saved map with global relocalization (:class:`MapLocalizer`); :func:`write_outputs` writes a
mapping run's folder (what ``scanreg map`` writes); :func:`open_scan_log` / :func:`scan_log`
read a CARMEN log or a LaserScan bag as the 2D pipelines' :class:`~scanreg.io.ScanLog`;
:func:`check_map` judges a 2D map's consistency without ground truth.
:func:`extend_map` joins a new run to a saved map, :func:`merge_maps` two saved maps made in
unrelated frames (2D or 3D; one graph, agreeing inter-session loops).
:func:`run_odometry_to_folder`, :func:`run_mapping_to_folder`,
:func:`run_localization_to_folder` and :func:`merge_maps_to_folder` are what ``scanreg
odometry|map|localize|merge`` do, callable the same way from Python (:mod:`.commands`)."""

from .commands import (
    MappingStopped,
    merge_maps_to_folder,
    registration_summary,
    run_localization_to_folder,
    run_mapping_to_folder,
    run_odometry_to_folder,
)
from .extend import extend_map
from .join import JoinReport
from .localizer import Localizer, Relocalization
from .localizer2d import GlobalFix, LocalizationConfig2D, Localizer2D
from .map_check import MapCheck, MapCheckSettings, check_map
from .map_localizer import GlobalFix3D, MapLocalizer
from .mapping import LoopRecord, Mapper, MappingConfig, MappingResult, run_mapping
from .mapping3d import Mapper3D, MappingConfig3D, run_mapping_3d
from .mapping_output import write_outputs
from .merge import merge_maps
from .odometry import AdaptiveGate, FrameResult, FrameTiming, Odometry, OdometryConfig
from .odometry2d import Frame2D, FrameTiming2D, Odometry2D, OdometryConfig2D
from .scan_source import open_scan_log, scan_log

__all__ = [
    "AdaptiveGate",
    "Frame2D",
    "FrameResult",
    "FrameTiming",
    "FrameTiming2D",
    "GlobalFix",
    "GlobalFix3D",
    "JoinReport",
    "LocalizationConfig2D",
    "Localizer",
    "Localizer2D",
    "LoopRecord",
    "MapCheck",
    "MapCheckSettings",
    "MapLocalizer",
    "Mapper",
    "Mapper3D",
    "MappingConfig",
    "MappingConfig3D",
    "MappingResult",
    "MappingStopped",
    "Odometry",
    "Odometry2D",
    "OdometryConfig",
    "OdometryConfig2D",
    "Relocalization",
    "check_map",
    "extend_map",
    "merge_maps",
    "merge_maps_to_folder",
    "open_scan_log",
    "registration_summary",
    "run_localization_to_folder",
    "run_mapping",
    "run_mapping_3d",
    "run_mapping_to_folder",
    "run_odometry_to_folder",
    "scan_log",
    "write_outputs",
]
