"""Plain-NumPy navigation helpers shared by the benchmark ports of jaxnav's filters.

``numpy_filter.py`` (tight INS15 / float PPP) and ``peers.py`` (loose INS15) both port jaxnav's
INS to NumPy so that a Python-loop implementation can be timed against the JAX one. The pieces
they have in common live here, restated without JAX: WGS-84 geometry (``jaxnav/geodesy.py``),
quaternions and DCMs (``jaxnav/attitude.py``), the strapdown mechanization with coning,
sculling and second-order l-frame rotation terms (``jaxnav/ins/strapdown.py``), the INS15 error
dynamics and lever-arm Jacobians (``jaxnav/ins/errors.py``) and the second-order Taylor
discretisation (``jaxnav/filter/ekf.py``). Same conventions as jaxnav: body right-forward-up,
l-frame ENU, llh = (lat, lon, h) [rad, rad, m], Hamilton scalar-first ``q_b_l``.

The scripts import it as ``import numpy_nav`` with ``benchmarks/`` on ``sys.path`` (each script
puts it there, so ``python benchmarks/x.py`` and the tests' file imports both work). Single
3-vectors are handled with explicit arithmetic and ``math``: NumPy's per-call overhead (e.g.
``np.cross`` ~10 us) would otherwise dominate the Python loops being timed.
"""

from __future__ import annotations

import math

import numpy as np

# ---- constants (the values of jaxnav.geodesy, restated for a JAX-free path) --------------------

A_WGS84 = 6378137.0
F_WGS84 = 1.0 / 298.257223563
E2_WGS84 = F_WGS84 * (2.0 - F_WGS84)
OMEGA_E = 7.2921151467e-5
#: Normal-gravity coefficients a1..a6 of geodesy.normal_gravity (SEED_SPEC 1.1).
GRAVITY_COEFFS = (
    9.7803267715, 0.0052790414, 0.0000232718, -3.087691089e-6, 4.397731e-9, 7.21e-13
)
_I3 = np.eye(3)


# ---- small vector helpers ----------------------------------------------------------------------


def cross(a, b):
    """a x b of two 3-vectors."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def cross_rows(a, b):
    """Row-wise cross products of [K, 3] arrays."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def skew(v):
    """[v x], the matrix of the cross product with v."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


# ---- geodesy (geodesy.py) ----------------------------------------------------------------------


def radii(lat):
    """(R_M, R_N) = (a (1 - e^2) / W^3, a / W), W = sqrt(1 - e^2 sin^2 lat) (geodesy.radii)."""
    s = math.sin(lat)
    w = math.sqrt(1.0 - E2_WGS84 * s * s)
    return A_WGS84 * (1.0 - E2_WGS84) / w**3, A_WGS84 / w


def radius_derivatives(lat):
    """(R_M, R_N, dR_M/dlat, dR_N/dlat)."""
    r_m, r_n = radii(lat)
    s, c = math.sin(lat), math.cos(lat)
    k = E2_WGS84 * s * c / (1.0 - E2_WGS84 * s * s)
    return r_m, r_n, 3.0 * r_m * k, r_n * k


def normal_gravity(lat, h):
    """g = a1 (1 + a2 s^2 + a3 s^4) + (a4 + a5 s^2) h + a6 h^2, s = sin lat (SEED_SPEC 1.1)."""
    g0, g1, g2, g3, g4, g5 = GRAVITY_COEFFS
    s2 = math.sin(lat) ** 2
    return g0 * (1.0 + g1 * s2 + g2 * s2 * s2) + (g3 + g4 * s2) * h + g5 * h * h


def gravity_slopes(lat, h):
    """(dg/dlat, dg/dh) of the normal-gravity polynomial (ins/errors.py takes them by autodiff)."""
    g0, g1, g2, g3, g4, g5 = GRAVITY_COEFFS
    s, c = math.sin(lat), math.cos(lat)
    s2 = s * s
    ds2 = 2.0 * s * c
    dg_dlat = g0 * (g1 + 2.0 * g2 * s2) * ds2 + g4 * ds2 * h
    return dg_dlat, g3 + g4 * s2 + 2.0 * g5 * h


def earth_rate(lat):
    """w_ie^l = (0, w_e cos lat, w_e sin lat)."""
    return np.array([0.0, OMEGA_E * math.cos(lat), OMEGA_E * math.sin(lat)])


def earth_rate_jacobian(lat):
    """d w_ie^l / d(lat, lon, h)."""
    s, c = math.sin(lat), math.cos(lat)
    return np.array([[0.0, 0.0, 0.0], [-OMEGA_E * s, 0.0, 0.0], [OMEGA_E * c, 0.0, 0.0]])


def transport_rate(llh, vel):
    """w_el^l = (-v_n / (R_M + h), v_e / (R_N + h), v_e tan lat / (R_N + h))."""
    r_m, r_n = radii(llh[0])
    h = llh[2]
    return np.array(
        [-vel[1] / (r_m + h), vel[0] / (r_n + h), vel[0] * math.tan(llh[0]) / (r_n + h)]
    )


def llh_rate_matrix(llh):
    """D^-1 with d(lat, lon, h)/dt = D^-1 v_enu."""
    r_m, r_n = radii(llh[0])
    h = llh[2]
    return np.array(
        [
            [0.0, 1.0 / (r_m + h), 0.0],
            [1.0 / ((r_n + h) * math.cos(llh[0])), 0.0, 0.0],
            [0.0, 0.0, 1.0],
        ]
    )


def C_l_e(lat, lon):
    """C_l^e: ENU to ECEF."""
    sp, cp = math.sin(lat), math.cos(lat)
    sl, cl = math.sin(lon), math.cos(lon)
    return np.array([[-sl, -sp * cl, cp * cl], [cl, -sp * sl, cp * sl], [0.0, cp, sp]])


def llh_to_ecef(llh):
    """ECEF position [m] of (lat, lon, h)."""
    lat, lon, h = llh
    _, r_n = radii(lat)
    cl = math.cos(lat)
    return np.array(
        [
            (r_n + h) * cl * math.cos(lon),
            (r_n + h) * cl * math.sin(lon),
            (r_n * (1.0 - E2_WGS84) + h) * math.sin(lat),
        ]
    )


def llh_to_ecef_jacobian(llh):
    """d r^e / d(lat, lon, h)."""
    lat, lon, h = llh
    r_m, r_n = radii(lat)
    sp, cp = math.sin(lat), math.cos(lat)
    sl, cl = math.sin(lon), math.cos(lon)
    return np.array(
        [
            [-(r_m + h) * sp * cl, -(r_n + h) * cp * sl, cp * cl],
            [-(r_m + h) * sp * sl, (r_n + h) * cp * cl, cp * sl],
            [(r_m + h) * cp, 0.0, sp],
        ]
    )


# ---- attitude (attitude.py) --------------------------------------------------------------------


def quat_mul(q, r):
    """Hamilton product q (x) r."""
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = r
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_from_rotvec(phi):
    """[cos(|phi|/2), sin(|phi|/2) phi/|phi|] with the Taylor branch below 1e-4 rad."""
    theta2 = float(phi @ phi)
    if theta2 < 1e-8:
        w, half_sinc = 1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0
    else:
        theta = math.sqrt(theta2)
        w, half_sinc = math.cos(0.5 * theta), math.sin(0.5 * theta) / theta
    return np.array([w, half_sinc * phi[0], half_sinc * phi[1], half_sinc * phi[2]])


def quats_from_rotvecs(phi):
    """Row-wise ``quat_from_rotvec`` of [K, 3] rotation vectors."""
    theta2 = np.einsum("ki,ki->k", phi, phi)
    small = theta2 < 1e-8
    theta = np.sqrt(np.where(small, 1.0, theta2))
    half_sinc = np.where(small, 0.5 - theta2 / 48.0, np.sin(0.5 * theta) / theta)
    w = np.where(small, 1.0 - theta2 / 8.0, np.cos(0.5 * theta))
    return np.concatenate([w[:, None], half_sinc[:, None] * phi], axis=1)


def quat_normalize(q):
    """Unit quaternion with a non-negative scalar part (attitude.quat_normalize)."""
    q = q / math.sqrt(float(q @ q))
    return -q if q[0] < 0.0 else q


def dcm_from_quat(q):
    """C = (w^2 - |v|^2) I + 2 v v^T + 2 w [v x]."""
    w, v = q[0], q[1:]
    return (w * w - float(v @ v)) * _I3 + 2.0 * np.outer(v, v) + 2.0 * w * skew(v)


def euler_from_dcm(C):
    """(roll, pitch, azimuth) of C_b_l (attitude.euler_from_dcm)."""
    return np.array(
        [
            math.atan2(-C[2, 0], C[2, 2]),
            math.asin(min(max(C[2, 1], -1.0), 1.0)),
            math.atan2(C[0, 1], C[1, 1]),
        ]
    )


# ---- strapdown (ins/strapdown.py) --------------------------------------------------------------


def velocity_position(llh, vel, C, dv_b, u_rot, dv_sf_b, dt, llh_mid, vel_mid):
    """strapdown._velocity_position: velocity with mid-interval gravity / Coriolis and l-frame
    rotation terms to second order in zeta, trapezoidal position (h, then lat, then lon).
    ``u_rot`` is C (dth x dv), already in the l-frame."""
    w_ie = earth_rate(llh_mid[0])
    w_el = transport_rate(llh_mid, vel_mid)
    zeta = (w_ie + w_el) * dt
    u = C @ dv_b
    zu = cross(zeta, u)
    dv_sf_l = C @ dv_sf_b - 0.5 * zu - cross(zeta, u_rot) / 3.0 + cross(zeta, zu) / 6.0
    g = normal_gravity(llh_mid[0], llh_mid[2])
    dv_cor = (np.array([0.0, 0.0, -g]) - cross(2.0 * w_ie + w_el, vel_mid)) * dt
    vel_new = vel + dv_sf_l + dv_cor

    v_avg = 0.5 * (vel + vel_new)
    h_new = llh[2] + v_avg[2] * dt
    h_mid = 0.5 * (llh[2] + h_new)
    r_m, _ = radii(llh_mid[0])
    lat_new = llh[0] + v_avg[1] * dt / (r_m + h_mid)
    lat_mid = 0.5 * (llh[0] + lat_new)
    _, r_n = radii(lat_mid)
    lon_new = llh[1] + v_avg[0] * dt / ((r_n + h_mid) * math.cos(lat_mid))
    return np.array([lat_new, lon_new, h_new]), vel_new, zeta


def sample_terms(prev_dth, prev_dv, dth, dv):
    """Per-sample terms that do not depend on the state, for a whole epoch at once ([K, ...]):
    the coning quaternion q(phi) (Savage two-sample), the sculled body increment dv_sf and
    dth x dv."""
    pdth = np.concatenate([prev_dth[None], dth[:-1]])
    pdv = np.concatenate([prev_dv[None], dv[:-1]])
    q_phi = quats_from_rotvecs(dth + cross_rows(pdth, dth) / 12.0)
    rot = cross_rows(dth, dv)
    dv_sf = (
        dv + 0.5 * rot + cross_rows(dth, rot) / 6.0
        + (cross_rows(pdth, dv) + cross_rows(pdv, dth)) / 12.0
    )
    return q_phi, dv_sf, rot


def mechanize(llh, vel, q, prev_dth, prev_dv, dth, dv, dt):
    """strapdown.mechanize over one epoch's compensated samples [K, 3], state as NumPy 3-vectors.

    The coning / sculling / rotation-compensation terms depend only on the samples, so they are
    computed for the whole epoch at once; the state recursion (predictor with start-of-interval
    rates, corrector with mid-interval ones) is a Python loop.
    """
    q_phi, dv_sf, rot = sample_terms(prev_dth, prev_dv, dth, dv)
    for k in range(dth.shape[0]):
        C = dcm_from_quat(q)
        u_rot = C @ rot[k]
        llh_p, vel_p, _ = velocity_position(llh, vel, C, dv[k], u_rot, dv_sf[k], dt, llh, vel)
        llh_mid = llh + 0.5 * (llh_p - llh)
        vel_mid = 0.5 * (vel + vel_p)
        llh, vel, zeta = velocity_position(
            llh, vel, C, dv[k], u_rot, dv_sf[k], dt, llh_mid, vel_mid
        )
        q = quat_mul(quat_mul(quat_from_rotvec(-zeta), q), q_phi[k])
        lon = llh[1]
        if lon > math.pi:
            llh[1] = lon - 2.0 * math.pi
        elif lon <= -math.pi:
            llh[1] = lon + 2.0 * math.pi
        q = quat_normalize(q)
    return llh, vel, q


# ---- INS error model (ins/errors.py) and discretisation (filter/ekf.py) ------------------------


def ins15_error_dynamics(llh, vel, C, f_b, accel_bias_tau_s, gyro_bias_tau_s):
    """The non-zero 3x3 blocks of the INS15 error-state F (errors.error_dynamics), keyed by
    (row block, column block) names of ``jaxnav.core.states.INS15``; GM bias time constants
    per axis [s]."""
    lat, h = llh[0], llh[2]
    ve, vn = vel[0], vel[1]
    r_m, r_n, dr_m, dr_n = radius_derivatives(lat)
    rho_m, rho_n = r_m + h, r_n + h
    c, t = math.cos(lat), math.tan(lat)
    F_rr = np.array(
        [
            [-vn * dr_m / rho_m**2, 0.0, -vn / rho_m**2],
            [ve * (t / (rho_n * c) - dr_n / (rho_n**2 * c)), 0.0, -ve / (rho_n**2 * c)],
            [0.0, 0.0, 0.0],
        ]
    )
    dwie_dr = earth_rate_jacobian(lat)
    dwel_dr = np.array(
        [
            [vn * dr_m / rho_m**2, 0.0, vn / rho_m**2],
            [-ve * dr_n / rho_n**2, 0.0, -ve / rho_n**2],
            [ve / (c * c * rho_n) - ve * t * dr_n / rho_n**2, 0.0, -ve * t / rho_n**2],
        ]
    )
    dwel_dv = np.array([[0.0, -1.0 / rho_m, 0.0], [1.0 / rho_n, 0.0, 0.0], [t / rho_n, 0.0, 0.0]])
    dg_dlat, dg_dh = gravity_slopes(lat, h)
    w_ie = earth_rate(lat)
    w_el = transport_rate(llh, vel)
    v_x = skew(vel)
    F_vp = v_x @ (2.0 * dwie_dr + dwel_dr)
    F_vp[2, 0] -= dg_dlat  # the up-gravity slopes
    F_vp[2, 2] -= dg_dh
    return {
        ("pos", "pos"): F_rr,
        ("pos", "vel"): llh_rate_matrix(llh),
        ("vel", "pos"): F_vp,
        ("vel", "vel"): -skew(2.0 * w_ie + w_el) + v_x @ dwel_dv,
        ("vel", "att"): skew(C @ f_b),
        ("att", "pos"): dwie_dr + dwel_dr,
        ("att", "vel"): dwel_dv,
        ("att", "att"): -skew(w_ie + w_el),
        ("vel", "accel_bias"): C,
        ("att", "gyro_bias"): -C,
        ("accel_bias", "accel_bias"): np.diag(-1.0 / accel_bias_tau_s),
        ("gyro_bias", "gyro_bias"): np.diag(-1.0 / gyro_bias_tau_s),
    }


def antenna_lever_arm(llh, vel, C, w_ib_b, lever_b):
    """InsSystem.antenna: antenna (lat, lon, h) and ENU velocity of the lever arm ``lever_b``
    (body, from the IMU), and the Jacobians of both w.r.t. the INS15 error state
    (errors.antenna_*_jacobian) as two dicts of 3x3 blocks keyed by block name."""
    u = C @ lever_b
    D = llh_rate_matrix(llh)
    llh_ant = llh + D @ u
    w_ie = earth_rate(llh[0])
    c_wl = C @ cross(w_ib_b, lever_b)
    vel_ant = vel + c_wl - cross(w_ie, u)

    lat, h = llh[0], llh[2]
    r_m, r_n, dr_m, dr_n = radius_derivatives(lat)
    rho_m, rho_n = r_m + h, r_n + h
    c, t = math.cos(lat), math.tan(lat)
    dDu = np.array(
        [
            [-u[1] * dr_m / rho_m**2, 0.0, -u[1] / rho_m**2],
            [u[0] * (t / (rho_n * c) - dr_n / (rho_n**2 * c)), 0.0, -u[0] / (rho_n**2 * c)],
            [0.0, 0.0, 0.0],
        ]
    )
    J_llh = {"pos": _I3 + dDu, "att": D @ skew(u)}
    J_vel = {
        "vel": _I3,
        "pos": skew(u) @ earth_rate_jacobian(lat),
        "att": skew(c_wl) - skew(w_ie) @ skew(u),
        "gyro_bias": -C @ skew(lever_b),
    }
    return llh_ant, vel_ant, J_llh, J_vel


def input_rate2(x, dt, psd):
    """InsSystem._input_rates: the squared least-squares slope of the increments x / dt over
    the samples [K, 3], minus the slope variance of white noise of PSD ``psd``, floored at 0."""
    t = (np.arange(x.shape[0]) - (x.shape[0] - 1) / 2.0) * dt
    stt = max(float(t @ t), dt * dt)
    slope = (t @ (x / dt)) / stt
    return np.maximum(slope**2 - psd / dt / stt, 0.0)


def gm_share(sigma_gm, sigma_ton):
    """errors.gm_share for a lumped (INS15) bias block: sigma_gm^2 / (sigma_gm^2 + sigma_ton^2)
    per axis, 1 where both are zero."""
    var_gm = np.broadcast_to(np.asarray(sigma_gm, float), (3,)) ** 2
    var = var_gm + np.broadcast_to(np.asarray(sigma_ton, float), (3,)) ** 2
    return np.where(var > 0.0, var_gm / np.where(var > 0.0, var, 1.0), 1.0)


def discretize(F, Qg, dt, squarings=3):
    """ekf.discretize: third-order series for Phi and Qd over dt / 2^k, then k doublings
    Qd <- Phi Qd Phi^T + Qd, Phi <- Phi Phi (symmetrised)."""
    h = dt / 2**squarings
    A = F * h
    A2 = A @ A
    Phi = np.eye(F.shape[0]) + A + A2 / 2.0 + A2 @ A / 6.0
    AQ = A @ Qg
    AAQ = A @ AQ
    Qd = h * (Qg + 0.5 * (AQ + AQ.T) + (AAQ + AAQ.T + 2.0 * AQ @ A.T) / 6.0)
    for _ in range(squarings):
        Qd = Phi @ Qd @ Phi.T + Qd
        Phi = Phi @ Phi
    return Phi, 0.5 * (Qd + Qd.T)
