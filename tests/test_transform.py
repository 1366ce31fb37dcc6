"""SE(2)/SE(3): group laws, exp/log, adjoint and validation (property-based)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scanreg import SE2, SE3
from scanreg.transform import so3_exp, so3_log

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-np.pi + 1e-6, np.pi - 1e-6, allow_nan=False)


@st.composite
def se2(draw: st.DrawFn) -> SE2:
    return SE2.from_vector([draw(finite), draw(finite), draw(angle)])


@st.composite
def rotvec(draw: st.DrawFn, max_angle: float = np.pi - 1e-6) -> np.ndarray:
    axis = draw(arrays(np.float64, 3, elements=st.floats(-1, 1)))
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    return axis / np.linalg.norm(axis) * draw(st.floats(0.0, max_angle))


@st.composite
def se3(draw: st.DrawFn) -> SE3:
    t = [draw(finite), draw(finite), draw(finite)]
    return SE3.from_vector(np.concatenate([t, draw(rotvec())]))


tangent2 = arrays(np.float64, 3, elements=st.floats(-3.0, 3.0))
tangent3 = st.builds(
    lambda t, r: np.concatenate([t, r]),
    arrays(np.float64, 3, elements=st.floats(-3.0, 3.0)),
    rotvec(max_angle=3.0),
)
pose = st.one_of(se2(), se3())


def _close(a: SE2 | SE3, b: SE2 | SE3, atol: float = 1e-9) -> bool:
    return a.is_close(b, atol=atol)


@given(se2(), se2(), se2())
def test_se2_associative(a: SE2, b: SE2, c: SE2) -> None:
    assert _close((a @ b) @ c, a @ (b @ c))


@given(se3(), se3(), se3())
def test_se3_associative(a: SE3, b: SE3, c: SE3) -> None:
    assert _close((a @ b) @ c, a @ (b @ c), atol=1e-8)


@given(pose)
def test_inverse(t: SE2 | SE3) -> None:
    ident = type(t).identity()
    assert _close(t @ t.inverse(), ident)
    assert _close(t.inverse() @ t, ident)


@given(tangent2)
def test_se2_exp_log_round_trip(xi: np.ndarray) -> None:
    xi = xi.copy()
    xi[2] = np.clip(xi[2], -np.pi + 1e-6, np.pi - 1e-6)
    np.testing.assert_allclose(SE2.exp(xi).log(), xi, atol=1e-9)


@given(tangent3)
def test_se3_exp_log_round_trip(xi: np.ndarray) -> None:
    np.testing.assert_allclose(SE3.exp(xi).log(), xi, atol=1e-8)


@given(pose)
def test_log_exp_round_trip(t: SE2 | SE3) -> None:
    assert _close(type(t).exp(t.log()), t, atol=1e-8)


@given(pose)
def test_vector_round_trip(t: SE2 | SE3) -> None:
    assert _close(type(t).from_vector(t.as_vector()), t, atol=1e-8)
    assert _close(type(t).from_matrix(t.as_matrix()), t)


@given(se2(), tangent2)
def test_se2_adjoint(t: SE2, xi: np.ndarray) -> None:
    assert _close(t @ SE2.exp(xi), SE2.exp(t.adjoint() @ xi) @ t, atol=1e-8)


@given(se3(), tangent3)
def test_se3_adjoint(t: SE3, xi: np.ndarray) -> None:
    assert _close(t @ SE3.exp(xi), SE3.exp(t.adjoint() @ xi) @ t, atol=1e-7)


@given(se3(), se3())
def test_adjoint_is_a_homomorphism(a: SE3, b: SE3) -> None:
    np.testing.assert_allclose((a @ b).adjoint(), a.adjoint() @ b.adjoint(), atol=1e-8)


@given(pose, st.floats(0.0, 1.0))
def test_interpolation_endpoints_and_geodesic(t: SE2 | SE3, alpha: float) -> None:
    a = type(t).identity()
    assert _close(a.interpolate(t, 0.0), a)
    assert _close(a.interpolate(t, 1.0), t, atol=1e-8)
    # From the identity, interpolation scales the tangent vector.
    np.testing.assert_allclose(a.interpolate(t, alpha).log(), alpha * t.log(), atol=1e-7)


@given(pose)
def test_apply_matches_matrix(t: SE2 | SE3) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(7, t.DIM))
    homog = np.column_stack([pts, np.ones(7)]) @ t.as_matrix().T
    np.testing.assert_allclose(t.apply(pts), homog[:, : t.DIM], atol=1e-12)


@settings(max_examples=50)
@given(rotvec())
def test_so3_log_near_pi_and_zero(r: np.ndarray) -> None:
    np.testing.assert_allclose(so3_exp(so3_log(so3_exp(r))), so3_exp(r), atol=1e-9)


def test_so3_log_exactly_pi() -> None:
    for axis in np.eye(3):
        r = so3_exp(np.pi * axis)
        np.testing.assert_allclose(np.abs(so3_log(r)), np.pi * axis, atol=1e-9)


def test_composition_convention() -> None:
    # T_a_b @ T_b_c maps c-coordinates to a: rotate by 90° then translate.
    t_a_b = SE2.from_vector([1.0, 0.0, np.pi / 2])
    t_b_c = SE2.from_vector([1.0, 0.0, 0.0])
    p_c = np.array([[0.0, 0.0]])
    np.testing.assert_allclose((t_a_b @ t_b_c).apply(p_c), [[1.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(t_a_b.apply(t_b_c.apply(p_c)), [[1.0, 1.0]], atol=1e-12)


def test_validation_errors() -> None:
    with pytest.raises(ValueError, match="rotation: not orthonormal"):
        SE3(np.diag([1.0, 1.0, 1.1]))
    with pytest.raises(ValueError, match="rotation: is a reflection"):
        SE2(np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match=r"matrix: expected shape \(4, 4\)"):
        SE3.from_matrix(np.eye(3))
    with pytest.raises(ValueError, match="matrix: last row"):
        m = np.eye(3)
        m[2, 0] = 1.0
        SE2.from_matrix(m)
    with pytest.raises(ValueError, match="vector: contains NaN"):
        SE2.from_vector([0.0, np.nan, 0.0])
    with pytest.raises(TypeError, match="vector: expected a real numeric array"):
        SE2.from_vector(np.array(["a", "b", "c"]))
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\)"):
        SE3().apply(np.zeros((4, 2)))
    with pytest.raises(AttributeError, match="immutable"):
        SE3().foo = 1  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="read-only"):
        SE3().rotation[0, 0] = 2.0


def test_nearly_orthonormal_input_is_projected() -> None:
    r = so3_exp(np.array([0.1, 0.2, 0.3])) + 1e-8
    t = SE3(r, np.zeros(3))
    np.testing.assert_allclose(t.rotation.T @ t.rotation, np.eye(3), atol=1e-14)


def test_poses_pickle_bit_identically() -> None:
    import pickle

    for pose in (
        SE2.from_vector([1.0, -2.0, 0.3]),
        SE3.from_vector([1.0, -2.0, 0.5, 0.1, -0.2, 0.3]),
    ):
        back = pickle.loads(pickle.dumps(pose))
        assert type(back) is type(pose)
        assert np.array_equal(back.as_matrix(), pose.as_matrix())
        with pytest.raises(AttributeError, match="immutable"):
            back._rotation = np.eye(pose.DIM)  # type: ignore[misc]


@pytest.mark.parametrize("cls", [SE2, SE3])
def test_orthonormalized_removes_round_off_and_keeps_clean_poses(cls: type) -> None:
    rng = np.random.default_rng(3)
    pose = cls.exp(rng.normal(size=cls.DOF))
    assert pose.orthonormalized() is pose  # clean: the same object, bit for bit
    drifted = cls._unchecked(pose.rotation * (1.0 + 1e-6), pose.translation)
    fixed = drifted.orthonormalized()
    r = fixed.rotation
    assert np.abs(r.T @ r - np.eye(cls.DIM)).max() < 1e-14
    assert np.abs(r - pose.rotation).max() < 1e-14  # a uniform scale projects back exactly
    np.testing.assert_array_equal(fixed.translation, pose.translation)
