"""jaxnav against its peers on identical inputs: FilterPy, dynamax and a plain NumPy loop.

Two problems, each run by every implementation that applies to it, side by side in one process,
on the same input arrays, with the outputs checked to agree before any time is reported:

1. Linear-Gaussian tracking. A 3D constant-velocity target (state [pos, vel], 6; position
   measurements, 3; dt = 1 s, white-acceleration process noise), T epochs x B independent
   tracks. jaxnav: ``filter.ekf.predict`` + ``filter.ekf.masked_update`` (Joseph form, Cholesky
   solve) in ``lax.scan``, ``vmap`` over tracks in chunks of 64 (``lax.map(batch_size=64)``:
   wider batched solves have stalled XLA:CPU on this machine), jitted. dynamax:
   ``linear_gaussian_ssm.lgssm_filter`` the same way (it also accumulates the marginal
   log-likelihood, which is part of its filter). FilterPy: ``kalman.KalmanFilter`` predict /
   update per track, on a subset of the tracks (its time is scaled per track). NumPy: the time
   loop written directly, vectorised over the tracks (batched matmul / solve).
2. Loosely coupled INS. ``jaxnav.filter.loose`` with the INS15 system on a simulated 100 Hz
   drive with 1 Hz GNSS position + velocity fixes at a lever-armed antenna and one GNSS outage,
   B realisations (IMU turn-on biases and white noise, GNSS noise) vmapped and jitted.
   NumPy: the same filter ported (``NumpyLooseIns15`` + ``numpy_nav``: strapdown step with coning,
   sculling and second-order l-frame terms, INS15 F/G/Qc, Taylor discretisation, lever-armed
   position/velocity rows, Joseph update, closed-loop feedback), a Python loop over epochs and
   IMU samples, one realisation at a time. FilterPy: ``kalman.ExtendedKalmanFilter`` carries
   the EKF algebra (predict with the supplied Phi, Qd; update with the supplied H and the
   linear error-state measurement function) inside the same NumPy loop, which still does the
   mechanization and the Jacobians: FilterPy has no INS. dynamax does not apply: its nonlinear
   filters (``dynamax.nonlinear_gaussian_ssm``) take a fixed-dimension state transition
   function and autodiff Jacobians, while this filter mechanizes 100 IMU samples per epoch,
   feeds the error estimate back into the whole-state (quaternion) navigation solution and
   resets the error state; there is nothing to compare but the 15x15 algebra, which case 1
   already times.

Agreement (printed, and bounded in ``tests/test_bench_peers.py``): every difference is scaled
by the filter's own uncertainty, |d x_i| / sqrt(P_ii) for means and |d P_ij| / sqrt(P_ii P_jj)
for covariances, so that it reads "fraction of a standard deviation" whatever the units.
Case 1 tolerance 1e-8. jaxnav, NumPy and FilterPy all use the Joseph form and differ only in
how S is inverted (Cholesky, LU solve, explicit inverse) and where they symmetrise: rounding,
2e-12 sigma measured at most (the filter is stable, so it does not grow). dynamax uses
P - K S K^T and, by design, solves with S + 1e-9 I (``dynamax.utils.psd_solve``'s
``diagonal_boost``): with S >= R = 9 m^2 that is a 1e-10 relative change of the gain, measured
as ~3e-10 sigma from the first epoch on. 1e-8 is 30x above that and far below any real
algorithmic difference (half the Q shows at > 1e-2, see the test). Case 2 tolerance 1e-6: on
top of the algebra, the mechanization runs 100 nonlinear steps per epoch with a different
order of floating-point operations (libm vs XLA sin/cos, fused vs separate products), whose
rounding the closed-loop filter then sees as a tiny error to correct; measured 5e-9 sigma
(1e-9 m) at most on the 300 s drive, 3e-12 sigma on the 40 s quick one.

Run from the project root: ``python benchmarks/peers.py`` (~35 s on 2 idle cores, up to ~3 min
on a busy machine) or ``--quick`` (~20 s, what the test runs). Results are appended to
``benchmarks/RESULTS.md`` (``--results PATH``, ``--no-append``); the last printed line is one
JSON object.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import benchutil  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy_nav as nn  # noqa: E402  (the NumPy INS port shared with numpy_filter.py)

import jaxnav  # noqa: E402, F401  (float64)
from jaxnav import attitude, geodesy  # noqa: E402
from jaxnav.core.states import INS15  # noqa: E402
from jaxnav.filter import ekf, loose  # noqa: E402
from jaxnav.filter.systems import InsSystem, NavSigmas  # noqa: E402
from jaxnav.ins import strapdown  # noqa: E402
from jaxnav.sim import sensors  # noqa: E402
from jaxnav.sim import trajectory as tr  # noqa: E402

#: Agreement tolerances (module docstring): in standard deviations of the filter's own P.
TOL_LG = 1e-8
TOL_INS = 1e-6
CHUNK = 64  # widest vmap of a long scan on this machine (see the module docstring)

SIZES = {
    # T epochs, B tracks, FilterPy tracks; drive s, B realisations, NumPy / FilterPy runs
    "full": dict(lg_T=1000, lg_B=256, lg_fp=16, ins_s=300, ins_B=64, ins_np=2, ins_fp=1),
    "quick": dict(lg_T=200, lg_B=64, lg_fp=2, ins_s=40, ins_B=4, ins_np=1, ins_fp=1),
}


def _peer(name):
    """Import a peer package, or return (None, reason) when it is not installed."""
    try:
        if name == "filterpy":
            from filterpy.kalman import ExtendedKalmanFilter, KalmanFilter

            return (KalmanFilter, ExtendedKalmanFilter), None
        if name == "dynamax":
            from dynamax.linear_gaussian_ssm import (
                ParamsLGSSM,
                ParamsLGSSMDynamics,
                ParamsLGSSMEmissions,
                ParamsLGSSMInitial,
                lgssm_filter,
            )

            return (
                lgssm_filter,
                ParamsLGSSM,
                ParamsLGSSMInitial,
                ParamsLGSSMDynamics,
                ParamsLGSSMEmissions,
            ), None
    except Exception as exc:  # any import failure (absent, or broken against this jax) skips
        return None, f"{name} not importable: {type(exc).__name__}: {exc}"
    raise ValueError(name)


def _version(name):
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def _jax_timed(fn, args, repeats):
    """Compile ``jax.jit(fn)`` for ``args`` (timed), then run it ``repeats`` times (best)."""
    with benchutil.Timer() as tc:
        compiled = jax.jit(fn).lower(*args).compile()
    best, out = math.inf, None
    for _ in range(repeats):
        with benchutil.Timer() as tr_:
            out = jax.block_until_ready(compiled(*args))
        best = min(best, tr_.s)
    return out, tc.s, best


# ================================================================================================
# Case 1: linear-Gaussian tracking
# ================================================================================================
def lg_model(dt=1.0, q_psd=0.05, sigma_meas_m=3.0):
    """Constant-velocity model: Phi = [[I, dt I], [0, I]], Qd the exact white-acceleration
    discretisation q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (x) I3 (q chosen: 0.05 m^2/s^3, a gently
    manoeuvring target), H = [I 0], R = sigma^2 I (chosen: 3 m)."""
    eye = np.eye(3)
    F = np.block([[eye, dt * eye], [np.zeros((3, 3)), eye]])
    Q = q_psd * np.block([[dt**3 / 3 * eye, dt**2 / 2 * eye], [dt**2 / 2 * eye, dt * eye]])
    H = np.hstack([eye, np.zeros((3, 3))])
    R = sigma_meas_m**2 * eye
    P0 = np.diag([50.0**2] * 3 + [5.0**2] * 3)  # chosen: a coarse first guess
    return F, Q, H, R, P0


def lg_simulate(T, B, seed=1):
    """Truth tracks and measurements (NumPy): x0 ~ N(0, P0), x+ = F x + w, z = H x + v."""
    F, Q, H, R, P0 = lg_model()
    rng = np.random.default_rng(seed)
    lq, lr, lp = np.linalg.cholesky(Q), np.linalg.cholesky(R), np.linalg.cholesky(P0)
    x = rng.standard_normal((B, 6)) @ lp.T
    x0_hat = x + rng.standard_normal((B, 6)) @ lp.T  # the filters' initial estimate
    zs = np.empty((B, T, 3))
    for t in range(T):
        x = x @ F.T + rng.standard_normal((B, 6)) @ lq.T
        zs[:, t] = x @ H.T + rng.standard_normal((B, 3)) @ lr.T
    return x0_hat, zs


def lg_jaxnav(x0, zs, F, Q, H, R, P0):
    """jaxnav: predict + masked Joseph update per epoch (every row used, no gate)."""
    mask = jnp.ones(H.shape[0], bool)

    def one(x0_zs):
        x0_, zs_ = x0_zs

        def step(c, z):
            x, P = ekf.predict(*c, F, Q)
            res = ekf.masked_update(x, P, z, H, R, mask)
            return (res.x, res.P), (res.x, res.P)

        return jax.lax.scan(step, (x0_, P0), zs_)[1]

    return jax.lax.map(one, (x0, zs), batch_size=CHUNK)


def lg_dynamax(mods, x1, P1, zs, F, Q, H, R):
    """dynamax: lgssm_filter conditions on y_1 first, so it starts from the predicted prior."""
    lgssm_filter, Params, Init, Dyn, Emis = mods

    def one(x1_zs):
        x1_, zs_ = x1_zs
        params = Params(Init(x1_, P1), Dyn(F, None, None, Q), Emis(H, None, None, R))
        post = lgssm_filter(params, zs_)
        return post.filtered_means, post.filtered_covariances

    return jax.lax.map(one, (x1, zs), batch_size=CHUNK)


def lg_numpy(x0, zs, F, Q, H, R, P0):
    """Plain NumPy: a loop over epochs, every track at once (batched matmul and solve)."""
    B, T, m = zs.shape
    n = F.shape[0]
    x = x0.copy()
    P = np.broadcast_to(P0, (B, n, n)).copy()
    xs, Ps = np.empty((B, T, n)), np.empty((B, T, n, n))
    eye = np.eye(n)
    for t in range(T):
        x = x @ F.T
        P = F @ P @ F.T + Q
        P = 0.5 * (P + P.swapaxes(-1, -2))
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).swapaxes(-1, -2)  # S symmetric: K^T = S^-1 H P
        nu = zs[:, t] - x @ H.T
        x = x + (K @ nu[..., None])[..., 0]
        IKH = eye - K @ H
        P = IKH @ P @ IKH.swapaxes(-1, -2) + K @ R @ K.swapaxes(-1, -2)
        P = 0.5 * (P + P.swapaxes(-1, -2))
        xs[:, t], Ps[:, t] = x, P
    return xs, Ps


def lg_filterpy(KalmanFilter, x0, zs, F, Q, H, R, P0):
    """FilterPy: one KalmanFilter object per track, predict() / update(z) per epoch."""
    B, T, m = zs.shape
    n = F.shape[0]
    xs, Ps = np.empty((B, T, n)), np.empty((B, T, n, n))
    for b in range(B):
        kf = KalmanFilter(dim_x=n, dim_z=m)
        kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = x0[b][:, None].copy(), P0.copy(), F, Q, H, R
        for t in range(T):
            kf.predict()
            kf.update(zs[b, t])
            xs[b, t], Ps[b, t] = kf.x[:, 0], kf.P
    return xs, Ps


def sigma_scaled_diff(x_ref, P_ref, x, P):
    """max |dx_i| / sqrt(P_ii) and max |dP_ij| / sqrt(P_ii P_jj) over everything given."""
    d = np.sqrt(np.diagonal(P_ref, axis1=-2, axis2=-1))
    dx = np.max(np.abs(x - x_ref) / d)
    dP = np.max(np.abs(P - P_ref) / (d[..., :, None] * d[..., None, :]))
    return float(dx), float(dP)


def run_tracking(sz, repeats):
    T, B, B_fp = sz["lg_T"], sz["lg_B"], sz["lg_fp"]
    F, Q, H, R, P0 = lg_model()
    x0, zs = lg_simulate(T, B)
    rows = []
    args = tuple(jnp.asarray(a) for a in (x0, zs, F, Q, H, R, P0))
    (xs_j, Ps_j), tc, tr_ = _jax_timed(lg_jaxnav, args, repeats)
    xs_j, Ps_j = np.asarray(xs_j), np.asarray(Ps_j)
    rows.append(dict(impl="jaxnav (jit, vmap)", n=B, compile_s=tc, run_s=tr_, diff=0.0))

    with benchutil.Timer() as t_np:
        xs_n, Ps_n = lg_numpy(x0, zs, F, Q, H, R, P0)
    rows.append(
        dict(
            impl="NumPy loop (batched over tracks)",
            n=B,
            compile_s=None,
            run_s=t_np.s,
            diff=max(sigma_scaled_diff(xs_j, Ps_j, xs_n, Ps_n)),
        )
    )

    fp, why = _peer("filterpy")
    if fp is None:
        rows.append(dict(impl="FilterPy KalmanFilter", skipped=why))
    else:
        with benchutil.Timer() as t_fp:
            xs_f, Ps_f = lg_filterpy(fp[0], x0[:B_fp], zs[:B_fp], F, Q, H, R, P0)
        rows.append(
            dict(
                impl=f"FilterPy {_version('filterpy')} KalmanFilter (per track)",
                n=B_fp,
                compile_s=None,
                run_s=t_fp.s,
                diff=max(sigma_scaled_diff(xs_j[:B_fp], Ps_j[:B_fp], xs_f, Ps_f)),
            )
        )

    dyn, why = _peer("dynamax")
    if dyn is None:
        rows.append(dict(impl="dynamax lgssm_filter", skipped=why))
    else:
        P1 = F @ P0 @ F.T + Q
        P1 = 0.5 * (P1 + P1.T)  # the same symmetrised prior jaxnav's first predict produces
        x1 = x0 @ F.T
        dargs = tuple(jnp.asarray(a) for a in (x1, P1, zs, F, Q, H, R))
        (xs_d, Ps_d), tc_d, tr_d = _jax_timed(lambda *a: lg_dynamax(dyn, *a), dargs, repeats)
        rows.append(
            dict(
                impl=f"dynamax {_version('dynamax')} lgssm_filter (jit, vmap)",
                n=B,
                compile_s=tc_d,
                run_s=tr_d,
                diff=max(sigma_scaled_diff(xs_j, Ps_j, np.asarray(xs_d), np.asarray(Ps_d))),
            )
        )
    return rows


# ================================================================================================
# Case 2: loosely coupled INS15 — the scenario and the NumPy port
# ================================================================================================
RATE_HZ = 100.0
K_IMU = 100  # IMU samples per 1 Hz GNSS epoch
LEVER_ANT_B = np.array([0.2, 0.8, 1.4])  # IMU -> antenna, body right-forward-up [m] (chosen)
SIGMA_POS_M, SIGMA_VEL_M_S = 0.5, 0.05  # GNSS fix noise per axis (chosen: a PPP-grade fix)
SEGMENTS = [
    tr.cruise(10.0), tr.turn(90.0, radius_m=40.0), tr.speed_to(20.0, 8.0), tr.cruise(15.0),
    tr.turn(-60.0, radius_m=150.0), tr.grade_to(3.0, 5.0), tr.cruise(10.0), tr.grade_to(0.0, 5.0),
    tr.speed_to(8.0, 8.0), tr.turn(120.0, radius_m=30.0), tr.speed_to(0.0, 6.0), tr.stop(10.0),
    tr.speed_to(12.0, 8.0), tr.turn(-90.0, radius_m=25.0), tr.speed_to(15.0, 5.0),
    tr.cruise(40.0), tr.turn(45.0, radius_m=100.0), tr.cruise(300.0),
]  # fmt: skip


def ins_filter():
    """INS15 loose filter for a tactical IMU (HG1700 preset), GNSS position + velocity rows."""
    grade = sensors.hg1700()
    system = InsSystem(
        layout=INS15, model=loose.imu_error_model(grade), lever_b=jnp.asarray(LEVER_ANT_B)
    )
    return grade, loose.LooseFilter(system, loose.LooseConfig(), 1.0 / RATE_HZ, 1.0)


def ins_simulate(duration_s, B, seed=7):
    """Identical inputs for every implementation, as NumPy arrays.

    Truth: ``sim.trajectory`` (JAX). Errors (NumPy, chosen for a cheap, exactly shared draw):
    per realisation constant turn-on + in-run biases with the grade's combined sigmas, white
    ARW / VRW noise on every increment, white GNSS noise; GNSS withheld over one outage in the
    middle of the drive (20 % of it, at least 10 s).
    """
    grade, lf = ins_filter()
    profile = tr.compile_profile(SEGMENTS, azimuth0_deg=30.0, speed0_mps=10.0)
    truth = tr.generate_truth(profile, RATE_HZ, duration_s=duration_s)
    # Truth at the 1 Hz epochs (every K-th sample), then one jitted function for the antenna
    # truth and the start carry (one compile instead of dozens of eager-op compiles).
    llh_e, vel_e, q_e, w_e, euler_e = (
        np.asarray(a)[::K_IMU]
        for a in (truth.llh, truth.vel_enu, truth.q_b_l, truth.w_ib_b, truth.euler)
    )
    # Start: truth position and velocity, attitude off by (0.1, -0.1, 0.5) deg (chosen).
    euler0 = euler_e[0] + np.radians([0.1, -0.1, 0.5])

    @jax.jit
    def prepare(llh_e, vel_e, q_e, w_e, euler0):
        C = jax.vmap(attitude.dcm_from_quat)(q_e)
        lever = jnp.asarray(LEVER_ANT_B)
        llh_ant = jax.vmap(strapdown.antenna_llh, (0, 0, None))(llh_e, C, lever)
        vel_ant = jax.vmap(strapdown.antenna_vel_enu, (0, 0, 0, 0, None))(
            llh_e, vel_e, C, w_e, lever
        )
        nav0 = loose.initial_nav(llh_e[0], vel_e[0], euler0)
        sig = NavSigmas(pos_m=SIGMA_POS_M, vel_m_s=SIGMA_VEL_M_S)
        return llh_ant, vel_ant, loose.initial_carry(lf, nav0, sig)

    llh_ant, vel_ant, carry0 = prepare(llh_e, vel_e, q_e, w_e, euler0)
    llh_ant, vel_ant = np.asarray(llh_ant), np.asarray(vel_ant)
    n_ep = int(duration_s)
    dth0 = np.asarray(truth.dtheta_b[1:]).reshape(n_ep, K_IMU, 3)
    dv0 = np.asarray(truth.dv_b[1:]).reshape(n_ep, K_IMU, 3)

    rng = np.random.default_rng(seed)
    dt = 1.0 / RATE_HZ
    sg = math.hypot(grade.gyro_bias_turn_on_rad_s, grade.gyro_bias_gm_sigma_rad_s)
    sa = math.hypot(grade.accel_bias_turn_on_m_s2, grade.accel_bias_gm_sigma_m_s2)
    bg = sg * rng.standard_normal((B, 1, 1, 3))
    ba = sa * rng.standard_normal((B, 1, 1, 3))
    dth = (
        dth0
        + bg * dt
        + grade.gyro_arw_rad_sqrt_s * math.sqrt(dt) * rng.standard_normal((B, n_ep, K_IMU, 3))
    )
    dv = (
        dv0
        + ba * dt
        + grade.accel_vrw_m_s_sqrt_s * math.sqrt(dt) * rng.standard_normal((B, n_ep, K_IMU, 3))
    )
    m_n, m_e = _radii_m_per_rad(llh_ant[1:])
    e_pos = SIGMA_POS_M * rng.standard_normal((B, n_ep, 3))
    fix_llh = llh_ant[1:] + np.stack([e_pos[..., 1] / m_n, e_pos[..., 0] / m_e, e_pos[..., 2]], -1)
    fix_vel = vel_ant[1:] + SIGMA_VEL_M_S * rng.standard_normal((B, n_ep, 3))
    t = np.arange(1, n_ep + 1)
    length = max(10, n_ep // 5)
    start = n_ep // 2
    valid = ~((t > start) & (t <= start + length))

    return dict(
        lf=lf,
        grade=grade,
        carry0=carry0,
        dth=dth,
        dv=dv,
        fix_llh=fix_llh,
        fix_vel=fix_vel,
        valid=valid,
        truth_llh=llh_e[1:],
        bias_sigmas=(sa, sg),
    )


def _radii_m_per_rad(llh):
    lat, h = llh[..., 0], llh[..., 2]
    w = np.sqrt(1.0 - geodesy.E2_WGS84 * np.sin(lat) ** 2)
    r_m = geodesy.A_WGS84 * (1.0 - geodesy.E2_WGS84) / w**3
    r_n = geodesy.A_WGS84 / w
    return r_m + h, (r_n + h) * np.cos(lat)


def ins_jaxnav(lf, carry0, dth, dv, fix_llh, fix_vel, valid):
    """jaxnav: ``loose.run`` vmapped over realisations (the start state shared)."""

    def one(dth_, dv_, llh_, vel_):
        fix = loose.gnss_fix(llh_, vel_, SIGMA_POS_M, SIGMA_VEL_M_S, valid, valid)
        inputs = loose.epoch_inputs(strapdown.ImuIncrements(dth_, dv_), fix)
        out = loose.run(lf, carry0, inputs)[1]
        return (
            out.llh,
            out.vel_enu,
            out.euler,
            out.P_nav,
            out.sensors.accel_bias_m_s2,
            out.sensors.gyro_bias_rad_s,
        )

    return jax.vmap(one)(dth, dv, fix_llh, fix_vel)


# ---- NumPy port of loose.epoch_step for InsSystem(INS15) with LooseConfig() defaults ----------
# The INS pieces (strapdown, INS15 error dynamics, lever arm) are benchmarks/numpy_nav.py, shared
# with numpy_filter.py.
_I3 = np.eye(3)


class NumpyLooseIns15:
    """``loose.run`` for ``InsSystem(INS15)`` + ``LooseConfig()`` (GNSS position and velocity
    rows only, one covariance step per epoch, no gate), in NumPy. State order pos, vel, att,
    accel_bias, gyro_bias (INS15); noise order accel, gyro, accel-bias drive, gyro-bias drive.

    ``algebra='numpy'`` writes the EKF predict / Joseph update directly; ``'filterpy'`` hands
    them to a FilterPy ``ExtendedKalmanFilter`` (x = the error state, reset to 0 every epoch).
    """

    def __init__(self, lf: loose.LooseFilter, algebra="numpy", ekf_cls=None):
        m = lf.system.model
        tri = lambda a: np.broadcast_to(np.asarray(a, float), (3,)).copy()
        self.dt = float(lf.imu_dt_s)
        self.lever_b = np.asarray(lf.system.lever_b, float)
        self.tau_a, self.tau_g = tri(m.accel_bias_tau_s), tri(m.gyro_bias_tau_s)
        # errors.gm_share (INS15 lumps turn-on + drift): the drift share of a bias correction
        self.share_a = nn.gm_share(m.accel_bias_sigma_m_s2, m.accel_bias_ton_sigma_m_s2)
        self.share_g = nn.gm_share(m.gyro_bias_sigma_rad_s, m.gyro_bias_ton_sigma_rad_s)
        self.qc = np.concatenate(
            [
                tri(m.accel_vrw_m_s_sqrt_s) ** 2,
                tri(m.gyro_arw_rad_sqrt_s) ** 2,
                2.0 * tri(m.accel_bias_sigma_m_s2) ** 2 / self.tau_a,
                2.0 * tri(m.gyro_bias_sigma_rad_s) ** 2 / self.tau_g,
            ]
        )
        # scale factors INS15 does not estimate (ins.errors.unmodelled_scale_psd)
        self.scale_a, self.scale_g = tri(m.accel_scale_sigma), tri(m.gyro_scale_sigma)
        self.psd_a, self.psd_g = self.qc[0:3], self.qc[3:6]
        self.pos_scale, self.vel_scale = float(lf.cfg.pos_cov_scale), float(lf.cfg.vel_cov_scale)
        self.algebra = algebra
        if algebra == "filterpy":
            self.kf = ekf_cls(dim_x=15, dim_z=6)

    def dynamics(self, llh, vel, C, f_b, w_b):
        """ins.errors.error_dynamics for INS15: F (15, 15), G (15, 12)."""
        F = np.zeros((15, 15))
        blocks = nn.ins15_error_dynamics(llh, vel, C, f_b, self.tau_a, self.tau_g)
        for (row, col), block in blocks.items():
            F[INS15.sl(row), INS15.sl(col)] = block
        G = np.zeros((15, 12))
        G[3:6, 0:3] = C
        G[6:9, 3:6] = -C
        G[9:12, 6:9] = _I3
        G[12:15, 9:12] = _I3
        return F, G

    def rows(self, llh, vel, C, w_b, fix_llh, fix_vel):
        """GNSS position (ENU m) and velocity rows of the lever-armed antenna (loose._gnss_rows
        with InsSystem.antenna; the Jacobians of ins.errors.antenna_*_jacobian)."""
        llh_ant, vel_ant, J_llh_blocks, J_vel_blocks = nn.antenna_lever_arm(
            llh, vel, C, w_b, self.lever_b
        )
        J_llh = np.zeros((3, 15))
        for name, block in J_llh_blocks.items():
            J_llh[:, INS15.sl(name)] = block
        J_vel = np.zeros((3, 15))
        for name, block in J_vel_blocks.items():
            J_vel[:, INS15.sl(name)] = block
        r_ma, r_na = nn.radii(llh_ant[0])
        m_north, m_east = r_ma + llh_ant[2], (r_na + llh_ant[2]) * math.cos(llh_ant[0])
        to_enu = np.array([[0.0, m_east, 0.0], [m_north, 0.0, 0.0], [0.0, 0.0, 1.0]])
        dllh = llh_ant - fix_llh
        dllh[1] = math.atan2(math.sin(dllh[1]), math.cos(dllh[1]))
        C_l_e = nn.C_l_e(llh_ant[0], llh_ant[1])
        dz = np.concatenate([to_enu @ dllh, C_l_e.T @ (C_l_e @ vel_ant) - fix_vel])
        H = np.vstack([to_enu @ J_llh, J_vel])
        R = np.diag([self.pos_scale * SIGMA_POS_M**2] * 3 + [self.vel_scale * SIGMA_VEL_M_S**2] * 3)
        return dz, H, R

    def run(self, nav0, P0, dth, dv, fix_llh, fix_vel, valid):
        """One realisation: ``dth``, ``dv`` [E, K, 3] raw increments; returns per-epoch outputs."""
        llh, vel, q = (np.array(a, float) for a in nav0)
        P = np.array(P0, float)
        prev_th, prev_v = np.zeros(3), np.zeros(3)
        ba, bg = np.zeros(3), np.zeros(3)
        ba_gm, bg_gm = np.zeros(3), np.zeros(3)  # their Gauss-Markov shares
        dt = self.dt
        n_ep, k_imu = dth.shape[:2]
        span = dt * k_imu
        out = {k: np.empty((n_ep, 3)) for k in ("llh", "vel", "euler", "ba", "bg")}
        out["P_nav"] = np.empty((n_ep, 9, 9))
        for e in range(n_ep):
            th_c = dth[e] - bg * dt  # compensation (scale factors are not in INS15)
            v_c = dv[e] - ba * dt
            llh, vel, q = nn.mechanize(llh, vel, q, prev_th, prev_v, th_c, v_c, dt)
            prev_th, prev_v = th_c[-1], v_c[-1]
            f_b, w_b = v_c.sum(0) / span, th_c.sum(0) / span
            C = nn.dcm_from_quat(q)
            F, G = self.dynamics(llh, vel, C, f_b, w_b)
            qc = self.qc.copy()
            qc[6:9] += self.scale_a**2 * nn.input_rate2(v_c, dt, self.psd_a) * span
            qc[9:12] += self.scale_g**2 * nn.input_rate2(th_c, dt, self.psd_g) * span
            # ekf.discretize as loose.py uses it: third-order series, no squarings.
            Phi, Qd = nn.discretize(F, (G * qc) @ G.T, span, squarings=0)
            # the bias estimates decay like the Gauss-Markov model (InsSystem.predict_sensors)
            fa, fg = np.exp(-span / self.tau_a), np.exp(-span / self.tau_g)
            ba, bg = ba - (1.0 - fa) * ba_gm, bg - (1.0 - fg) * bg_gm
            ba_gm, bg_gm = fa * ba_gm, fg * bg_gm
            dz, H, R = self.rows(llh, vel, C, prev_th / dt, fix_llh[e], fix_vel[e])
            dx, P = self._filter(P, Phi, Qd, dz, H, R, bool(valid[e]))
            llh = llh - dx[0:3]
            vel = vel - dx[3:6]
            q = nn.quat_normalize(nn.quat_mul(nn.quat_from_rotvec(dx[6:9]), q))
            ba, bg = ba + dx[9:12], bg + dx[12:15]
            ba_gm, bg_gm = ba_gm + self.share_a * dx[9:12], bg_gm + self.share_g * dx[12:15]
            out["llh"][e], out["vel"][e] = llh, vel
            out["euler"][e] = nn.euler_from_dcm(nn.dcm_from_quat(q))
            out["P_nav"][e], out["ba"][e], out["bg"][e] = P[:9, :9], ba, bg
        return out

    def _filter(self, P, Phi, Qd, dz, H, R, use):
        if self.algebra == "filterpy":
            kf = self.kf
            kf.x, kf.P, kf.F, kf.Q = np.zeros((15, 1)), P, Phi, Qd
            kf.predict()
            if use:
                kf.update(dz[:, None], lambda x: H, lambda x: H @ x, R=R)
            return kf.x[:, 0].copy(), kf.P.copy()
        P = Phi @ P @ Phi.T + Qd
        P = 0.5 * (P + P.T)
        if not use:
            return np.zeros(15), P
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        IKH = np.eye(15) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        return K @ dz, 0.5 * (P + P.T)


def ins_diff(ref, out, b, bias_sigmas):
    """Differences of one realisation against jaxnav's: position, velocity and attitude by the
    filter's sigmas, P_nav by sqrt(P_ii P_jj), the bias estimates by their prior sigmas
    (P_nav holds no bias block); and the largest position difference [m]."""
    P = ref[3][b]
    sig = np.sqrt(np.diagonal(P, axis1=-2, axis2=-1))
    d_att = out["euler"] - ref[2][b]
    d_att = (d_att + np.pi) % (2.0 * np.pi) - np.pi
    diffs = [
        np.abs(out["llh"] - ref[0][b]) / sig[:, 0:3],
        np.abs(out["vel"] - ref[1][b]) / sig[:, 3:6],
        np.abs(d_att) / sig[:, 6:9],
        np.abs(out["P_nav"] - P) / (sig[..., :, None] * sig[..., None, :]),
        np.abs(out["ba"] - ref[4][b]) / bias_sigmas[0],
        np.abs(out["bg"] - ref[5][b]) / bias_sigmas[1],
    ]
    m_n, m_e = _radii_m_per_rad(ref[0][b])
    d_llh = out["llh"] - ref[0][b]
    pos_m = np.sqrt((d_llh[:, 0] * m_n) ** 2 + (d_llh[:, 1] * m_e) ** 2 + d_llh[:, 2] ** 2)
    return max(float(np.max(d)) for d in diffs), float(pos_m.max())


def run_ins(sz, repeats):
    B = sz["ins_B"]
    with benchutil.Timer() as t_sim:
        s = ins_simulate(float(sz["ins_s"]), B)
    lf, carry0 = s["lf"], s["carry0"]
    rows = []
    args = (
        jnp.asarray(s["dth"]),
        jnp.asarray(s["dv"]),
        jnp.asarray(s["fix_llh"]),
        jnp.asarray(s["fix_vel"]),
    )
    valid = jnp.asarray(s["valid"])
    fn = lambda a, b, c, d: ins_jaxnav(lf, carry0, a, b, c, d, valid)
    ref, tc, tr_ = _jax_timed(fn, args, repeats)
    ref = [np.asarray(a) for a in ref]
    m_n, m_e = _radii_m_per_rad(ref[0])
    d = ref[0] - s["truth_llh"]
    err2d = np.hypot(d[..., 0] * m_n, d[..., 1] * m_e)
    rows.append(
        dict(impl="jaxnav loose.run (jit, vmap)", n=B, compile_s=tc, run_s=tr_, diff=0.0, pos_m=0.0)
    )

    nav0 = (
        np.asarray(carry0.nav.state.llh),
        np.asarray(carry0.nav.state.vel_enu),
        np.asarray(carry0.nav.state.q_b_l),
    )
    P0 = np.asarray(carry0.P)

    def loop(impl, n, **kw):
        port = NumpyLooseIns15(lf, **kw)
        diffs, pos = [], []
        with benchutil.Timer() as t:
            outs = [
                port.run(
                    nav0, P0, s["dth"][b], s["dv"][b], s["fix_llh"][b], s["fix_vel"][b], s["valid"]
                )
                for b in range(n)
            ]
        for b, o in enumerate(outs):
            dd, pm = ins_diff(ref, o, b, s["bias_sigmas"])
            diffs.append(dd)
            pos.append(pm)
        return dict(impl=impl, n=n, compile_s=None, run_s=t.s, diff=max(diffs), pos_m=max(pos))

    rows.append(loop("NumPy port (loop over epochs and samples)", sz["ins_np"]))
    fp, why = _peer("filterpy")
    if fp is None:
        rows.append(dict(impl="FilterPy ExtendedKalmanFilter", skipped=why))
    else:
        rows.append(
            loop(
                f"FilterPy {_version('filterpy')} ExtendedKalmanFilter algebra in the NumPy port",
                sz["ins_fp"],
                algebra="filterpy",
                ekf_cls=fp[1],
            )
        )
    rows.append(
        dict(
            impl="dynamax",
            skipped="no INS mechanization / error-state feedback "
            "(module docstring); not applicable",
        )
    )
    extra = dict(
        sim_s=t_sim.s,
        err2d_mean_m=float(err2d.mean()),
        n_ep=int(sz["ins_s"]),
        outage_epochs=int((~s["valid"]).sum()),
    )
    return rows, extra


# ================================================================================================
# Reporting
# ================================================================================================
def _fmt(x, spec):
    return "—" if x is None else format(x, spec)


def table(rows, unit_name):
    """Markdown table: per-scenario time and its ratio to jaxnav's, agreement."""
    base = rows[0]["run_s"] / rows[0]["n"]
    lines = [
        f"| implementation | {unit_name}s timed | compile [s] | wall [s] | per {unit_name} "
        "[ms] | ratio to jaxnav | max diff vs jaxnav [sigma] |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "skipped" in r:
            lines.append(f"| {r['impl']} | skipped: {r['skipped']} | | | | | |")
            continue
        per = r["run_s"] / r["n"]
        r["ratio"] = per / base
        diff = f"{r['diff']:.1e}"
        if r.get("pos_m"):
            diff += f" ({r['pos_m']:.1e} m)"
        lines.append(
            f"| {r['impl']} | {r['n']} | {_fmt(r['compile_s'], '.1f')} | "
            f"{r['run_s']:.2f} | {1e3 * per:.3f} | {r['ratio']:.1f} | {diff} |"
        )
    return "\n".join(lines)


def _ratio(rows, key):
    for r in rows:
        if r["impl"].lower().startswith(key) and "skipped" not in r:
            return round(r["ratio"], 2)
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="much smaller run (< 40 s)")
    ap.add_argument(
        "--results",
        type=Path,
        default=benchutil.RESULTS_MD,
        help="Markdown file the section is appended to",
    )
    ap.add_argument("--no-append", action="store_true", help="do not write the results file")
    ap.add_argument("--repeats", type=int, default=None, help="timed runs of each JAX function")
    a = ap.parse_args(argv)
    mode = "quick" if a.quick else "full"
    sz = SIZES[mode]
    repeats = a.repeats or (1 if a.quick else 3)

    with benchutil.Timer() as t_all:
        lg = run_tracking(sz, repeats)
        ins, extra = run_ins(sz, repeats)
    t1 = table(lg, "track")
    t2 = table(ins, "run")
    head1 = (
        f"Case 1, linear-Gaussian tracking: 3D constant velocity (6 states, 3 position "
        f"measurements), T = {sz['lg_T']} epochs x B = {sz['lg_B']} tracks; tolerance "
        f"{TOL_LG:g} sigma. jaxnav's `ekf.masked_update` carries per-row masks, chi-square "
        "gating and the NIS, which makes H and R per-track operands under vmap; the peers "
        "have a fixed, unmasked H (a plain shared-H Joseph update in the same scan measured "
        "~5x faster than `masked_update` on this problem)."
    )
    head2 = (
        f"Case 2, loosely coupled INS15 + GNSS pos/vel at 1 Hz, 100 Hz HG1700-grade IMU, "
        f"{extra['n_ep']} s drive with a {extra['outage_epochs']} s outage, "
        f"B = {sz['ins_B']} realisations (jaxnav 2D error vs truth, mean over epochs and "
        f"runs: {extra['err2d_mean_m']:.2f} m); tolerance {TOL_INS:g} sigma."
    )
    notes = (
        f"Times: best of {repeats} run(s) for the JAX rows, compile separate; per-scenario "
        "= wall / scenarios timed; ratio = per-scenario time / jaxnav's (> 1: jaxnav "
        "faster). Differences are scaled by the filter's own sigma (module docstring of "
        f"`benchmarks/peers.py`). Input simulation (not timed in the table) "
        f"{extra['sim_s']:.1f} s; whole script {t_all.s:.0f} s."
    )
    print(head1)
    print(t1)
    print()
    print(head2)
    print(t2)
    print()
    print(notes)
    lg_diff = max(r["diff"] for r in lg if "skipped" not in r)
    ins_diff_ = max(r["diff"] for r in ins if "skipped" not in r)
    figures = {
        "mode": mode,
        "lg_T": sz["lg_T"],
        "lg_B": sz["lg_B"],
        "lg_jaxnav_compile_s": round(lg[0]["compile_s"], 2),
        "lg_jaxnav_ms_per_track": round(1e3 * lg[0]["run_s"] / lg[0]["n"], 4),
        "lg_ratio_numpy": _ratio(lg, "numpy"),
        "lg_ratio_filterpy": _ratio(lg, "filterpy"),
        "lg_ratio_dynamax": _ratio(lg, "dynamax"),
        "lg_max_diff_sigma": lg_diff,
        "lg_tol_sigma": TOL_LG,
        "ins_duration_s": extra["n_ep"],
        "ins_B": sz["ins_B"],
        "ins_jaxnav_compile_s": round(ins[0]["compile_s"], 2),
        "ins_jaxnav_ms_per_run": round(1e3 * ins[0]["run_s"] / ins[0]["n"], 3),
        "ins_ratio_numpy": _ratio(ins, "numpy"),
        "ins_ratio_filterpy": _ratio(ins, "filterpy"),
        "ins_max_diff_sigma": ins_diff_,
        "ins_max_pos_diff_m": max(r.get("pos_m", 0.0) for r in ins if "skipped" not in r),
        "ins_tol_sigma": TOL_INS,
        "ins_sim_s": round(extra["sim_s"], 1),
        "total_s": round(t_all.s, 1),
        "peak_rss_mb": round(benchutil.peak_rss_mb(), 1),
    }
    body = "\n\n".join(
        [
            f"Peers: FilterPy {_version('filterpy')}, dynamax {_version('dynamax')}.",
            head1,
            t1,
            head2,
            t2,
            notes,
        ]
    )
    if not a.no_append:
        benchutil.append_results(f"Peers ({mode})", body, figures, path=a.results)
    ok = lg_diff < TOL_LG and ins_diff_ < TOL_INS
    if not ok:
        print(
            f"DISAGREEMENT: tracking {lg_diff:.2e} (tol {TOL_LG}), INS {ins_diff_:.2e} "
            f"(tol {TOL_INS})"
        )
    benchutil.print_json_line(figures)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
