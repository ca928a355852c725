"""The jaxtyping shape annotations are checked (tests/conftest.py's import hook with beartype).

Each rejected call below is one that JAX alone would run without complaint (broadcasting, clamped
indexing) or reject only with an unrelated error; the checks name the argument and dimension.
"""

import os

import jax
import jax.numpy as jnp
import pytest
from jaxtyping import TypeCheckError

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.states import INS15
from jaxnav.filter import ekf
from jaxnav.gnss import corrections, models
from jaxnav.ins import errors, strapdown

pytestmark = pytest.mark.skipif(
    os.environ.get("JAXNAV_TYPECHECK") == "0", reason="type checks off (JAXNAV_TYPECHECK=0)"
)

N, M = 4, 3
LLH = jnp.array([0.7, 0.1, 120.0])


def _update_args(n=N, m=M):
    P = jnp.eye(n) * 2.0
    H = jnp.ones((m, n)) + jnp.arange(m)[:, None]
    return jnp.zeros(n), P, jnp.ones(m), H, jnp.eye(m), jnp.ones(m, bool)


def test_correctly_shaped_calls_pass():
    x, P, y, H, R, mask = _update_args()
    res = ekf.masked_update(x, P, y, H, R, mask, ekf.CHI2_1DOF_999)
    assert res.x.shape == (N,) and res.P.shape == (N, N) and res.used.shape == (M,)
    F, G, Qc = jnp.eye(N) * 0.01, jnp.ones((N, 2)), jnp.eye(2)
    Phi, Qd = ekf.discretize(F, G, Qc, 1.0)
    x2, P2 = ekf.predict(x, P, Phi, Qd)
    assert x2.shape == (N,) and P2.shape == (N, N)
    nav = strapdown.nav_state(LLH, jnp.zeros(3), jnp.zeros(3))
    imu = strapdown.stationary_imu(LLH, nav.C_b_l, 0.01)
    assert strapdown.mechanize_step(nav, imu, imu, 0.01).llh.shape == (3,)
    F, G, Qc = errors.error_dynamics(
        INS15, LLH, jnp.zeros(3), nav.C_b_l, jnp.array([0.0, 0.0, 9.8]), jnp.zeros(3), _model()
    )
    assert F.shape == (15, 15) and G.shape[0] == 15 and Qc.shape == (G.shape[1],) * 2


def _model():
    return errors.ImuErrorModel(1e-3, 1e-4, 1e-3, 300.0, 1e-5, 300.0)


def test_masked_update_rejects_a_covariance_of_another_size():
    x, _, y, H, R, mask = _update_args()
    with pytest.raises(TypeCheckError, match="P"):
        ekf.masked_update(x, jnp.eye(N + 1), y, H, R, mask)


def test_masked_update_rejects_a_measurement_noise_that_would_broadcast():
    # R [1, 1] broadcasts against H P H^T [m, m]: JAX would silently update with R = r I-ish.
    x, P, y, H, _, mask = _update_args()
    with pytest.raises(TypeCheckError, match="R"):
        ekf.masked_update(x, P, y, H, jnp.ones((1, 1)), mask)


def test_predict_rejects_process_noise_that_would_broadcast():
    x, P, *_ = _update_args()
    with pytest.raises(TypeCheckError, match="Qd"):
        ekf.predict(x, P, jnp.eye(N), jnp.full((1, N), 0.1))


def test_checks_run_inside_jit_at_trace_time():
    x, P, y, H, R, mask = _update_args()

    @jax.jit
    def step(P):
        return ekf.predict(x, P, jnp.eye(N), jnp.eye(N))[1]

    assert step(P).shape == (N, N)
    with pytest.raises(TypeCheckError):
        step(jnp.eye(N + 2))


def test_mechanization_step_rejects_a_2_vector_position():
    # Without the check JAX fails only later, on a broadcast inside the step.
    nav = strapdown.nav_state(LLH, jnp.zeros(3), jnp.zeros(3))
    imu = strapdown.stationary_imu(LLH, nav.C_b_l, 0.01)
    bad = nav._replace(llh=LLH[:2])
    with pytest.raises(TypeCheckError, match="llh"):
        strapdown.mechanize_step(bad, imu, imu, 0.01)


def test_receiver_geometry_rejects_a_2_vector_antenna():
    S = 5
    sat = models.SatEpoch(
        jnp.full((S, 3), 2.0e7), jnp.zeros((S, 3)), jnp.zeros(S), jnp.zeros(S)
    )
    with pytest.raises(TypeCheckError, match="rx_pos_ecef"):
        models.geometry(jnp.array([6.4e6, 0.0]), jnp.zeros(3), sat)
    with pytest.raises(TypeCheckError, match="tau_s"):
        corrections.earth_rotation_correct(jnp.ones((S, 3)), jnp.ones(S + 1))
