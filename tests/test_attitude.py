"""Attitude conventions: one documented convention, round trips, and its physical meaning."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxnav  # noqa: F401
from jaxnav import attitude as att

angles = st.tuples(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.14, 3.14))


def test_euler_convention_physical_meaning():
    # Azimuth 90 deg (facing east): body forward (y) points east, body right (x) points south.
    C = att.dcm_from_euler(jnp.array([0.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose(C @ jnp.array([0.0, 1.0, 0.0]), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(C @ jnp.array([1.0, 0.0, 0.0]), [0, -1, 0], atol=1e-15)
    # Pitch up 10 deg facing north: forward gains a positive up component.
    C = att.dcm_from_euler(jnp.array([0.0, np.radians(10), 0.0]))
    np.testing.assert_allclose(
        C @ jnp.array([0.0, 1.0, 0.0]),
        [0, np.cos(np.radians(10)), np.sin(np.radians(10))],
        atol=1e-15,
    )
    # Positive roll (right wing down, RFU body) lowers the right axis.
    C = att.dcm_from_euler(jnp.array([np.radians(5), 0.0, 0.0]))
    assert float((C @ jnp.array([1.0, 0.0, 0.0]))[2]) < 0.0


@settings(max_examples=100, deadline=None)
@given(angles)
def test_round_trips(e):
    e = jnp.array(e)
    C = att.dcm_from_euler(e)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(att.euler_from_dcm(C), e, atol=1e-9)
    q = att.quat_from_dcm(C)
    assert float(jnp.linalg.norm(q)) == pytest.approx(1.0)
    np.testing.assert_allclose(att.dcm_from_quat(q), C, atol=1e-14)
    phi = att.rotvec_from_quat(q)
    np.testing.assert_allclose(att.dcm_from_rotvec(phi), C, atol=1e-13)


def test_quaternion_product_composes_rotations():
    rng = np.random.default_rng(2)
    for _ in range(20):
        a, b = (jnp.array(rng.normal(size=3)) for _ in range(2))
        qa, qb = att.quat_from_rotvec(a), att.quat_from_rotvec(b)
        np.testing.assert_allclose(
            att.dcm_from_quat(att.quat_multiply(qa, qb)),
            att.dcm_from_quat(qa) @ att.dcm_from_quat(qb),
            atol=1e-14,
        )
        v = jnp.array(rng.normal(size=3))
        vq = jnp.concatenate([jnp.zeros(1), v])
        rotated = att.quat_multiply(att.quat_multiply(qa, vq), att.quat_conjugate(qa))[1:]
        np.testing.assert_allclose(rotated, att.dcm_from_quat(qa) @ v, atol=1e-14)


def test_rotvec_small_angle_is_smooth_and_exact():
    phi = jnp.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(att.rotvec_from_quat(att.quat_from_rotvec(phi)), phi, rtol=1e-12)
    J = jax.jacfwd(att.quat_from_rotvec)(jnp.zeros(3))
    np.testing.assert_allclose(J[1:], 0.5 * np.eye(3), atol=1e-15)
    # Rodrigues check at a finite angle.
    phi = jnp.array([0.0, 0.0, 0.3])
    C = att.dcm_from_rotvec(phi)
    np.testing.assert_allclose(
        C[:2, :2], [[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]], atol=1e-15
    )


def test_attitude_error_convention_and_correction():
    C = att.dcm_from_euler(jnp.array([0.05, -0.1, 1.0]))
    eps = jnp.array([1e-3, -2e-3, 5e-3])
    C_hat = (jnp.eye(3) - att.skew(eps)) @ C
    # Recovered to first order; the second-order residual is ~|eps|^2.
    np.testing.assert_allclose(att.attitude_error(C_hat, C), eps, atol=3e-5)
    C_fixed = att.correct_attitude(C_hat, eps)
    assert float(jnp.abs(C_fixed - C).max()) < 3e-5
    # Exact when the error is applied as a rotation.
    C_hat = att.dcm_from_rotvec(-eps) @ C
    np.testing.assert_allclose(att.attitude_error(C_hat, C), eps, atol=1e-15)
    np.testing.assert_allclose(att.correct_attitude(C_hat, eps), C, atol=1e-15)


def test_wrap_angle():
    np.testing.assert_allclose(
        att.wrap_angle(jnp.array([3 * np.pi / 2, -3 * np.pi / 2, 0.1])),
        [-np.pi / 2, np.pi / 2, 0.1],
        atol=1e-15,
    )


def test_dcm_euler_partials_match_autodiff():
    e = jnp.array([0.1, -0.25, 2.2])
    J = jax.jacfwd(att.dcm_from_euler)(e)  # [3, 3, 3]
    for k, d in enumerate(att.dcm_euler_partials(e)):
        np.testing.assert_allclose(d, J[:, :, k], atol=1e-15)
