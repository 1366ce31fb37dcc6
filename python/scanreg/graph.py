"""Pose-graph optimization through gtsam: the only module of scanreg that imports ``gtsam``.

A small adapter. scanreg's conventions go in and come out; gtsam's stay inside:

* **Poses** are ``T_world_node`` (:class:`~scanreg.SE2` / :class:`~scanreg.SE3`); an edge
  measurement is ``T_i_j = inv(T_world_i) @ T_world_j``.
* **Covariance and information** are over scanreg's tangent, translation first, with the
  right perturbation ``T_true = T @ exp(δ)`` (``docs/concepts.md``). gtsam perturbs on the
  right too (``retract(v) = T · Expmap(v)``, checked in ``tests/test_graph.py``), with the
  same ``Pose2`` tangent ``(x, y, θ)`` but a ``Pose3`` tangent ordered *rotation first*
  ``(ω, v)``: 3D matrices are permuted on the way in and out (:func:`to_gtsam_order`,
  :func:`from_gtsam_order`).
* **Degenerate directions** carry no information: :func:`project_information` removes them
  from an information matrix (a corridor loop then constrains only across the corridor).
  gtsam's Gaussian noise model needs a positive-definite matrix, so a rank-deficient
  information gets ``INFORMATION_FLOOR`` (σ = 1 km, or 1000 rad) added along every direction
  before it is handed over: negligible against any real constraint, and it keeps the
  Cholesky factorisation well posed.
* **Loop edges** may take a robust kernel (Cauchy, Huber, or dynamic covariance scaling,
  ``"dcs"``, Agarwal et al. 2013) so that a false loop that passed verification cannot pull
  the whole map.

Solvers: iSAM2 (Kaess et al. 2012) for incremental updates as nodes and edges arrive
(:meth:`Graph.update`), batch Levenberg–Marquardt over everything (:meth:`Graph.optimize`);
marginal covariances from whichever ran last.

A solve never fails on a graph that is merely underdetermined: a connected group of nodes
that nothing anchors to the world gets a weak prior (``ANCHOR_INFORMATION``) at its first
node (:attr:`Graph.anchored`), and when iSAM2's incremental factorisation still finds the
system indeterminate, the whole graph is solved in batch (Levenberg–Marquardt's damping keeps
it well posed) and iSAM2 restarts from there. What cannot be solved even so raises
:class:`GraphSolveError` with the graph as it was before the update, so that the caller can
drop the edges it just added (:meth:`Graph.remove_last_edges`).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ._validate import FloatArray, as_matrix, readonly
from .transform import SE2, SE3

#: Added to every eigenvalue of an edge's information before gtsam sees it (1/m², 1/rad²).
INFORMATION_FLOOR = 1e-6
#: Information matrices whose checked copy and noise model :class:`Graph` keeps at a time.
_NOISE_MODELS_KEPT = 64
#: The prior that anchors a group of nodes nothing else anchors (σ = 1 km, 1000 rad): it
#: fixes the group's gauge and nothing else.
ANCHOR_INFORMATION = 1e-6


class GraphSolveError(RuntimeError):
    """gtsam could not solve the graph, not even in batch; the graph is as before the update.
    Also raised when a marginal covariance cannot be computed (an undamped factorisation of
    a nearly indeterminate system)."""


def _marginal_error(exc: Exception) -> GraphSolveError:
    message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return GraphSolveError(f"graph: gtsam could not compute a marginal covariance ({message})")


KernelName = Literal["none", "cauchy", "huber", "dcs"]
KERNELS: tuple[str, ...] = ("none", "cauchy", "huber", "dcs")
EdgeKind = Literal["prior", "odometry", "loop"]


def require_gtsam() -> Any:
    """Import gtsam, or raise an ImportError that names the extra to install."""
    try:
        return importlib.import_module("gtsam")
    except ImportError as exc:
        raise ImportError(
            "pose-graph optimization needs gtsam: pip install 'scanreg[mapping]'"
        ) from exc


def _perm(dim: int) -> FloatArray:
    """``P`` with ``x_gtsam = P x_ours`` (identity in 2D; (v, ω) → (ω, v) in 3D)."""
    if dim == 2:
        return np.eye(3)
    p = np.zeros((6, 6))
    p[:3, 3:] = np.eye(3)
    p[3:, :3] = np.eye(3)
    return p


def to_gtsam_order(matrix: Any, dim: int) -> FloatArray:
    """A covariance or information matrix over scanreg's tangent, reordered for gtsam."""
    dof = 3 if dim == 2 else 6
    m = as_matrix(matrix, "matrix", (dof, dof))
    p = _perm(dim)
    out: FloatArray = p @ m @ p.T
    return out


def from_gtsam_order(matrix: Any, dim: int) -> FloatArray:
    """A covariance or information matrix over gtsam's tangent, reordered for scanreg."""
    dof = 3 if dim == 2 else 6
    m = as_matrix(matrix, "matrix", (dof, dof))
    p = _perm(dim)
    out: FloatArray = p.T @ m @ p
    return out


def project_information(information: Any, weak_projector: Any) -> FloatArray:
    """The information with nothing left along the weak subspace.

    ``weak_projector`` is ``P_w`` (dof × dof, tangent coordinates), the projector onto the weak
    directions along the strong ones, as :meth:`scanreg.degeneracy.Degeneracy.weak_projector`
    returns it. With ``Q = I − P_w`` the result is ``Qᵀ Λ Q``: ``dᵀ (Qᵀ Λ Q) d = 0`` for any
    weak ``d`` (``Q d = 0``), while a strong ``s`` keeps ``sᵀ Λ s``.
    """
    info = np.asarray(information, dtype=np.float64)
    if info.shape not in ((3, 3), (6, 6)):
        raise ValueError(f"information: expected shape (3, 3) or (6, 6), got {info.shape}")
    info = as_matrix(info, "information", info.shape)
    p = as_matrix(weak_projector, "weak_projector", info.shape)
    q = np.eye(info.shape[0]) - p
    out = q.T @ info @ q
    result: FloatArray = 0.5 * (out + out.T)
    return result


@dataclass(frozen=True)
class Kernel:
    """A robust kernel for an edge: ``name`` in ``none``, ``cauchy``, ``huber``, ``dcs``;
    ``scale`` in whitened units (Mahalanobis distance; for ``dcs``, its Φ)."""

    name: KernelName = "cauchy"
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in KERNELS:
            raise ValueError(f"kernel: unknown {self.name!r}; expected one of {', '.join(KERNELS)}")
        if not (
            isinstance(self.scale, (int, float)) and np.isfinite(self.scale) and self.scale > 0
        ):
            raise ValueError(f"kernel scale: must be finite and > 0, got {self.scale!r}")


@dataclass(frozen=True)
class Edge:
    """An edge as added: ``kind``, nodes, measurement ``T_i_j`` (``i == j`` for a prior, whose
    measurement is ``T_world_i``), information in scanreg's ordering, kernel."""

    kind: EdgeKind
    i: int
    j: int
    measurement: SE2 | SE3
    information: FloatArray
    kernel: Kernel | None = None


def _checked_information(information: Any, dof: int) -> FloatArray:
    info = as_matrix(information, "information", (dof, dof))
    if np.abs(info - info.T).max() > 1e-9 * max(1.0, float(np.abs(info).max())):
        raise ValueError("information: must be symmetric")
    sym = 0.5 * (info + info.T)
    vals = np.linalg.eigvalsh(sym)
    if vals[0] < -1e-9 * max(1.0, float(vals[-1])):
        raise ValueError(
            f"information: must be positive semi-definite, smallest eigenvalue {vals[0]:.3g}"
        )
    if not vals[-1] > 0:
        raise ValueError("information: is zero (the edge would constrain nothing)")
    out: FloatArray = sym
    return out


class Graph:
    """A pose graph in SE(2) (``dim=2``) or SE(3) (``dim=3``), solved by gtsam.

    >>> g = Graph(2)
    >>> g.add_node(0, SE2.identity()); g.add_prior(0, SE2.identity(), np.eye(3) * 1e-6)
    >>> g.add_node(1, guess); g.add_edge(0, 1, T_0_1, information)
    >>> g.update()                      # iSAM2 step with what was added since the last one
    >>> g.add_edge(1, 0, T_1_0, info, kind="loop", kernel=Kernel("cauchy", 1.0))
    >>> g.optimize()                    # batch Levenberg–Marquardt over everything
    >>> g.pose(1), g.marginal_covariance(1)

    Keys are non-negative ints. The graph holds the edges as added (:attr:`edges`) and the
    current estimate; :meth:`update` and :meth:`optimize` both replace the estimate.
    """

    def __init__(self, dim: int, *, relinearize_threshold: float = 0.01) -> None:
        if dim not in (2, 3):
            raise ValueError(f"dim: expected 2 or 3, got {dim!r}")
        gtsam = require_gtsam()
        self._g = gtsam
        self.dim = dim
        self.dof = 3 if dim == 2 else 6
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(float(relinearize_threshold))
        self._isam_params = params
        self._isam = gtsam.ISAM2(params)
        self._all_factors = gtsam.NonlinearFactorGraph()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._estimate = gtsam.Values()
        self._initial: dict[int, SE2 | SE3] = {}
        self._edges: list[Edge] = []
        self._marginals: Any = None  # gtsam.Marginals after a batch solve
        # Marginal and relative covariances read off the current solve: a loop search asks
        # for the same pair again (its candidate gate, then its window) and each is a joint
        # marginal of the Bayes tree (~1 ms on a 3000-node graph). Emptied where the solve
        # (iSAM2's, the estimate or the batch marginals) changes; new nodes and edges change
        # nothing read until the next update.
        self._covariances: dict[tuple[int, ...], FloatArray] = {}
        # pose_vectors of the current estimate: a loop search reads every node's pose up to
        # three times between two solves (its candidates, the wide search's candidates and
        # submap), each a copy of the whole estimate. Emptied where the estimate changes.
        self._pose_rows: tuple[list[int], FloatArray] | None = None
        # The checked information and noise model of each information matrix seen lately, by
        # its bytes and kernel: the final pass over the scans adds thousands of edges with
        # two matrices (each checked by an eigen-decomposition, ~0.1 ms).
        self._noise_models: dict[tuple[bytes, Kernel | None], tuple[FloatArray, Any]] = {}
        self._isam_current = True  # iSAM2 holds every factor (False after a batch solve)
        # Connected groups of nodes (union-find) and whether a prior anchors each.
        self._parent: dict[int, int] = {}
        self._has_prior: set[int] = set()
        #: Nodes that got an anchoring prior because nothing else fixed their group.
        self.anchored: list[int] = []
        #: Each recovery from a failed incremental update: gtsam's message, first line.
        self.recoveries: list[str] = []

    # -- conversion ---------------------------------------------------------------------
    def _to_gtsam(self, pose: SE2 | SE3) -> Any:
        if self.dim == 2:
            if not isinstance(pose, SE2):
                raise TypeError(f"pose: expected SE2 for a 2D graph, got {type(pose).__name__}")
            x, y = pose.translation
            return self._g.Pose2(float(x), float(y), float(pose.angle))
        if not isinstance(pose, SE3):
            raise TypeError(f"pose: expected SE3 for a 3D graph, got {type(pose).__name__}")
        return self._g.Pose3(self._g.Rot3(pose.rotation), np.asarray(pose.translation))

    def _from_gtsam(self, value: Any) -> SE2 | SE3:
        if self.dim == 2:
            return SE2.from_vector([value.x(), value.y(), value.theta()])
        return SE3.from_matrix(value.matrix(), atol=1e-6)

    def _noise(self, information: FloatArray, kernel: Kernel | None) -> Any:
        nm = self._g.noiseModel
        info = to_gtsam_order(information, self.dim) + INFORMATION_FLOOR * np.eye(self.dof)
        base = nm.Gaussian.Information(info, False)
        if kernel is None or kernel.name == "none":
            return base
        est = nm.mEstimator
        robust = {
            "cauchy": est.Cauchy,
            "huber": est.Huber,
            "dcs": est.DCS,
        }[kernel.name].Create(float(kernel.scale))
        return nm.Robust.Create(robust, base)

    def _checked_noise(self, information: Any, kernel: Kernel | None) -> tuple[FloatArray, Any]:
        """``(_checked_information(information), self._noise(it, kernel))``, the same matrix
        and model for the same bytes (a copy of the matrix each time: an edge keeps its own)."""
        key = (as_matrix(information, "information", (self.dof, self.dof)).tobytes(), kernel)
        known = self._noise_models.get(key)
        if known is None:
            info = _checked_information(information, self.dof)
            known = (info, self._noise(info, kernel))
            if len(self._noise_models) >= _NOISE_MODELS_KEPT:
                self._noise_models.clear()
            self._noise_models[key] = known
        return known[0].copy(), known[1]

    def _changed(self) -> None:
        """Forget what was read off the graph as it was (marginals, covariances)."""
        self._marginals = None
        self._covariances.clear()
        self._pose_rows = None

    def _key(self, key: Any, name: str) -> int:
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
            raise TypeError(f"{name}: expected a non-negative int key, got {key!r}")
        return int(key)

    def _pose(self, pose: Any, name: str) -> SE2 | SE3:
        expected = SE2 if self.dim == 2 else SE3
        if not isinstance(pose, expected):
            raise TypeError(f"{name}: expected {expected.__name__}, got {type(pose).__name__}")
        return pose

    # -- building ------------------------------------------------------------------------
    def add_node(self, key: int, initial: SE2 | SE3) -> None:
        """A new pose ``T_world_key`` with its initial guess."""
        k = self._key(key, "key")
        pose = self._pose(initial, "initial")
        if k in self._initial:
            raise ValueError(f"key: node {k} already exists")
        self._initial[k] = pose
        self._new_values.insert(k, self._to_gtsam(pose))
        self._parent[k] = k

    def _root(self, k: int) -> int:
        parent = self._parent
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    def _join(self, a: int, b: int) -> None:
        ra, rb = self._root(a), self._root(b)
        if ra != rb:
            self._parent[max(ra, rb)] = min(ra, rb)
            if max(ra, rb) in self._has_prior:
                self._has_prior.add(min(ra, rb))

    def _anchor_free_groups(self) -> None:
        """A weak prior on the first node of every group of nodes nothing anchors (an
        unanchored group leaves the linear system indeterminate)."""
        free = {self._root(k) for k in self._new_values.keys()}  # noqa: SIM118 (gtsam.Values)
        for root in sorted(free - self._has_prior):
            info = ANCHOR_INFORMATION * np.eye(self.dof)
            self.add_prior(root, self._initial[root], info)
            self.anchored.append(root)

    def add_prior(self, key: int, pose: SE2 | SE3, information: Any) -> None:
        """Anchor ``T_world_key`` at ``pose`` with ``information`` (scanreg ordering)."""
        k = self._require(key, "key")
        p = self._pose(pose, "pose")
        info, noise = self._checked_noise(information, None)
        factor_cls = self._g.PriorFactorPose2 if self.dim == 2 else self._g.PriorFactorPose3
        self._push(factor_cls(k, self._to_gtsam(p), noise))
        self._edges.append(Edge("prior", k, k, p, info))
        self._has_prior.add(self._root(k))

    def add_edge(
        self,
        i: int,
        j: int,
        measurement: SE2 | SE3,
        information: Any,
        *,
        kind: Literal["odometry", "loop"] = "odometry",
        kernel: Kernel | None = None,
    ) -> None:
        """A relative-pose edge: ``T_i_j = inv(T_world_i) @ T_world_j`` observed as
        ``measurement`` with ``information`` (scanreg ordering; may be rank-deficient, see
        :func:`project_information`)."""
        a, b = self._require(i, "i"), self._require(j, "j")
        if a == b:
            raise ValueError(f"i, j: an edge needs two different nodes, got {a} twice")
        if kind not in ("odometry", "loop"):
            raise ValueError(f"kind: expected 'odometry' or 'loop', got {kind!r}")
        if kernel is not None and not isinstance(kernel, Kernel):
            raise TypeError(f"kernel: expected Kernel or None, got {type(kernel).__name__}")
        m = self._pose(measurement, "measurement")
        info, noise = self._checked_noise(information, kernel)
        factor_cls = self._g.BetweenFactorPose2 if self.dim == 2 else self._g.BetweenFactorPose3
        self._push(factor_cls(a, b, self._to_gtsam(m), noise))
        self._edges.append(Edge(kind, a, b, m, info, kernel))
        self._join(a, b)

    def remove_last_edges(self, count: int) -> None:
        """Drop the ``count`` edges added last (not priors), e.g. loop edges with which
        :meth:`update` raised :class:`GraphSolveError`. The next solve starts from the
        current estimate without them."""
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
            raise ValueError(f"count: expected an int >= 0, got {count!r}")
        if count == 0:
            return
        if count > len(self._edges) or any(e.kind == "prior" for e in self._edges[-count:]):
            raise ValueError(f"count: the last {count} edges are not all relative-pose edges")
        del self._edges[-count:]
        factors = self._g.NonlinearFactorGraph()
        for k in range(int(self._all_factors.size()) - count):
            factors.push_back(self._all_factors.at(k))
        self._all_factors = factors
        self._new_factors = self._g.NonlinearFactorGraph()
        self._isam_current = False
        self._changed()

    def _require(self, key: Any, name: str) -> int:
        k = self._key(key, name)
        if k not in self._initial:
            raise ValueError(f"{name}: unknown node {k} (add_node it first)")
        return k

    def _push(self, factor: Any) -> None:
        self._new_factors.push_back(factor)
        self._all_factors.push_back(factor)

    # -- solving -------------------------------------------------------------------------
    def update(self, extra_iterations: int = 0) -> None:
        """One iSAM2 update with the nodes and edges added since the last one (plus
        ``extra_iterations`` more relinearisation steps, e.g. after a loop closure)."""
        self._covariances.clear()  # (iSAM2 may change even where it then fails)
        self._anchor_free_groups()
        try:
            if not self._isam_current:
                self._rebuild_isam()
            self._isam.update(self._new_factors, self._new_values)
            for _ in range(int(extra_iterations)):
                self._isam.update()
        except RuntimeError as exc:
            # iSAM2 factorises without damping: a nearly indeterminate system (a long chain
            # of weak edges, a loop along a degenerate direction) can stop it where a damped
            # batch solve goes through.
            self.recoveries.append(str(exc).strip().splitlines()[0])
            self._solve_in_batch(exc)
            return
        self._new_factors = self._g.NonlinearFactorGraph()
        self._new_values = self._g.Values()
        self._estimate = self._isam.calculateEstimate()
        self._changed()

    def _solve_in_batch(self, cause: Exception) -> None:
        """Levenberg–Marquardt over everything from the last good estimate; iSAM2 restarts
        from its result at the next update. Raises :class:`GraphSolveError` (the estimate
        untouched) when even that fails."""
        before = self._g.Values(self._estimate)
        try:
            self.optimize()
        except RuntimeError as exc:
            self._estimate = before
            self._isam_current = False
            self._covariances.clear()
            self._pose_rows = None
            message = str(exc).strip().splitlines()[0]
            raise GraphSolveError(
                f"graph: gtsam could not solve it, incrementally ({str(cause).strip()}) "
                f"nor in batch ({message})"
            ) from exc

    def _rebuild_isam(self) -> None:
        # After a batch solve the incremental solver restarts from the batch estimate, with
        # every factor, so that later updates build on it.
        values = self._g.Values(self._estimate)
        values.insert(self._new_values)
        self._isam = self._g.ISAM2(self._isam_params)
        self._isam.update(self._all_factors, values)
        self._new_factors = self._g.NonlinearFactorGraph()
        self._new_values = self._g.Values()
        self._isam_current = True

    def optimize(self, *, max_iterations: int = 100, relative_tolerance: float = 1e-6) -> int:
        """Batch Levenberg–Marquardt over every node and edge, from the current estimate
        (initial guesses for nodes not yet estimated). Returns the iterations run."""
        self._anchor_free_groups()
        values = self._g.Values(self._estimate)
        values.insert(self._new_values)
        if values.size() == 0:
            raise ValueError("graph: has no nodes to optimize")
        params = self._g.LevenbergMarquardtParams()
        params.setMaxIterations(int(max_iterations))
        params.setRelativeErrorTol(float(relative_tolerance))
        optimizer = self._g.LevenbergMarquardtOptimizer(self._all_factors, values, params)
        self._estimate = optimizer.optimize()
        self._new_values = self._g.Values()
        self._new_factors = self._g.NonlinearFactorGraph()
        self._isam_current = False
        self._changed()
        return int(optimizer.iterations())

    def move_gauge(self, key: int, pose: SE2 | SE3) -> None:
        """Move every solved node by one rigid transform so that ``key`` sits exactly at
        ``pose``. Relative poses, hence every edge's error, are unchanged; only a prior sees
        it. Why: a finite anchoring prior is met only as far as the solver converged (iSAM2
        relinearises beyond a threshold), and a map is read in its first scan's frame."""
        k = self._solved(key)
        target = self._pose(pose, "pose")
        correction = target @ self.pose(k).inverse()  # type: ignore[operator]
        moved = self._g.Values()
        for n in self._estimate.keys():  # noqa: SIM118 (gtsam.Values)
            moved.insert(n, self._to_gtsam(correction @ self.pose(int(n))))  # type: ignore[operator]
        self._estimate = moved
        self._isam_current = False  # iSAM2 restarts from the moved estimate at its next update
        self._changed()

    # -- reading -------------------------------------------------------------------------
    @property
    def edges(self) -> tuple[Edge, ...]:
        return tuple(self._edges)

    @property
    def keys(self) -> list[int]:
        return sorted(self._initial)

    def __len__(self) -> int:
        return len(self._initial)

    def pose(self, key: int) -> SE2 | SE3:
        """``T_world_key``: the current estimate (the initial guess before any solve)."""
        k = self._require(key, "key")
        if self._estimate.exists(k):
            getter = self._estimate.atPose2 if self.dim == 2 else self._estimate.atPose3
            return self._from_gtsam(getter(k))
        return self._initial[k]

    def poses(self) -> dict[int, SE2 | SE3]:
        return {k: self.pose(k) for k in self.keys}

    def pose_vectors(self) -> tuple[list[int], FloatArray]:
        """2D only: the solved keys (ascending) and their ``[x, y, θ]`` rows (read-only), in one
        call (no per-node conversion: what a candidate search over every node needs); kept until
        the estimate changes."""
        if self.dim != 2:
            raise ValueError("pose_vectors: 2D graphs only")
        if self._pose_rows is None:
            keys = [int(k) for k in self._estimate.keys()]  # noqa: SIM118 (gtsam.Values)
            rows = np.zeros((0, 3))
            if keys:
                rows = np.array(self._g.utilities.extractPose2(self._estimate), dtype=np.float64)
            self._pose_rows = (keys, readonly(rows.reshape(-1, 3)))
        keys, rows = self._pose_rows
        return list(keys), rows

    def error(self) -> float:
        """The total (robust) cost ``½ Σ ‖e‖²`` of the current estimate."""
        values = self._g.Values(self._estimate)
        values.insert(self._new_values)
        return float(self._all_factors.error(values))

    def _solved(self, key: int) -> int:
        k = self._require(key, "key")
        if not self._estimate.exists(k):
            raise ValueError(f"key: node {k} has not been solved yet (call update or optimize)")
        return k

    def marginal_covariance(self, key: int) -> FloatArray:
        """Marginal covariance of ``T_world_key`` (scanreg ordering, right perturbation)."""
        k = self._solved(key)
        known = self._covariances.get((k,))
        if known is None:
            try:
                if self._isam_current:
                    cov = self._isam.marginalCovariance(k)
                else:
                    cov = self._batch_marginals().marginalCovariance(k)
            except RuntimeError as exc:
                raise _marginal_error(exc) from exc
            known = from_gtsam_order(np.asarray(cov), self.dim)
            self._covariances[(k,)] = known
        return known.copy()

    def _batch_marginals(self) -> Any:
        if self._marginals is None:
            self._marginals = self._g.Marginals(self._all_factors, self._estimate)
        return self._marginals

    def relative_covariance(self, i: int, j: int) -> FloatArray:
        """Covariance of ``T_i_j = inv(T_world_i) @ T_world_j`` from the joint marginal of
        the two nodes (scanreg ordering, right perturbation of ``T_i_j``).

        To first order ``δ_ij = −Ad(T_j_i) δ_i + δ_j``, so
        ``Σ_ij = A Σ_joint Aᵀ`` with ``A = [−Ad(T_j_i), I]``.
        """
        a, b = self._solved(i), self._solved(j)
        known = self._covariances.get((a, b))
        if known is None:
            known = self._relative_covariance(a, b)
            self._covariances[(a, b)] = known
        return known.copy()

    def _relative_covariance(self, a: int, b: int) -> FloatArray:
        keys = self._g.KeyVector([a, b])
        try:
            if self._isam_current:
                joint = np.asarray(self._isam.jointMarginalCovariance(keys).fullMatrix())
            else:
                marginals = self._batch_marginals()
                joint = np.asarray(marginals.jointMarginalCovariance(keys).fullMatrix())
        except RuntimeError as exc:
            raise _marginal_error(exc) from exc
        d = self.dof
        p = _perm(self.dim)
        big_p = np.zeros((2 * d, 2 * d))
        big_p[:d, :d] = p
        big_p[d:, d:] = p
        joint = big_p.T @ joint @ big_p
        t_ji = self.pose(b).inverse() @ self.pose(a)  # type: ignore[operator]
        a_mat = np.hstack([-t_ji.adjoint(), np.eye(d)])
        out = a_mat @ joint @ a_mat.T
        result: FloatArray = 0.5 * (out + out.T)
        return result
