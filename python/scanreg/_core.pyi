"""Type stub of the native module ``scanreg._core`` (checked by ``python -m mypy.stubtest``)."""

import numpy as np
from numpy.typing import NDArray

__version__: str

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

class Linearization:
    @property
    def hessian(self) -> NDArray[np.float64]: ...
    @property
    def gradient(self) -> NDArray[np.float64]: ...
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

# --- scan simulation (crates/scanreg-py/src/simulate.rs) ---

from typing import final  # noqa: E402

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
