"""Type stub of the native module ``scanreg._core`` (checked by ``python -m mypy.stubtest``)."""

from typing import final

import numpy as np
from numpy.typing import NDArray

__version__: str

@final
class Moments:
    @property
    def weight_sum(self) -> float: ...
    @property
    def source_mean(self) -> NDArray[np.float64]: ...
    @property
    def target_mean(self) -> NDArray[np.float64]: ...
    @property
    def cross_covariance(self) -> NDArray[np.float64]: ...
    @property
    def source_spread(self) -> float: ...
    @property
    def target_spread(self) -> float: ...

@final
class Linearization:
    @property
    def hessian(self) -> NDArray[np.float64]: ...
    @property
    def gradient(self) -> NDArray[np.float64]: ...
    @property
    def score_outer(self) -> NDArray[np.float64]: ...
    @property
    def robust_cost(self) -> float: ...
    @property
    def weighted_sum_squares(self) -> float: ...
    @property
    def irls_sum_squares(self) -> float: ...
    @property
    def irls_weight_sum(self) -> float: ...
    @property
    def residuals(self) -> NDArray[np.float64]: ...
    @property
    def kernel_weights(self) -> NDArray[np.float64]: ...

def paired_moments(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    weights: NDArray[np.float64] | None = None,
) -> Moments: ...
def linearize_paired(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    *,
    objective: str,
    kernel: str,
    kernel_scale: float,
    weights: NDArray[np.float64] | None = None,
    target_normals: NDArray[np.float64] | None = None,
) -> Linearization: ...
def lzf_decompress(data: bytes, expected_size: int) -> bytes: ...
def lzf_compress(data: bytes) -> bytes: ...

# --- neighbour search and preprocessing (crates/scanreg-py/src/{knn,preprocess}.rs) ---

@final
class KdTree:
    def __new__(cls, points_array: NDArray[np.float64]) -> KdTree: ...
    @property
    def dim(self) -> int: ...
    def __len__(self) -> int: ...
    def __reduce__(self) -> tuple[type[KdTree], tuple[NDArray[np.float64]]]: ...
    @property
    def points(self) -> NDArray[np.float64]: ...
    def nearest(
        self, query_points: NDArray[np.float64], max_distance: float = ...
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]: ...
    def knn(
        self, query_points: NDArray[np.float64], k: int
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]: ...
    def radius(
        self, query_points: NDArray[np.float64], radius: float
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]: ...
    def local_geometry(
        self,
        k: int,
        viewpoint: NDArray[np.float64],
        *,
        normals: bool = True,
        regularization: str | None = None,
        epsilon: float = 1e-3,
        drop_linear: bool = False,
    ) -> tuple[
        NDArray[np.float64] | None, NDArray[np.float64] | None, NDArray[np.bool_], NDArray[np.bool_]
    ]: ...
    def local_geometry_noise(
        self,
        k: int,
        viewpoint: NDArray[np.float64],
        *,
        normals: bool = True,
        regularization: str | None = None,
        epsilon: float = 1e-3,
        drop_linear: bool = False,
    ) -> tuple[
        NDArray[np.float64] | None,
        NDArray[np.float64] | None,
        NDArray[np.bool_],
        NDArray[np.bool_],
        tuple[float, float],
        float,
    ]: ...
    def statistical_outliers(
        self, k: int, std_ratio: float
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], float]: ...
    def radius_outliers(self, radius: float, min_neighbors: int) -> NDArray[np.int64]: ...
    def project_to_local_planes(self, k: int, radius: float) -> NDArray[np.float64]: ...

@final
class KeyframeMap:
    def __new__(
        cls,
        dim: int,
        voxel_size: float,
        num_neighbors: int,
        max_keyframes: int,
        viewpoint: NDArray[np.float64],
    ) -> KeyframeMap: ...
    @property
    def dim(self) -> int: ...
    def __len__(self) -> int: ...
    @property
    def num_keyframes(self) -> int: ...
    def insert(
        self, points_array: NDArray[np.float64]
    ) -> tuple[KdTree, NDArray[np.float64], NDArray[np.bool_], tuple[float, float], float, int]: ...

@final
class LocalMap:
    def __new__(
        cls,
        dim: int,
        voxel_size: float,
        max_points_per_voxel: int,
        min_spacing: float,
        attributes: str = "none",
    ) -> LocalMap: ...
    @property
    def dim(self) -> int: ...
    @property
    def voxel_size(self) -> float: ...
    @property
    def max_points_per_voxel(self) -> int: ...
    @property
    def attributes(self) -> str: ...
    @property
    def num_voxels(self) -> int: ...
    def __len__(self) -> int: ...
    def insert(
        self,
        points: NDArray[np.float64],
        normals: NDArray[np.float64] | None = None,
        covariances: NDArray[np.float64] | None = None,
    ) -> int: ...
    def remove_far(self, center: NDArray[np.float64], max_distance: float) -> int: ...
    def points(self) -> NDArray[np.float64]: ...
    def normals(self) -> NDArray[np.float64] | None: ...
    def covariances(self) -> NDArray[np.float64] | None: ...
    def gather(
        self, ids: NDArray[np.int64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]: ...
    def nearest(
        self, query_points: NDArray[np.float64], max_distance: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

def voxel_downsample(
    points_array: NDArray[np.float64], voxel_size: float, method: str
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]: ...
def sweep_grids(
    points_array: NDArray[np.float64],
    min_range: float,
    max_range: float,
    fine_voxel: float,
    coarse_voxel: float,
    coarse_covariances: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int, NDArray[np.float64] | None]: ...
def sweep_residual_sums(
    source: NDArray[np.float64],
    nearest: NDArray[np.int64],
    target_points: NDArray[np.float64],
    target_normals: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    source_fractions: NDArray[np.float64] | None = None,
    target_slots: NDArray[np.int64] | None = None,
    target_fractions: NDArray[np.float64] | None = None,
    node_poses: NDArray[np.float64] | None = None,
    mean_fractions: NDArray[np.float64] | None = None,
) -> (
    tuple[int, NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None] | None
): ...
def random_subsample_indices(n: int, count: int, seed: int) -> NDArray[np.int64]: ...
def crop_range(
    points_array: NDArray[np.float64], min_distance: float, max_distance: float
) -> NDArray[np.int64]: ...
def crop_box(
    points_array: NDArray[np.float64],
    min_corner: NDArray[np.float64],
    max_corner: NDArray[np.float64],
) -> NDArray[np.int64]: ...

# --- scan simulation (crates/scanreg-py/src/simulate.rs) ---

SIMULATE_PRIMITIVE_COLUMNS: int

@final
class CastResult:
    @property
    def true_range(self) -> NDArray[np.float64]: ...
    @property
    def range(self) -> NDArray[np.float64]: ...
    @property
    def status(self) -> NDArray[np.uint8]: ...
    @property
    def hit(self) -> NDArray[np.int64]: ...
    @property
    def points(self) -> NDArray[np.float64]: ...
    @property
    def points_reference(self) -> NDArray[np.float64]: ...

def cast_rays(
    primitives: NDArray[np.float64],
    directions: NDArray[np.float64],
    time_offsets: NDArray[np.float64],
    *,
    start_time: float,
    knot_times: NDArray[np.float64],
    knot_poses: NDArray[np.float64],
    twists: NDArray[np.float64],
    reference_time: float,
    min_range: float,
    max_range: float,
    range_sigma: float,
    dropout_probability: float,
    seed: int,
) -> CastResult: ...

# --- local registration (icp) ---

@final
class IcpOutcome:
    @property
    def pose(self) -> NDArray[np.float64]: ...
    @property
    def rotation(self) -> NDArray[np.float64]: ...
    @property
    def translation(self) -> NDArray[np.float64]: ...
    @property
    def iterations(self) -> int: ...
    @property
    def stop_reason(self) -> str: ...
    @property
    def hessian(self) -> NDArray[np.float64]: ...
    @property
    def gradient(self) -> NDArray[np.float64]: ...
    @property
    def score_outer(self) -> NDArray[np.float64]: ...
    @property
    def cost(self) -> float: ...
    @property
    def num_correspondences(self) -> int: ...
    @property
    def num_in_gate(self) -> int: ...
    @property
    def sum_squares(self) -> float: ...
    @property
    def irls_sum_squares(self) -> float: ...
    @property
    def irls_weight_sum(self) -> float: ...
    @property
    def sum_squared_distances(self) -> float: ...
    @property
    def iteration_seconds(self) -> tuple[float, ...]: ...
    @property
    def final_evaluation_seconds(self) -> float: ...
    @property
    def correspondences(self) -> NDArray[np.int64]: ...

def register_icp(
    source: NDArray[np.float64],
    target: KdTree | LocalMap,
    init_pose: NDArray[np.float64],
    method: str,
    kernel: str,
    kernel_scale: float,
    max_correspondence_distance: float,
    max_iterations: int,
    translation_tolerance: float,
    rotation_tolerance: float,
    optimizer: str,
    min_correspondences: int,
    num_threads: int | None = None,
    source_covariances: NDArray[np.float64] | None = None,
    target_normals: NDArray[np.float64] | None = None,
    target_covariances: NDArray[np.float64] | None = None,
    iterate: bool = True,
    step_projector: NDArray[np.float64] | None = None,
    extrapolate: bool = True,
) -> IcpOutcome: ...

# --- Censi covariance and block scores (crates/scanreg-py/src/censi.rs) ---

@final
class CensiAnalysis:
    @property
    def hessian(self) -> NDArray[np.float64]: ...
    @property
    def censi_meat(self) -> NDArray[np.float64]: ...
    @property
    def source_meat(self) -> NDArray[np.float64]: ...
    @property
    def target_meat(self) -> NDArray[np.float64]: ...
    @property
    def normal_meat(self) -> NDArray[np.float64]: ...
    @property
    def plane_sum_squares(self) -> float: ...
    @property
    def determined_plane_sum_squares(self) -> float: ...
    @property
    def block_meat(self) -> NDArray[np.float64]: ...
    @property
    def num_blocks(self) -> int: ...
    @property
    def determined_block_meat(self) -> NDArray[np.float64]: ...
    @property
    def num_determined_blocks(self) -> int: ...
    @property
    def plane_information(self) -> NDArray[np.float64]: ...
    @property
    def num_plane_correspondences(self) -> int: ...
    @property
    def num_determined_correspondences(self) -> int: ...
    @property
    def linear_known(self) -> bool: ...
    @property
    def num_correspondences(self) -> int: ...
    @property
    def plane_noise_information(self) -> NDArray[np.float64]: ...
    @property
    def normal_disagreement(self) -> float: ...
    @property
    def num_normal_pairs(self) -> int: ...
    @property
    def score(self) -> NDArray[np.float64]: ...
    @property
    def determined_hessian(self) -> NDArray[np.float64]: ...
    @property
    def determined_score(self) -> NDArray[np.float64]: ...
    @property
    def num_determined_pairs(self) -> int: ...

def censi_analysis(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    correspondences: NDArray[np.int64],
    *,
    method: str,
    kernel: str,
    kernel_scale: float,
    source_variance: float,
    target_variance: float,
    block_size: float,
    normal_variance: float = 0.0,
    target_normals: NDArray[np.float64] | None = None,
    source_covariances: NDArray[np.float64] | None = None,
    target_covariances: NDArray[np.float64] | None = None,
    num_threads: int | None = None,
    source_normals: NDArray[np.float64] | None = None,
    target_linear: NDArray[np.bool_] | None = None,
) -> CensiAnalysis: ...

# --- the trust arithmetic of one result (crates/scanreg-py/src/trust.rs) ---

@final
class TrustNumbers:
    @property
    def degeneracy_information(self) -> NDArray[np.float64]: ...
    @property
    def degeneracy_eigenvalues(self) -> NDArray[np.float64]: ...
    @property
    def degeneracy_eigenvectors(self) -> NDArray[np.float64]: ...
    @property
    def degeneracy_directions(self) -> NDArray[np.float64]: ...
    @property
    def degeneracy_descriptions(self) -> list[str]: ...
    @property
    def degeneracy_threshold(self) -> float: ...
    @property
    def degeneracy_count(self) -> int: ...
    @property
    def degeneracy_removed_normal_noise(self) -> float: ...
    @property
    def point_variance(self) -> float: ...
    @property
    def hidden_noise_variance(self) -> float: ...
    @property
    def hessian(self) -> NDArray[np.float64]: ...
    @property
    def censi(self) -> NDArray[np.float64]: ...
    @property
    def block(self) -> NDArray[np.float64]: ...
    @property
    def calibrated(self) -> NDArray[np.float64]: ...
    @property
    def model_shift(self) -> NDArray[np.float64]: ...
    @property
    def information(self) -> NDArray[np.float64]: ...
    @property
    def motion_nees(self) -> float | None: ...
    @property
    def conditioning_eigenvalues(self) -> NDArray[np.float64]: ...
    @property
    def conditioning_eigenvectors(self) -> NDArray[np.float64]: ...
    @property
    def condition_number(self) -> float: ...
    @property
    def length_scale(self) -> float: ...
    @property
    def scaled_eigenvalues(self) -> NDArray[np.float64]: ...
    @property
    def scaled_condition_number(self) -> float: ...
    @property
    def weakest(self) -> NDArray[np.float64]: ...
    @property
    def weakest_ratio(self) -> float: ...
    @property
    def weakest_description(self) -> str: ...
    @property
    def num_blocks(self) -> int: ...
    @property
    def num_plane_correspondences(self) -> int: ...
    @property
    def normal_variance(self) -> float: ...
    @property
    def source_normals(self) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None: ...
    @property
    def source_spacing(self) -> float: ...
    @property
    def overlap(self) -> tuple[int, float, float, float, float, int] | None: ...
    @property
    def source_is_cloud(self) -> bool: ...
    @property
    def scene(
        self,
    ) -> tuple[NDArray[np.float64], float, float, NDArray[np.float64]] | None: ...

def trust_analysis(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    correspondences: NDArray[np.int64],
    method: str,
    kernel: str,
    kernel_scale: float,
    block_size: float,
    num_neighbors: int,
    target_normals: NDArray[np.float64] | None,
    target_covariances: NDArray[np.float64] | None,
    source_covariances: NDArray[np.float64] | None,
    num_threads: int | None,
    hessian: NDArray[np.float64],
    sigma2: float,
    levers: NDArray[np.float64] | None,
    prior: NDArray[np.float64] | None,
    drift: NDArray[np.float64],
    motion: NDArray[np.float64],
    length_scale: float | None,
    covariance: str,
    num_correspondences: int,
    sum_squared_distances: float,
    score_outer: NDArray[np.float64] | None,
    effective_residuals: float,
    normal_noise: float,
    typical_normal_noise: float,
    beam_phase_variance: float,
    max_step: float,
    min_agreement: float,
    sampling_scale: float,
    source_normals: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None,
    valley: NDArray[np.float64] | None = None,
    held: tuple[NDArray[np.float64], float, float, float, int, float] | None = None,
    target_linear: NDArray[np.bool_] | None = None,
    target_spacing: float | None = None,
    overlap_target: KdTree | None = None,
    overlap_gate: float | None = None,
    outcome: IcpOutcome | None = None,
    scene_gate: float | None = None,
    sweep_motion: NDArray[np.float64] | None = None,
    target_sweep_motion: NDArray[np.float64] | None = None,
    target_sweep_origin: NDArray[np.float64] | None = None,
) -> TrustNumbers: ...
def trust_numbers(
    analysis: CensiAnalysis,
    hessian: NDArray[np.float64],
    sigma2: float,
    *,
    method: str,
    levers: NDArray[np.float64],
    prior: NDArray[np.float64],
    drift: NDArray[np.float64],
    motion: NDArray[np.float64],
    length_scale: float,
    covariance: str,
    num_correspondences: int,
    sum_squared_distances: float,
    score_outer: NDArray[np.float64] | None = None,
    effective_residuals: float = 0.0,
    normal_noise: float = ...,
    typical_normal_noise: float = ...,
    normal_variance: float = 0.0,
    agreement: tuple[
        NDArray[np.float64],
        NDArray[np.float64],
        int,
        NDArray[np.float64],
        NDArray[np.float64],
        int,
    ]
    | None = None,
    valley: NDArray[np.float64] | None = None,
    sampling_system: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    sampling: float = 0.0,
    held: tuple[NDArray[np.float64], float, float, float, int, float] | None = None,
    hidden_noise_variance: float = 0.0,
) -> TrustNumbers: ...
def trust_sampling(
    source: NDArray[np.float64],
    correspondences: NDArray[np.int64],
    rotation: NDArray[np.float64],
    max_step: float,
    *,
    target_normals: NDArray[np.float64] | None = None,
    target_covariances: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None: ...
def trust_scene(
    source: NDArray[np.float64], gate: float, *, beam_phase: bool = True
) -> tuple[NDArray[np.float64], float, float, NDArray[np.float64]]: ...

# --- overlap and normal noise (crates/scanreg-py/src/measure.rs) ---

def overlap_statistics(
    target: KdTree | LocalMap,
    source: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    max_distance: float,
    num_threads: int | None = None,
    hints: NDArray[np.int64] | None = None,
    within: float | None = None,
    outcome: IcpOutcome | None = None,
) -> tuple[int, float, float, float, float, int]: ...
def target_normal_noise(tree: KdTree, normals: NDArray[np.float64]) -> tuple[float, float]: ...
def count_within(
    target: KdTree | LocalMap,
    source: NDArray[np.float64],
    pose_matrix: NDArray[np.float64],
    max_distance: float,
) -> int: ...
def probe_restarts(
    source: NDArray[np.float64],
    target: KdTree | LocalMap,
    init_poses: NDArray[np.float64],
    method: str,
    kernel: str,
    kernel_scale: float,
    max_correspondence_distance: float,
    max_iterations: int,
    translation_tolerance: float,
    rotation_tolerance: float,
    optimizer: str,
    min_correspondences: int,
    num_threads: int | None,
    source_covariances: NDArray[np.float64] | None,
    target_normals: NDArray[np.float64] | None,
    target_covariances: NDArray[np.float64] | None,
    step_projector: NDArray[np.float64] | None,
    extrapolate: bool,
    result: NDArray[np.float64],
    home_radius: float,
    home_cos_angle: float,
    grid: CorrelativeGrid | None,
    stride: int,
    half_width: int,
    ntheta: int,
    angular_step: float,
    tight: float,
    covariance: NDArray[np.float64] | None,
    chi2: float,
    here: float,
    stop_ratio: float,
    near_move: float,
    near_turn: float,
    implausible_start: NDArray[np.float64] | None,
    implausible_information: NDArray[np.float64] | None,
    implausible_chi2: float,
) -> tuple[list[int], NDArray[np.float64], list[float], NDArray[np.float64]]: ...
def orientation_symmetry(
    points_array: NDArray[np.float64], normals: NDArray[np.float64]
) -> float: ...
def sampled_normals(
    points_array: NDArray[np.float64], k: int, max_points: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]: ...
def correspondence_normal_noise(
    sample: NDArray[np.int64],
    source_normals: NDArray[np.float64],
    target_normals: NDArray[np.float64],
    rotation: NDArray[np.float64],
    correspondences: NDArray[np.int64],
) -> float: ...
def normal_agreement_systems(
    sample: NDArray[np.int64],
    sample_normals: NDArray[np.float64],
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    target_normals: NDArray[np.float64],
    correspondences: NDArray[np.int64],
    pose_matrix: NDArray[np.float64],
    min_agreement: float,
    kernel: str = "none",
    kernel_scale: float = 1.0,
) -> tuple[
    NDArray[np.float64], NDArray[np.float64], int, NDArray[np.float64], NDArray[np.float64], int
]: ...

# --- correlative scan matching (crates/scanreg-py/src/correlative.rs) ---

@final
class CorrelativeMatch:
    @property
    def pose(self) -> NDArray[np.float64]: ...
    @property
    def index(self) -> tuple[int, int, int]: ...
    @property
    def sum(self) -> float: ...
    @property
    def score(self) -> float: ...
    @property
    def fitness(self) -> float: ...
    @property
    def covariance(self) -> NDArray[np.float64]: ...
    @property
    def mean(self) -> NDArray[np.float64]: ...
    @property
    def evaluated(self) -> int: ...
    @property
    def bounds(self) -> int: ...
    @property
    def covariance_candidates(self) -> int: ...

@final
class CorrelativeGrid:
    def __new__(
        cls, reference: NDArray[np.float64], resolution: float, sigma: float, levels: int
    ) -> CorrelativeGrid: ...
    def updated(self, reference: NDArray[np.float64]) -> CorrelativeGrid: ...
    def update(self, reference: NDArray[np.float64]) -> None: ...
    @property
    def origin(self) -> tuple[float, float]: ...
    @property
    def resolution(self) -> float: ...
    @property
    def sigma(self) -> float: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def levels(self) -> int: ...
    @property
    def likelihood(self) -> NDArray[np.float32]: ...
    @property
    def distance_squared(self) -> NDArray[np.float32]: ...
    def search(
        self,
        source: NDArray[np.float64],
        center: tuple[float, float, float],
        nx: int,
        ny: int,
        ntheta: int,
        angular_step: float,
        method: str,
        covariance_radius: int,
        penalty: tuple[float, ...] | None = None,
        min_score: float | None = None,
    ) -> CorrelativeMatch | None: ...

# --- motion compensation (crates/scanreg-py/src/deskew.rs) ---

def deskew(
    points_array: NDArray[np.float64],
    timestamps: NDArray[np.float64],
    velocity: NDArray[np.float64],
    reference_time: float,
) -> NDArray[np.float64]: ...

# --- 2D NDT (crates/scanreg-py/src/ndt2d.rs) ---

@final
class NdtGrid:
    def __new__(
        cls,
        reference: NDArray[np.float64],
        cell_size: float,
        min_points: int,
        min_eigen_ratio: float,
    ) -> NdtGrid: ...
    @property
    def cell_size(self) -> float: ...
    @property
    def num_cells(self) -> tuple[int, int, int, int]: ...
    def cells(self, g: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def evaluate(
        self, source: NDArray[np.float64], pose: tuple[float, float, float]
    ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int]: ...

@final
class NdtGrid3:
    def __new__(
        cls,
        target: NDArray[np.float64],
        cell_size: float,
        min_points: int,
        min_eigen_ratio: float,
    ) -> NdtGrid3: ...
    @property
    def cell_size(self) -> float: ...
    @property
    def num_cells(self) -> int: ...
    def cells(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def evaluate(
        self, source: NDArray[np.float64], pose_matrix: NDArray[np.float64]
    ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int]: ...

# --- place recognition (crates/scanreg-py/src/place.rs) ---

def scan_context(
    points_array: NDArray[np.float64],
    num_rings: int,
    num_sectors: int,
    max_radius: float,
    height_offset: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
def scan_context_distance(
    query: NDArray[np.float64], candidate: NDArray[np.float64]
) -> tuple[float, float, int]: ...

@final
class ScanContextIndex:
    def __new__(cls, num_rings: int, num_sectors: int) -> ScanContextIndex: ...
    def __len__(self) -> int: ...
    def add(self, descriptor_array: NDArray[np.float64]) -> int: ...
    def query(
        self,
        descriptor_array: NDArray[np.float64],
        num_candidates: int,
        top_k: int,
        exclude_recent: int,
        max_distance: float,
    ) -> tuple[
        NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]
    ]: ...

def set_num_threads(num_threads: int) -> None: ...
def get_num_threads() -> int: ...

# --- global 3D registration (crates/scanreg-py/src/global.rs) ---

@final
class GlobalMatch:
    @property
    def poses(self) -> NDArray[np.float64]: ...
    @property
    def clique_sizes(self) -> NDArray[np.int64]: ...
    @property
    def num_inliers(self) -> NDArray[np.int64]: ...
    @property
    def exact(self) -> NDArray[np.bool_]: ...
    @property
    def source_keypoints(self) -> NDArray[np.float64]: ...
    @property
    def target_keypoints(self) -> NDArray[np.float64]: ...
    @property
    def num_source_descriptors(self) -> int: ...
    @property
    def num_target_descriptors(self) -> int: ...
    @property
    def correspondences(self) -> NDArray[np.int64]: ...
    @property
    def stage_seconds(self) -> list[tuple[str, float]]: ...
    @property
    def stage_cpu_seconds(self) -> list[tuple[str, float]]: ...

def register_global(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    *,
    voxel_size: float,
    feature_radius: float,
    noise_bound: float,
    normal_neighbors: int = 30,
    max_feature_neighbors: int = 100,
    max_hypotheses: int = 3,
    clique_search_budget: int = 50_000_000,
) -> GlobalMatch: ...
def solve_correspondences(
    source: NDArray[np.float64],
    target: NDArray[np.float64],
    *,
    noise_bound: float,
    max_hypotheses: int = 3,
    clique_search_budget: int = 50_000_000,
) -> GlobalMatch: ...
def fpfh(
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    *,
    radius: float,
    max_neighbors: int = 100,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]: ...

# --- map self-check (free space) ---

def see_through(
    poses: NDArray[np.float64],
    points: NDArray[np.float64],
    offsets: NDArray[np.int64],
    *,
    bins: int,
    margin: float,
    max_range: float,
    min_gap: int,
    stride: int = 1,
    sessions: NDArray[np.uint32] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.uint32], NDArray[np.uint32]]: ...
def see_through_3d(
    poses: NDArray[np.float64],
    points: NDArray[np.float64],
    offsets: NDArray[np.int64],
    *,
    bins: int,
    elevation_bins: int,
    margin: float,
    max_range: float,
    min_gap: int,
    stride: int = 1,
    sessions: NDArray[np.uint32] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.uint32], NDArray[np.uint32]]: ...
