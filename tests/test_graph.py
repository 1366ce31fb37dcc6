"""scanreg.graph: the gtsam adapter — hand-computed graphs, the tangent conversion, degenerate
and robust loop edges."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scanreg import SE2, SE3
from scanreg import graph as G
from scanreg.quality import information_from_covariance

gtsam = pytest.importorskip("gtsam")

SIGMA = 0.1  # m, per odometry/loop edge


def _info(dim: int, sigma_t: float = SIGMA, sigma_r: float = 1e-4) -> np.ndarray:
    n = dim
    r = 1 if dim == 2 else 3
    return np.diag([1 / sigma_t**2] * n + [1 / sigma_r**2] * r)


def _line(dim: int, solve: str) -> G.Graph:
    """0 → 1 → 2 one metre apart along x, a loop 0 → 2 measuring 2.2 m, equal weights;
    rotation held stiff so x and y decouple."""
    pose = SE2 if dim == 2 else SE3
    g = G.Graph(dim)

    def along(x: float) -> Any:
        return SE2.from_vector([x, 0, 0]) if dim == 2 else SE3.from_vector([x, 0, 0, 0, 0, 0])

    for k in range(3):
        g.add_node(k, along(float(k)))
    g.add_prior(0, pose.identity(), np.eye(g.dof) * 1e12)
    g.add_edge(0, 1, along(1.0), _info(dim))
    g.add_edge(1, 2, along(1.0), _info(dim))
    if solve == "isam":
        g.update()
    g.add_edge(0, 2, along(2.2), _info(dim), kind="loop")
    if solve == "isam":
        g.update(extra_iterations=2)
    else:
        g.optimize()
    return g


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("solve", ["isam", "batch"])
def test_tiny_loop_against_hand_computed_answer(dim: int, solve: str) -> None:
    g = _line(dim, solve)
    # The loop disagrees with the chain by 0.2 m; three equal edges share it, 1/3 each.
    assert g.pose(1).translation[0] == pytest.approx(1 + 0.2 / 3, abs=1e-6)
    assert g.pose(2).translation[0] == pytest.approx(2 + 0.4 / 3, abs=1e-6)
    assert np.abs(g.pose(2).translation[1:]).max() < 1e-9
    # Node 2: two edges in series (2σ²) in parallel with one (σ²) → (2/3)σ²; same for node 1.
    for k in (1, 2):
        cov = g.marginal_covariance(k)
        assert cov.shape == (g.dof, g.dof)
        # Translation first in scanreg's order: a swapped Pose3 ordering would read ~1e-8 here.
        for axis in range(dim):
            assert cov[axis, axis] == pytest.approx(2 / 3 * SIGMA**2, rel=1e-4)
        assert cov[dim, dim] < 1e-7


@pytest.mark.parametrize("dim", [2, 3])
def test_relative_covariance_of_an_edge_is_the_edge_covariance(dim: int) -> None:
    rng = np.random.default_rng(4)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-3 + np.eye(6) * 1e-4
    cov = cov[:3, :3] if dim == 2 else cov
    meas = (
        SE2.from_vector([1.0, 0.5, 0.8])
        if dim == 2
        else SE3.from_vector([1, 0.5, -0.2, 0.3, -0.4, 0.8])
    )
    start = (
        SE2.from_vector([3.0, -1.0, 2.0])
        if dim == 2
        else SE3.from_vector([3, -1, 2, 0.1, 0.2, 2.0])
    )
    for solve in ("isam", "batch"):
        g = G.Graph(dim)
        g.add_node(5, start)
        g.add_node(2, start @ meas)  # type: ignore[operator]
        g.add_prior(5, start, np.eye(g.dof) * 1e10)
        g.add_edge(5, 2, meas, information_from_covariance(cov))
        g.update() if solve == "isam" else g.optimize()
        # Keys given out of order (5 > 2) on purpose: the joint block order must follow them.
        np.testing.assert_allclose(g.relative_covariance(5, 2), cov, rtol=1e-5, atol=1e-10)
        back = g.relative_covariance(2, 5)
        ad = meas.adjoint()
        np.testing.assert_allclose(back, ad @ cov @ ad.T, rtol=1e-5, atol=1e-10)


@example(vec=[0.0] * 6, delta=[0.28125, 0.5, 1e-10, 0.0, 0.0, 0.0], seed=0)
@settings(max_examples=40, deadline=None)
@given(
    vec=st.lists(st.floats(-3, 3), min_size=6, max_size=6),
    delta=st.lists(st.floats(-0.5, 0.5), min_size=6, max_size=6),
    seed=st.integers(0, 2**16),
)
def test_conversion_round_trip_and_frame(vec: list[float], delta: list[float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    for dim in (2, 3):
        dof = 3 if dim == 2 else 6
        pose: Any = SE2.from_vector(vec[:3]) if dim == 2 else SE3.from_vector(vec)
        d = np.array(delta[:dof])
        a = rng.normal(size=(dof, dof))
        cov = a @ a.T + 0.1 * np.eye(dof)
        np.testing.assert_allclose(
            G.from_gtsam_order(G.to_gtsam_order(cov, dim), dim), cov, rtol=1e-12
        )
        g = G.Graph(dim)
        # The same perturbation: our T @ exp(δ) equals gtsam's retract of the reordered δ.
        gp = g._to_gtsam(pose)
        ours = (pose @ type(pose).exp(d)).as_matrix()
        theirs = gp.retract(G._perm(dim) @ d).matrix()
        # gtsam's Pose2 exponential forms its translation as (v⊥ − R v⊥)/θ, which loses about
        # ε·|v|/|θ| to cancellation above its small-angle switch at |θ| = 1e-10 (hypothesis
        # found δ = (0.5, 0.039, 1e-9): 2.5e-8 m, and (0.28, 0.5, 1e-10): 5.3e-7 m); ours is
        # exact there.
        tol = 1e-7
        if dim == 2 and abs(d[2]) >= 1e-10:
            tol += 4e-16 * float(np.linalg.norm(d[:2])) / abs(d[2])
        np.testing.assert_allclose(theirs, ours, atol=tol)
        # A covariance goes through gtsam as a prior and comes back as the marginal.
        g.add_node(0, pose)
        g.add_prior(0, pose, information_from_covariance(cov))
        g.update()
        # Exactly, up to the floor every edge gets (INFORMATION_FLOOR, σ = 1 km).
        floored = np.linalg.inv(np.linalg.inv(cov) + G.INFORMATION_FLOOR * np.eye(dof))
        np.testing.assert_allclose(g.marginal_covariance(0), floored, rtol=1e-7, atol=1e-12)


def test_corridor_loop_constrains_only_across_the_corridor() -> None:
    # A loop measured in a corridor along x: its x information is removed, so a loop that
    # disagrees with the chain by 0.5 m along x and 0.2 m along y corrects y only.
    g = G.Graph(2)
    g.add_node(0, SE2.identity())
    g.add_node(1, SE2.from_vector([5.0, 0.0, 0.0]))
    g.add_prior(0, SE2.identity(), np.eye(3) * 1e12)
    g.add_edge(0, 1, SE2.from_vector([5.0, 0.0, 0.0]), np.diag([1.0, 1.0, 1e4]))
    weak = np.diag([1.0, 0.0, 0.0])  # projector onto x
    info = G.project_information(np.diag([1e4, 1e4, 1e4]), weak)
    assert info[0, 0] == 0 and info[1, 1] == 1e4
    g.add_edge(0, 1, SE2.from_vector([5.5, 0.2, 0.0]), info, kind="loop")
    g.optimize()
    t = g.pose(1).translation
    assert t[0] == pytest.approx(5.0, abs=1e-4)  # along the corridor: odometry only
    assert t[1] == pytest.approx(0.2 * 1e4 / (1e4 + 1), abs=1e-4)  # across: the loop wins
    # Without the projection the loop would have moved x as well.
    h = G.Graph(2)
    h.add_node(0, SE2.identity())
    h.add_node(1, SE2.from_vector([5.0, 0.0, 0.0]))
    h.add_prior(0, SE2.identity(), np.eye(3) * 1e12)
    h.add_edge(0, 1, SE2.from_vector([5.0, 0.0, 0.0]), np.diag([1.0, 1.0, 1e4]))
    h.add_edge(0, 1, SE2.from_vector([5.5, 0.2, 0.0]), np.diag([1e4] * 3), kind="loop")
    h.optimize()
    assert h.pose(1).translation[0] > 5.49


@pytest.mark.parametrize("kernel", ["cauchy", "dcs"])
def test_robust_kernel_limits_a_false_loop(kernel: str) -> None:
    # A square of four 2 m edges closed by a consistent loop and a false one 1.5 m off.
    def build(k: G.Kernel | None) -> G.Graph:
        g = G.Graph(2)
        truth = [SE2.from_vector([0, 0, 0])]
        step = SE2.from_vector([2.0, 0.0, math.pi / 2])
        for _ in range(3):
            truth.append(truth[-1] @ step)
        for i, p in enumerate(truth):
            g.add_node(i, p)
        g.add_prior(0, truth[0], np.eye(3) * 1e12)
        info = np.diag([400.0, 400.0, 4000.0])
        for i in range(3):
            g.add_edge(i, i + 1, step, info)
        g.add_edge(3, 0, step, info, kind="loop", kernel=k)
        wrong = step @ SE2.from_vector([1.5, 0.0, 0.0])
        g.add_edge(3, 0, wrong, info, kind="loop", kernel=k)
        g.optimize()
        return g

    plain, robust = build(None), build(G.Kernel(kernel, 1.0))  # type: ignore[arg-type]
    step = SE2.from_vector([2.0, 0.0, math.pi / 2])
    truth3 = step @ step @ step
    err_plain = np.linalg.norm((truth3.inverse() @ plain.pose(3)).translation)
    err_robust = np.linalg.norm((truth3.inverse() @ robust.pose(3)).translation)
    assert err_plain > 0.3
    assert err_robust < 0.3 * err_plain


def test_bad_input_is_named() -> None:
    g = G.Graph(2)
    g.add_node(0, SE2.identity())
    with pytest.raises(ValueError, match="key: node 0 already exists"):
        g.add_node(0, SE2.identity())
    with pytest.raises(TypeError, match="initial: expected SE2"):
        g.add_node(1, SE3.identity())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="j: unknown node 7"):
        g.add_edge(0, 7, SE2.identity(), np.eye(3))
    g.add_node(1, SE2.identity())
    with pytest.raises(ValueError, match="positive semi-definite"):
        g.add_edge(0, 1, SE2.identity(), -np.eye(3))
    with pytest.raises(ValueError, match="information: is zero"):
        g.add_edge(0, 1, SE2.identity(), np.zeros((3, 3)))
    # A noise-free (zero) covariance inverts to an infinite information: no edge takes it.
    with pytest.raises(ValueError, match="information: contains NaN or inf"):
        g.add_edge(0, 1, SE2.identity(), information_from_covariance(np.zeros((3, 3))))
    with pytest.raises(ValueError, match="has not been solved"):
        g.marginal_covariance(1)
    with pytest.raises(ValueError, match="dim: expected 2 or 3"):
        G.Graph(4)
    with pytest.raises(ValueError, match="kernel: unknown 'tukey'"):
        G.Kernel("tukey")  # type: ignore[arg-type]


def test_missing_gtsam_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    real = G.importlib.import_module

    def fake(name: str, *args: Any) -> Any:
        if name == "gtsam":
            raise ImportError("No module named 'gtsam'")
        return real(name, *args)

    monkeypatch.setattr(G.importlib, "import_module", fake)
    with pytest.raises(ImportError, match=r"scanreg\[mapping\]"):
        G.Graph(2)


def test_an_unanchored_group_is_anchored_not_indeterminate() -> None:
    # Nodes 1 and 2 are tied to each other but to nothing that fixes them in the world: the
    # linear system is indeterminate (gtsam's IndeterminateLinearSystemException from a raw
    # iSAM2 update). The graph anchors the group at its first node and says so.
    g = G.Graph(2)
    g.add_node(0, SE2.identity())
    g.add_prior(0, SE2.identity(), np.eye(3) * 1e4)
    g.add_node(1, SE2.from_vector([5.0, 0.0, 0.3]))
    g.add_node(2, SE2.from_vector([6.0, 0.0, 0.3]))  # 0.3 m off what the edge says
    g.add_edge(1, 2, SE2.from_vector([1.0, 0.0, 0.0]), np.eye(3) * 100)
    g.update()
    assert g.anchored == [1]
    # The anchor only fixes the gauge: the edge holds exactly, and the group has moved no
    # farther than the disagreement of its initial guesses.
    assert np.linalg.norm(g.pose(1).translation - [5.0, 0.0]) < 0.3
    rel = g.pose(1).inverse() @ g.pose(2)
    assert np.allclose(rel.as_vector(), [1.0, 0.0, 0.0], atol=1e-6)
    # Joining the group to the anchored one later leaves the weak anchor negligible.
    g.add_edge(0, 1, SE2.from_vector([1.0, 0.0, 0.0]), np.eye(3) * 100)
    g.update(extra_iterations=2)
    assert np.allclose(g.pose(2).as_vector(), [2.0, 0.0, 0.0], atol=1e-4)


def test_a_failed_incremental_update_is_solved_in_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    g = G.Graph(2)
    g.add_node(0, SE2.identity())
    g.add_prior(0, SE2.identity(), np.eye(3) * 1e4)
    g.update()
    g.add_node(1, SE2.from_vector([0.9, 0.1, 0.0]))
    g.add_edge(0, 1, SE2.from_vector([1.0, 0.0, 0.0]), np.eye(3) * 100)

    class Failing:
        def update(self, *args: Any) -> None:
            raise RuntimeError("\nIndeterminate linear system detected near variable 1")

    monkeypatch.setattr(g, "_isam", Failing())
    g.update()  # no exception: Levenberg–Marquardt solved it instead
    assert g.recoveries == ["Indeterminate linear system detected near variable 1"]
    assert np.allclose(g.pose(1).as_vector(), [1.0, 0.0, 0.0], atol=1e-6)
    # iSAM2 restarts from the batch solution at the next update.
    g.add_node(2, SE2.from_vector([2.1, 0.0, 0.0]))
    g.add_edge(1, 2, SE2.from_vector([1.0, 0.0, 0.0]), np.eye(3) * 100)
    g.update()
    assert np.allclose(g.pose(2).as_vector(), [2.0, 0.0, 0.0], atol=1e-6)


def test_unsolvable_update_names_gtsam_and_edges_can_be_dropped(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    g = G.Graph(2)
    g.add_node(0, SE2.identity())
    g.add_prior(0, SE2.identity(), np.eye(3) * 1e4)
    g.add_node(1, SE2.from_vector([1.0, 0.0, 0.0]))
    g.add_edge(0, 1, SE2.from_vector([1.0, 0.0, 0.0]), np.eye(3) * 100)
    g.update()
    g.add_edge(0, 1, SE2.from_vector([3.0, 0.0, 0.0]), np.eye(3) * 100, kind="loop")

    def broken(*args: Any, **kwargs: Any) -> int:
        raise RuntimeError("Indeterminate linear system detected near variable 1")

    monkeypatch.setattr(g, "_rebuild_isam", broken)
    monkeypatch.setattr(g, "_isam_current", False)
    monkeypatch.setattr(g, "optimize", broken)
    with pytest.raises(G.GraphSolveError, match=r"nor in batch \(Indeterminate linear system"):
        g.update()
    monkeypatch.undo()
    assert np.allclose(g.pose(1).as_vector(), [1.0, 0.0, 0.0])  # the estimate before it
    g.remove_last_edges(1)
    assert [e.kind for e in g.edges] == ["prior", "odometry"]
    g.update()
    assert np.allclose(g.pose(1).as_vector(), [1.0, 0.0, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match="count: the last 2 edges are not all relative-pose"):
        g.remove_last_edges(2)
    with pytest.raises(ValueError, match="count: expected an int >= 0, got -1"):
        g.remove_last_edges(-1)


@pytest.mark.parametrize("dim", [2, 3])
def test_move_gauge_puts_the_key_at_the_pose_and_keeps_every_relative_pose(dim: int) -> None:
    g = G.Graph(dim)
    pose = SE2 if dim == 2 else SE3
    along = [pose.exp(np.r_[x, 0.1 * x, [0.0] * (g.dof - 3), 0.05 * x]) for x in (0.0, 1.0, 2.0)]
    for k, p in enumerate(along):
        g.add_node(k, p)
    g.add_prior(0, pose.identity(), np.eye(g.dof) * 1e2)
    g.add_edge(0, 1, along[0].inverse() @ along[1], _info(dim))
    g.add_edge(1, 2, along[1].inverse() @ along[2], _info(dim))
    loop = along[0].inverse() @ along[2]
    off = pose.exp(np.r_[[0.3] * dim, [0.01] * (g.dof - dim)])
    g.add_edge(0, 2, loop @ off, _info(dim), kind="loop")
    g.optimize()
    before = g.poses()
    target = pose.exp(np.r_[[0.5] * dim, [0.2] * (g.dof - dim)])  # anywhere, not the prior
    g.move_gauge(0, target)
    after = g.poses()
    assert np.abs((target.inverse() @ after[0]).log()).max() < 1e-9
    for i, j in ((0, 1), (1, 2), (0, 2)):
        rel_before = before[i].inverse() @ before[j]
        rel_after = after[i].inverse() @ after[j]
        assert np.abs((rel_before.inverse() @ rel_after).log()).max() < 1e-9
    # Back at the prior's pose, the next incremental update builds on the moved estimate.
    g.move_gauge(0, pose.identity())
    back = g.poses()
    g.add_node(3, back[2] @ (along[1].inverse() @ along[2]))
    g.add_edge(2, 3, along[1].inverse() @ along[2], _info(dim))
    g.update()
    assert np.abs((g.pose(2).inverse() @ back[2]).log()).max() < 1e-6
    with pytest.raises(TypeError, match="pose"):
        g.move_gauge(0, SE3.identity() if dim == 2 else SE2.identity())
    with pytest.raises(ValueError, match="node 9"):
        g.move_gauge(9, pose.identity())


def test_covariances_read_again_are_the_same_until_the_solve_changes() -> None:
    # The graph keeps what it read off the current solve: the same bits again (a copy the
    # caller may change), and a new solve's own after an update, a batch solve or a dropped
    # edge (the loop, as certain as the chain's two edges together, cuts the 0-2 variance to
    # a third: a stale answer would be the chain's).
    chain = G.Graph(2)
    for k in range(3):
        chain.add_node(k, SE2.from_vector([float(k), 0, 0]))
    chain.add_prior(0, SE2.identity(), np.eye(3) * 1e12)
    for k in range(2):
        chain.add_edge(k, k + 1, SE2.from_vector([1.0, 0, 0]), _info(2))
    chain.update()
    first = chain.relative_covariance(0, 2)
    first[0, 0] = -1.0
    again = chain.relative_covariance(0, 2)
    assert again[0, 0] > 0
    assert np.array_equal(again, chain.relative_covariance(0, 2))
    marginal = chain.marginal_covariance(2)
    assert np.array_equal(marginal, chain.marginal_covariance(2))
    # A loop edge added but not solved changes nothing read; solved, it does.
    chain.add_edge(0, 2, SE2.from_vector([2.2, 0, 0]), _info(2), kind="loop")
    assert np.array_equal(again, chain.relative_covariance(0, 2))
    chain.update()
    looped = chain.relative_covariance(0, 2)
    assert looped[0, 0] == pytest.approx(again[0, 0] / 3, rel=1e-6)
    chain.remove_last_edges(1)
    chain.optimize()
    assert chain.relative_covariance(0, 2)[0, 0] == pytest.approx(again[0, 0], rel=1e-6)
    assert chain.marginal_covariance(2)[0, 0] == pytest.approx(marginal[0, 0], rel=1e-6)


def test_pose_vectors_follow_every_change_of_the_estimate() -> None:
    # pose_vectors is kept between solves: read-only, and each solve's own after an update,
    # a batch solve, a gauge move (the loop's 2.2 m, as certain as the chain's two edges
    # together, pulls node 2 from 2.0 m to their weighted mean, 3.2 / 1.5 m).
    g = G.Graph(2)
    for k in range(3):
        g.add_node(k, SE2.from_vector([float(k), 0, 0]))
    g.add_prior(0, SE2.identity(), np.eye(3) * 1e12)
    for k in range(2):
        g.add_edge(k, k + 1, SE2.from_vector([1.0, 0, 0]), _info(2))
    g.update()
    keys, rows = g.pose_vectors()
    assert keys == [0, 1, 2] and rows[2, 0] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="read-only"):
        rows[0, 0] = 5.0
    keys.append(7)  # the caller's own list
    assert g.pose_vectors()[0] == [0, 1, 2]
    g.add_edge(0, 2, SE2.from_vector([2.2, 0, 0]), _info(2), kind="loop")
    assert g.pose_vectors()[1][2, 0] == pytest.approx(2.0)  # not solved yet
    g.update(extra_iterations=2)
    solved = g.pose_vectors()[1]
    assert solved[2, 0] == pytest.approx(3.2 / 1.5, rel=1e-6)
    g.move_gauge(0, SE2.from_vector([0.0, 1.0, 0.0]))
    assert g.pose_vectors()[1][:, 1] == pytest.approx([1.0, 1.0, 1.0])
    g.optimize()
    assert np.array_equal(g.pose_vectors()[1], np.array([g.pose(k).as_vector() for k in range(3)]))


def test_edges_with_the_same_information_each_keep_their_own_copy() -> None:
    g = G.Graph(2)
    for k in range(3):
        g.add_node(k, SE2.from_vector([float(k), 0, 0]))
    info = _info(2)
    g.add_edge(0, 1, SE2.from_vector([1.0, 0, 0]), info)
    g.add_edge(1, 2, SE2.from_vector([1.0, 0, 0]), info)
    first, second = g.edges
    assert first.information is not second.information
    assert np.array_equal(first.information, second.information)
    first.information[0, 0] = 0.0
    assert second.information[0, 0] == info[0, 0]
    # A matrix refused once is refused again (nothing of it was kept).
    bad = np.diag([1.0, -1.0, 1.0])
    for _ in range(2):
        with pytest.raises(ValueError, match="positive semi-definite"):
            g.add_edge(0, 2, SE2.from_vector([2.0, 0, 0]), bad)
