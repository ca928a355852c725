"""Plain-NumPy reference of jaxnav's tightly coupled INS / float-PPP filter (the sweep baseline).

``benchmarks/sweep_throughput.py`` compares jaxnav's vectorised sweep with this: the same filter
written the way a competent NumPy author would, i.e. Python loops over epochs and IMU samples,
NumPy vectorised over satellites and over the state dimension, no JAX anywhere in the epoch
path. It reproduces ``jaxnav.filter.tight.epoch_step`` / ``run`` for one configuration only:

- system ``InsSystem`` with the INS15 layout (``ins/strapdown.py`` mechanization with coning,
  sculling and the second-order l-frame rotation terms; ``ins/errors.py`` error model, lever-arm
  Jacobians, closed-loop feedback);
- PPP mode ``float_ppp``, GPS only, undifferenced: IF code and IF phase rows with a float
  ambiguity per slot, Doppler rows, ZWD (Saastamoinen + Niell), receiver clock bias and drift
  (``gnss/ppp.py``, ``gnss/models.py``, ``gnss/corrections.py``);
- the EKF of ``filter/ekf.py``: second-order Taylor discretisation, predict, masked Joseph
  update with chi-square gating; and tight.py's median pre-fit test, clock-jump re-levelling,
  post-fit test with one redo, per-slot ambiguity resets and closed-loop feedback.

The INS pieces (geodesy, attitude, strapdown, INS15 error dynamics, lever arm, discretisation)
are shared with ``peers.py`` in ``benchmarks/numpy_nav.py``; the GNSS models, the filter logic
and the Python-float strapdown recursion are here.

Anything else (RISS, INS21, other modes, GLONASS / Galileo, BSSD) raises in
:meth:`NumpyTightFilter.from_jax`. ``tests/test_numpy_filter.py`` checks that the two agree to
round-off on a simulated drive with outages.

Public API:
    NumpyTightFilter.from_jax(tf)              configuration of a jaxnav TightFilter, as floats
    run(nf, carry0, inputs, strapdown="scalar") -> dict
                                               llh, vel_enu, euler [T, 3], P_nav [T, 9, 9], ...

Cost: the 100 Hz strapdown recursion is most of it. ``strapdown="scalar"`` (default) runs it on
Python floats (~2.5 ms per 1-s epoch on one core, 60 % of it strapdown); ``"vector"`` on NumPy
3-vectors (same numbers to round-off, ~4x slower from NumPy's per-call overhead).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy_nav as nn  # noqa: E402  (benchmarks/numpy_nav.py: the shared NumPy INS port)

# ---- constants (the values of gnss.corrections, restated for a JAX-free path) ------------------

C_LIGHT = 299792458.0

KIND_CODE, KIND_PHASE, KIND_DOPPLER = 0, 1, 2


# ---- strapdown: the scalar recursion (numpy_nav.mechanize is the NumPy 3-vector one) ---------


def _mechanize_scalar(llh, vel, q, prev_dth, prev_dv, dth, dv, dt):
    """``numpy_nav.mechanize`` with the per-sample recursion on Python floats.

    Same equations and operation order; for 3-vectors, scalar arithmetic avoids NumPy's
    per-call overhead (about 5x faster), which makes this the fairer CPU baseline.
    """
    q_phi, dv_sf, rot = nn.sample_terms(prev_dth, prev_dv, dth, dv)
    q_phi, dv_sf, rot, dvs = q_phi.tolist(), dv_sf.tolist(), rot.tolist(), dv.tolist()
    lat, lon, h = (float(v) for v in llh)
    ve, vn, vu = (float(v) for v in vel)
    qw, qx, qy, qz = (float(v) for v in q)
    e2, a_e, we = nn.E2_WGS84, nn.A_WGS84, nn.OMEGA_E
    g0, g1, g2, g3, g4, g5 = nn.GRAVITY_COEFFS
    sin, cos, tan, sqrt = math.sin, math.cos, math.tan, math.sqrt

    for k in range(len(dvs)):
        # C_b_l of q: (w^2 - |v|^2) I + 2 v v^T + 2 w [v x]
        a = qw * qw - (qx * qx + qy * qy + qz * qz)
        c00, c11, c22 = a + 2.0 * qx * qx, a + 2.0 * qy * qy, a + 2.0 * qz * qz
        c01, c10 = 2.0 * qx * qy - 2.0 * qw * qz, 2.0 * qy * qx + 2.0 * qw * qz
        c02, c20 = 2.0 * qx * qz + 2.0 * qw * qy, 2.0 * qz * qx - 2.0 * qw * qy
        c12, c21 = 2.0 * qy * qz - 2.0 * qw * qx, 2.0 * qz * qy + 2.0 * qw * qx
        # u = C dv, u_rot = C (dth x dv), C dv_sf
        x, y, z = dvs[k]
        ue, un = c00 * x + c01 * y + c02 * z, c10 * x + c11 * y + c12 * z
        uu = c20 * x + c21 * y + c22 * z
        x, y, z = rot[k]
        re, rn = c00 * x + c01 * y + c02 * z, c10 * x + c11 * y + c12 * z
        ru = c20 * x + c21 * y + c22 * z
        x, y, z = dv_sf[k]
        se, sn = c00 * x + c01 * y + c02 * z, c10 * x + c11 * y + c12 * z
        su = c20 * x + c21 * y + c22 * z

        # Predictor (start-of-interval rates) then corrector (mid-interval), as strapdown.py.
        lat_m, h_m, ve_m, vn_m, vu_m = lat, h, ve, vn, vu
        for corrector in (False, True):
            sl, cl = sin(lat_m), cos(lat_m)
            w = sqrt(1.0 - e2 * sl * sl)
            r_m, r_n = a_e * (1.0 - e2) / w**3, a_e / w
            wie_n, wie_u = we * cl, we * sl
            wel_e, wel_n = -vn_m / (r_m + h_m), ve_m / (r_n + h_m)
            wel_u = ve_m * tan(lat_m) / (r_n + h_m)
            ze, zn, zu = 0.0 + wel_e, wie_n + wel_n, wie_u + wel_u
            ze, zn, zu = ze * dt, zn * dt, zu * dt
            # zeta x u, zeta x u_rot, zeta x (zeta x u)
            xe, xn, xu = zn * uu - zu * un, zu * ue - ze * uu, ze * un - zn * ue
            ye, yn, yu = zn * ru - zu * rn, zu * re - ze * ru, ze * rn - zn * re
            te, tn, tu = zn * xu - zu * xn, zu * xe - ze * xu, ze * xn - zn * xe
            s2 = sl * sl
            g = g0 * (1.0 + g1 * s2 + g2 * s2 * s2) + (g3 + g4 * s2) * h_m + g5 * h_m * h_m
            oe, on, ou = 2.0 * 0.0 + wel_e, 2.0 * wie_n + wel_n, 2.0 * wie_u + wel_u
            cor_e = on * vu_m - ou * vn_m
            cor_n = ou * ve_m - oe * vu_m
            cor_u = oe * vn_m - on * ve_m
            ve1 = ve + (se - 0.5 * xe - ye / 3.0 + te / 6.0) + (0.0 - cor_e) * dt
            vn1 = vn + (sn - 0.5 * xn - yn / 3.0 + tn / 6.0) + (0.0 - cor_n) * dt
            vu1 = vu + (su - 0.5 * xu - yu / 3.0 + tu / 6.0) + (-g - cor_u) * dt
            ae, an, au = 0.5 * (ve + ve1), 0.5 * (vn + vn1), 0.5 * (vu + vu1)
            h1 = h + au * dt
            hm = 0.5 * (h + h1)
            lat1 = lat + an * dt / (r_m + hm)
            latm = 0.5 * (lat + lat1)
            r_n2 = a_e / sqrt(1.0 - e2 * sin(latm) ** 2)
            lon1 = lon + ae * dt / ((r_n2 + hm) * cos(latm))
            if not corrector:
                lat_m, h_m = lat + 0.5 * (lat1 - lat), h + 0.5 * (h1 - h)
                ve_m, vn_m, vu_m = 0.5 * (ve + ve1), 0.5 * (vn + vn1), 0.5 * (vu + vu1)
        lat, lon, h, ve, vn, vu = lat1, lon1, h1, ve1, vn1, vu1
        if lon > math.pi:
            lon -= 2.0 * math.pi
        elif lon <= -math.pi:
            lon += 2.0 * math.pi

        # q <- q(-zeta) (x) q (x) q(phi), normalised with a non-negative scalar part.
        th2 = ze * ze + zn * zn + zu * zu
        if th2 < 1e-8:
            zw, hs = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0
        else:
            th = sqrt(th2)
            zw, hs = cos(0.5 * th), sin(0.5 * th) / th
        zx, zy, zz = -hs * ze, -hs * zn, -hs * zu
        aw = zw * qw - zx * qx - zy * qy - zz * qz
        ax = zw * qx + zx * qw + zy * qz - zz * qy
        ay = zw * qy - zx * qz + zy * qw + zz * qx
        az = zw * qz + zx * qy - zy * qx + zz * qw
        pw, px, py, pz = q_phi[k]
        qw = aw * pw - ax * px - ay * py - az * pz
        qx = aw * px + ax * pw + ay * pz - az * py
        qy = aw * py - ax * pz + ay * pw + az * px
        qz = aw * pz + ax * py - ay * px + az * pw
        nq = sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        if qw < 0.0:
            nq = -nq
        qw, qx, qy, qz = qw / nq, qx / nq, qy / nq, qz / nq
    return np.array([lat, lon, h]), np.array([ve, vn, vu]), np.array([qw, qx, qy, qz])


# ---- configuration -----------------------------------------------------------------------------


@dataclass(frozen=True)
class NumpyTightFilter:
    """Everything ``run`` needs from a jaxnav ``TightFilter``, as Python floats / NumPy arrays."""

    layout: object  # jaxnav.core.states.StateLayout of the full filter (pure Python)
    n_sys: int  # size of the navigation + sensor prefix (INS15: 15)
    n_nav: int  # size of the reported covariance block (pos, vel, att)
    imu_dt_s: float
    epoch_dt_s: float
    lever_b: np.ndarray
    # IMU error model (ins/errors.ImuErrorModel, per-axis)
    accel_vrw: np.ndarray
    gyro_arw: np.ndarray
    accel_bias_sigma: np.ndarray
    accel_bias_tau_s: np.ndarray
    gyro_bias_sigma: np.ndarray
    gyro_bias_tau_s: np.ndarray
    # scale-factor sigmas INS15 does not estimate (errors.unmodelled_scale_psd)
    accel_scale_sigma: np.ndarray
    gyro_scale_sigma: np.ndarray
    accel_gm_share: np.ndarray  # errors.gm_share: drift part of a lumped bias correction
    gyro_gm_share: np.ndarray
    # PPP configuration (gnss/ppp.PppConfig)
    n_slots: int
    alpha: np.ndarray  # [S] IF coefficients
    beta: np.ndarray
    code_sigma_m: float  # zenith, white + white-equivalent multipath at the epoch interval
    phase_sigma_m: float
    doppler_sigma_m_s: float
    product_var_m2: float  # orbit^2 + clock^2 (code rows)
    ambiguity_psd: float  # 2 sigma^2 / tau of orbit and clock (the ambiguities' random walk)
    elevation_mask_rad: float
    prefit_code_m: float
    gate_chi2: float
    postfit_sigma: float
    postfit_passes: int
    clock_bias_psd: float
    clock_drift_psd: float
    zwd_psd: float
    clock_init_sigma_m: float
    ambiguity_init_sigma_m: float

    @classmethod
    def from_jax(cls, tf) -> NumpyTightFilter:
        """Extract the configuration of ``tf`` (a ``jaxnav.filter.tight.TightFilter``); raises for
        anything but InsSystem/INS15 with undifferenced GPS float PPP, Doppler and ZWD."""
        from jaxnav.core.states import INS15
        from jaxnav.filter.systems import InsSystem
        from jaxnav.gnss import signals

        cfg, system = tf.cfg, tf.system
        if not isinstance(system, InsSystem) or system.layout != INS15:
            raise ValueError("the NumPy reference implements InsSystem with the INS15 layout only")
        if cfg.mode != "float_ppp" or cfg.bssd or not cfg.doppler or not cfg.estimate_zwd:
            raise ValueError("the NumPy reference implements undifferenced float_ppp + Doppler "
                             "+ ZWD only")
        sys_of_slot = np.asarray(tf.slots.system)
        if tuple(cfg.systems) != (signals.SYS_GPS,) or np.any(sys_of_slot != signals.SYS_GPS):
            raise ValueError("the NumPy reference implements GPS only")
        layout = tf.layout
        expected = INS15.blocks + (("clock_bias", 1), ("clock_drift", 1), ("zwd", 1),
                                   ("amb", cfg.n_slots))
        if layout.blocks != expected:
            raise ValueError(f"unexpected layout {layout.blocks}")
        f1 = np.asarray(tf.slots.f1_hz, np.float64)
        f2 = np.asarray(tf.slots.f2_hz, np.float64)
        d = f1**2 - f2**2
        m = system.model

        def triad(x):
            return np.broadcast_to(np.asarray(x, np.float64), (3,)).copy()

        return cls(
            layout=layout,
            n_sys=INS15.size,
            n_nav=max(layout.sl(n).stop for n in ("pos", "vel", "att")),
            imu_dt_s=float(tf.imu_dt_s),
            epoch_dt_s=float(tf.epoch_dt_s),
            lever_b=np.asarray(system.lever_b, np.float64),
            accel_vrw=triad(m.accel_vrw_m_s_sqrt_s),
            gyro_arw=triad(m.gyro_arw_rad_sqrt_s),
            accel_bias_sigma=triad(m.accel_bias_sigma_m_s2),
            accel_bias_tau_s=triad(m.accel_bias_tau_s),
            gyro_bias_sigma=triad(m.gyro_bias_sigma_rad_s),
            gyro_bias_tau_s=triad(m.gyro_bias_tau_s),
            accel_scale_sigma=triad(m.accel_scale_sigma),
            gyro_scale_sigma=triad(m.gyro_scale_sigma),
            # INS15 lumps turn-on + drift: the drift share of a correction by prior variances
            accel_gm_share=nn.gm_share(m.accel_bias_sigma_m_s2, m.accel_bias_ton_sigma_m_s2),
            gyro_gm_share=nn.gm_share(m.gyro_bias_sigma_rad_s, m.gyro_bias_ton_sigma_rad_s
                                      if system.gyro_calibration_s is None else
                                      m.gyro_arw_rad_sqrt_s / np.sqrt(system.gyro_calibration_s)),
            n_slots=int(cfg.n_slots),
            alpha=f1**2 / d,
            beta=-(f2**2) / d,
            code_sigma_m=_with_multipath(cfg.code_sigma_m, cfg.multipath_code_sigma_m, cfg,
                                         tf.epoch_dt_s),
            phase_sigma_m=_with_multipath(cfg.phase_sigma_m, cfg.multipath_phase_sigma_m, cfg,
                                          tf.epoch_dt_s),
            doppler_sigma_m_s=float(cfg.doppler_sigma_m_s),
            product_var_m2=float(cfg.orbit_sigma_m**2 + cfg.sat_clock_sigma_m**2),
            ambiguity_psd=float(2.0 * cfg.orbit_sigma_m**2 / cfg.orbit_tau_s
                                + 2.0 * cfg.sat_clock_sigma_m**2 / cfg.sat_clock_tau_s),
            elevation_mask_rad=float(cfg.elevation_mask_rad),
            prefit_code_m=float(cfg.prefit_code_m),
            gate_chi2=float(cfg.gate_chi2),
            postfit_sigma=float(cfg.postfit_sigma),
            postfit_passes=int(cfg.postfit_passes),
            clock_bias_psd=float(cfg.clock_bias_psd_m2_s),
            clock_drift_psd=float(cfg.clock_drift_psd_m2_s3),
            zwd_psd=float(cfg.zwd_psd_m2_s),
            clock_init_sigma_m=float(cfg.clock_init_sigma_m),
            ambiguity_init_sigma_m=float(cfg.ambiguity_init_sigma_m),
        )


def _with_multipath(white_m, multipath_m, cfg, dt_s) -> float:
    """sqrt(white^2 + sum over all lags of the multipath's AR(1) autocovariance)."""
    rho = np.exp(-float(dt_s) / float(cfg.multipath_tau_s))
    lags = float(multipath_m) ** 2 * (1.0 + 2.0 * rho / (1.0 - rho))
    return float(np.sqrt(float(white_m) ** 2 + lags))


# ---- INS error model (ins/errors.py) -----------------------------------------------------------


def _process_model(nf: NumpyTightFilter, llh, vel, C, f_b, rates=None):
    """Continuous F of the full filter and the driving noise G Qc G^T (errors.error_dynamics and
    ppp.gnss_dynamics; the GNSS states are driven by identity columns of their own PSDs)."""
    L = nf.layout
    n = L.size
    V, E = L.sl("vel"), L.sl("att")
    F = np.zeros((n, n))
    blocks = nn.ins15_error_dynamics(llh, vel, C, f_b, nf.accel_bias_tau_s, nf.gyro_bias_tau_s)
    for (row, col), block in blocks.items():
        F[L.sl(row), L.sl(col)] = block
    F[L.i("clock_bias"), L.i("clock_drift")] = 1.0

    # G Qc G^T: white accelerometer / gyro noise through C and -C, GM drivers, GNSS random walks.
    BA, BG = L.sl("accel_bias"), L.sl("gyro_bias")
    Qg = np.zeros((n, n))
    Qg[V, V] = (C * nf.accel_vrw**2) @ C.T
    Qg[E, E] = (C * nf.gyro_arw**2) @ C.T
    Qg[BA, BA] = np.diag(2.0 * nf.accel_bias_sigma**2 / nf.accel_bias_tau_s)
    Qg[BG, BG] = np.diag(2.0 * nf.gyro_bias_sigma**2 / nf.gyro_bias_tau_s)
    if rates is not None:  # errors.unmodelled_scale_psd: INS15 has no scale-factor states
        f_rate2, w_rate2, span = rates
        Qg[BA, BA] += np.diag(nf.accel_scale_sigma**2 * f_rate2 * span)
        Qg[BG, BG] += np.diag(nf.gyro_scale_sigma**2 * w_rate2 * span)
    Qg[L.i("clock_bias"), L.i("clock_bias")] = nf.clock_bias_psd
    Qg[L.i("clock_drift"), L.i("clock_drift")] = nf.clock_drift_psd
    Qg[L.i("zwd"), L.i("zwd")] = nf.zwd_psd
    amb = np.arange(L.sl("amb").start, L.sl("amb").stop)
    Qg[amb, amb] = nf.ambiguity_psd
    return F, Qg


def _propagate_covariance(nf: NumpyTightFilter, P, F, Qg):
    """tight._propagate_covariance: the INS block by ekf.discretize (3 squarings), the GNSS
    block by its series alone; P <- Phi P Phi^T + Qd (symmetrised)."""
    k = nf.layout.i("clock_bias")  # the INS states precede the GNSS blocks
    Phi, Qd = np.zeros_like(F), np.zeros_like(F)
    Phi[:k, :k], Qd[:k, :k] = nn.discretize(F[:k, :k], Qg[:k, :k], nf.epoch_dt_s)
    Phi[k:, k:], Qd[k:, k:] = nn.discretize(F[k:, k:], Qg[k:, k:], nf.epoch_dt_s, squarings=0)
    P = Phi @ P @ Phi.T + Qd
    return 0.5 * (P + P.T)


def _antenna(nf: NumpyTightFilter, llh, vel, C, w_ib_b):
    """InsSystem.antenna: antenna ECEF position / velocity and their Jacobians w.r.t. dx."""
    L = nf.layout
    llh_ant, vel_ant, J_llh_blocks, J_vel_blocks = nn.antenna_lever_arm(
        llh, vel, C, w_ib_b, nf.lever_b
    )
    J_llh = np.zeros((3, L.size))
    for name, block in J_llh_blocks.items():
        J_llh[:, L.sl(name)] = block
    J_v = np.zeros((3, L.size))
    for name, block in J_vel_blocks.items():
        J_v[:, L.sl(name)] = block
    C_l_e = nn.C_l_e(llh_ant[0], llh_ant[1])
    return (
        nn.llh_to_ecef(llh_ant),
        C_l_e @ vel_ant,
        llh_ant,
        nn.llh_to_ecef_jacobian(llh_ant) @ J_llh,
        C_l_e @ J_v,
    )

# ---- GNSS models (gnss/models.py, gnss/corrections.py) -----------------------------------------

_NIELL_TABLE = np.array(
    [  # |lat| 15, 30, 45, 60, 75 deg: hydrostatic average (a, b, c), amplitude, wet (Niell 1996)
        [1.2769934e-3, 2.9153695e-3, 62.610505e-3, 0.0, 0.0, 0.0,
         5.8021897e-4, 1.4275268e-3, 4.3472961e-2],
        [1.2683230e-3, 2.9152299e-3, 62.837393e-3, 1.2709626e-5, 2.1414979e-5, 9.0128400e-5,
         5.6794847e-4, 1.5138625e-3, 4.6729510e-2],
        [1.2465397e-3, 2.9288445e-3, 63.721774e-3, 2.6523662e-5, 3.0160779e-5, 4.3497037e-5,
         5.8118019e-4, 1.4572752e-3, 4.3908931e-2],
        [1.2196049e-3, 2.9022565e-3, 63.824265e-3, 3.4000452e-5, 7.2562722e-5, 84.795348e-5,
         5.9727542e-4, 1.5007428e-3, 4.4626982e-2],
        [1.2045996e-3, 2.9024912e-3, 64.258455e-3, 4.1202191e-5, 11.723375e-5, 170.37206e-5,
         6.1641693e-4, 1.7599082e-3, 5.4736038e-2],
    ]
)


def _marini(s, a, b, c):
    return (1.0 + a / (1.0 + b / (1.0 + c))) / (s + a / (s + b / (s + c)))


def _niell(el, lat, h, doy):
    """Niell hydrostatic and wet mapping functions per slot (corrections.niell_mapping)."""
    x = min(max((abs(math.degrees(lat)) - 15.0) / 15.0, 0.0), 4.0)
    i = min(math.floor(x), 3.0)
    w = x - i
    i = int(i)
    coef = _NIELL_TABLE[i] * (1.0 - w) + _NIELL_TABLE[i + 1] * w
    season = math.cos(2.0 * math.pi * (doy - 28.0) / 365.25)
    season = -season if lat < 0.0 else season
    a_h, b_h, c_h = (coef[j] - coef[3 + j] * season for j in range(3))
    s = np.sin(el)
    m_h = _marini(s, a_h, b_h, c_h) + (1.0 / s - _marini(s, 2.53e-5, 5.49e-3, 1.14e-3)) * (
        h * 1e-3
    )
    return m_h, _marini(s, coef[6], coef[7], coef[8])


def _zhd(lat, h):
    p = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    return 0.0022768 * p / (1.0 - 0.00266 * math.cos(2.0 * lat) - 2.8e-7 * h)


def _earth_rotate(v, tau):
    """R3(w_e tau) v for [S, 3] vectors and [S] travel times."""
    th = nn.OMEGA_E * tau
    c, s = np.cos(th), np.sin(th)
    return np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]], axis=1)


def _geometry(rx_pos, rx_vel, sat_pos, sat_vel):
    """models.geometry: Sagnac-corrected range (2 light-time iterations), LOS, range rate."""
    rho = np.linalg.norm(sat_pos - rx_pos, axis=1)
    for _ in range(2):
        rot = _earth_rotate(sat_pos, rho / C_LIGHT)
        rho = np.linalg.norm(rot - rx_pos, axis=1)
    vel_s = _earth_rotate(sat_vel, rho / C_LIGHT)
    los = (rot - rx_pos) / rho[:, None]
    return rho, los, np.sum(los * (vel_s - rx_vel), axis=1)


def _elevation(los, rx_llh):
    C = nn.C_l_e(rx_llh[0], rx_llh[1])
    return np.arcsin(np.clip(los @ C[:, 2], -1.0, 1.0))


def _elevation_sigma(sigma, el):
    s = np.sin(np.maximum(el, 1e-3))
    return np.where(el >= math.pi / 6, sigma, sigma / (2.0 * s))


# ---- EKF (filter/ekf.py) -----------------------------------------------------------------------


def _masked_update(P, y, H, r_var, mask, gate):
    """ekf.masked_update from x = 0 with diagonal R: Joseph form, chi-square gated, masked rows
    decoupled. Returns (x, P, used, nis)."""
    s_diag = np.einsum("ij,jk,ik->i", H, P, H) + r_var
    used = mask & ~(y * y > gate * s_diag)
    n = P.shape[0]
    if not used.any():
        return np.zeros(n), P, used, 0.0
    H_u = H[used]
    nu_u = y[used]
    r_u = r_var[used]
    HP = H_u @ P
    S = HP @ H_u.T + np.diag(r_u)
    sol = np.linalg.solve(S, np.concatenate([HP, nu_u[:, None]], axis=1))
    K = sol[:, :n].T
    IKH = np.eye(n) - K @ H_u
    P_new = IKH @ P @ IKH.T + (K * r_u) @ K.T
    P_new = 0.5 * (P_new + P_new.T)
    return K @ nu_u, P_new, used, float(nu_u @ sol[:, n])


def _update_with_postfit(nf: NumpyTightFilter, P, dz, H, r_var, mask, slot, kind):
    """tight._update_with_postfit: one update, then up to ``postfit_passes`` times: if the worst
    normalised post-fit residual (covariance R - H P+ H^T, untestable rows 0) of the used rows
    exceeds the threshold, drop it (a code row: every row of its slot) and redo. Also returns
    the slots dropped for a code outlier."""
    x, P1, used, nis = _masked_update(P, dz, H, r_var, mask, nf.gate_chi2)
    dropped = np.zeros(nf.n_slots, bool)
    for _ in range(nf.postfit_passes):
        c = r_var - np.einsum("ij,jk,ik->i", H, P1, H)
        testable = c > 1e-6 * r_var
        resid = np.where(testable, (dz - H @ x) / np.sqrt(np.where(testable, c, 1.0)), 0.0)
        score = np.where(used, np.abs(resid), 0.0)
        worst = int(np.argmax(score))
        if score[worst] <= nf.postfit_sigma:
            break
        if kind[worst] == KIND_CODE:
            drop = slot == slot[worst]
            dropped[slot[worst]] = True
        else:
            drop = np.arange(dz.size) == worst
        x, P1, used, nis = _masked_update(P, dz, H, r_var, used & ~drop, nf.gate_chi2)
    return x, P1, used, nis, dropped


def _median_code(dz, is_code):
    return float(np.median(dz[is_code])) if is_code.any() else 0.0


# ---- the epoch ---------------------------------------------------------------------------------


def _epoch(nf: NumpyTightFilter, st: dict, ep: dict, mechanize):
    """tight.epoch_step for InsSystem / INS15 / float_ppp (GPS, undifferenced)."""
    L = nf.layout
    S = nf.n_slots
    dt = nf.imu_dt_s
    i_clk, i_drift, i_zwd = L.i("clock_bias"), L.i("clock_drift"), L.i("zwd")
    AMB = L.sl("amb")

    # InsSystem.propagate: compensate the raw samples (errors.correct_imu), mechanize.
    dth = (ep["dtheta_b"] - st["gyro_bias"] * dt) / (1.0 + st["gyro_scale"])
    dv = (ep["dv_b"] - st["accel_bias"] * dt) / (1.0 + st["accel_scale"])
    llh, vel, q = mechanize(
        st["llh"], st["vel"], st["q"], st["prev_dth"], st["prev_dv"], dth, dv, dt
    )
    span = dt * dth.shape[0]
    f_b, w_ib_b = dv.sum(0) / span, dth.sum(0) / span
    C = nn.dcm_from_quat(q)

    rates = (nn.input_rate2(dv, dt, nf.accel_vrw**2), nn.input_rate2(dth, dt, nf.gyro_arw**2),
             span)
    F, Qg = _process_model(nf, llh, vel, C, f_b, rates)
    P = _propagate_covariance(nf, st["P"], F, Qg)
    # InsSystem.predict_sensors (errors.decay): the filter's Gauss-Markov bias shares decay.
    fa = np.exp(-nf.epoch_dt_s / nf.accel_bias_tau_s)
    fg = np.exp(-nf.epoch_dt_s / nf.gyro_bias_tau_s)
    accel_bias = st["accel_bias"] - (1.0 - fa) * st["accel_bias_gm"]
    gyro_bias = st["gyro_bias"] - (1.0 - fg) * st["gyro_bias_gm"]
    accel_gm, gyro_gm = fa * st["accel_bias_gm"], fg * st["gyro_bias_gm"]
    gnss = st["gnss"].copy()
    gnss[i_clk] += gnss[i_drift] * nf.epoch_dt_s

    rx_pos, rx_vel, rx_llh, J_pos, J_vel = _antenna(nf, llh, vel, C, w_ib_b)
    rho, los, rate = _geometry(rx_pos, rx_vel, ep["sat_pos"], ep["sat_vel"])
    el = _elevation(los, rx_llh)
    usable = ep["available"] & ep["keep"] & (el >= nf.elevation_mask_rad)
    restart = usable & (~st["tracked"] | ep["slip"])

    # Per-slot ambiguity resets (ppp.slot_state_resets + ekf.reset_states) from IF phase - code.
    code = ep["code_m"] - ep["code_bias_m"]
    code_if = nf.alpha * code[:, 0] + nf.beta * code[:, 1]
    phase_if = nf.alpha * ep["phase_m"][:, 0] + nf.beta * ep["phase_m"][:, 1]
    if restart.any():
        idx = np.flatnonzero(restart) + AMB.start
        P[idx, :] = 0.0
        P[:, idx] = 0.0
        P[idx, idx] = nf.ambiguity_init_sigma_m**2
        amb = gnss[AMB]
        gnss[AMB] = np.where(restart, phase_if - code_if, amb)

    # Measurement rows (ppp.measurement_rows, float_ppp + Doppler): code, phase, Doppler blocks.
    m_h, m_w = _niell(el, rx_llh[0], rx_llh[2], ep["doy"])
    trop = _zhd(rx_llh[0], rx_llh[2]) * m_h + gnss[i_zwd] * m_w
    geo_pred = rho + (gnss[i_clk] - ep["sat_clock"]) + trop
    u_pos = -los
    H_common = u_pos @ J_pos
    H_common[:, i_clk] += 1.0
    H_common[:, i_zwd] += m_w
    H_phase = H_common.copy()
    H_phase[np.arange(S), AMB.start + np.arange(S)] += 1.0
    H_dop = u_pos @ J_vel
    H_dop[:, i_drift] += 1.0
    sig_scale = _elevation_sigma(1.0, el)
    if_noise = np.sqrt(nf.alpha**2 + nf.beta**2)
    prod = nf.product_var_m2
    dz = np.concatenate(
        [
            geo_pred - code_if,
            geo_pred + gnss[AMB] - phase_if,
            rate + gnss[i_drift] - ep["sat_clock_rate"] - ep["range_rate"],
        ]
    )
    H = np.concatenate([H_common, H_phase, H_dop])
    r_var = np.concatenate(
        [
            (nf.code_sigma_m * sig_scale * if_noise) ** 2 + prod,
            (nf.phase_sigma_m * sig_scale * if_noise) ** 2,
            (nf.doppler_sigma_m_s * sig_scale) ** 2,
        ]
    )
    mask = np.concatenate([usable, usable, usable])
    slot = np.tile(np.arange(S), 3)
    kind = np.repeat([KIND_CODE, KIND_PHASE, KIND_DOPPLER], S)
    is_code = (kind == KIND_CODE) & mask

    # tight._clock_jump: a common code offset beyond the pre-fit threshold re-levels the clock.
    med = _median_code(dz, is_code)
    if abs(med) > nf.prefit_code_m:
        gnss[i_clk] -= med
        dz = dz - med * H[:, i_clk]
        P[i_clk, :] = 0.0
        P[:, i_clk] = 0.0
        P[i_clk, i_clk] = nf.clock_init_sigma_m**2

    # tight._prefit_mask: a code row far from the median code residual removes its whole slot.
    med = _median_code(dz, is_code)
    bad = is_code & (np.abs(dz - med) > nf.prefit_code_m)
    bad_slot = np.zeros(S, bool)
    bad_slot[slot[bad]] = True
    code_slot = np.zeros(S, bool)
    code_slot[slot[is_code]] = True
    n_min = 4  # tight.MIN_PREFIT_SATELLITES: the lock-out guard
    if code_slot.sum() < n_min or (code_slot & ~bad_slot).sum() >= n_min:
        mask = mask & ~bad_slot[slot]

    x, P, used, nis, dropped = _update_with_postfit(nf, P, dz, H, r_var, mask, slot, kind)

    # Closed-loop feedback (errors.feedback, errors.feedback_sensors) and GNSS totals.
    llh = llh - x[L.sl("pos")]
    vel = vel - x[L.sl("vel")]
    q = nn.quat_normalize(nn.quat_mul(nn.quat_from_rotvec(x[L.sl("att")]), q))
    d_accel = (1.0 + st["accel_scale"]) * x[L.sl("accel_bias")]
    d_gyro = (1.0 + st["gyro_scale"]) * x[L.sl("gyro_bias")]
    accel_bias, accel_gm = accel_bias + d_accel, accel_gm + nf.accel_gm_share * d_accel
    gyro_bias, gyro_gm = gyro_bias + d_gyro, gyro_gm + nf.gyro_gm_share * d_gyro
    gnss[nf.n_sys :] -= x[nf.n_sys :]

    tracked = np.zeros(S, bool)
    tracked[slot[used & (kind == KIND_PHASE)]] = True
    tracked |= dropped & st["tracked"] & ~ep["slip"]  # a post-fit outlier is not a slip
    new = dict(
        llh=llh, vel=vel, q=q, prev_dth=dth[-1], prev_dv=dv[-1],
        accel_bias=accel_bias, gyro_bias=gyro_bias, accel_bias_gm=accel_gm, gyro_bias_gm=gyro_gm,
        accel_scale=st["accel_scale"], gyro_scale=st["gyro_scale"],
        gnss=gnss, P=P, tracked=tracked, elevation=np.where(usable, el, st["elevation"]),
    )
    euler = nn.euler_from_dcm(nn.dcm_from_quat(q))
    out = (llh, vel, euler, P[: nf.n_nav, : nf.n_nav], nis, int(used.sum()), gnss[i_clk])
    return new, out


def _to_numpy(tree):
    import jax

    return jax.tree.map(lambda a: np.array(a), tree)


def run(nf: NumpyTightFilter, carry0, inputs, strapdown: str = "scalar") -> dict:
    """Run the filter over stacked epochs from a jaxnav ``tight.Carry`` and ``tight.EpochInput``
    (converted to NumPy once here). Returns NumPy arrays per epoch: llh [T, 3] (rad, rad, m),
    vel_enu [T, 3], euler [T, 3] (roll, pitch, azimuth), P_nav [T, 9, 9], nis [T], dof [T],
    clock_bias_m [T] (as ``tight.EpochOutput``), and ``final``: the last state as a dict.

    ``strapdown``: "scalar" (default) runs the IMU-rate recursion on Python floats, "vector" on
    NumPy 3-vectors (same equations; about 5x slower from NumPy's per-call overhead).
    """
    mechanize = {"scalar": _mechanize_scalar, "vector": nn.mechanize}[strapdown]
    c = _to_numpy(carry0)
    inp = _to_numpy(inputs)
    nav, prev, sens = c.nav.state, c.nav.prev, c.sensors
    st = dict(
        llh=nav.llh, vel=nav.vel_enu, q=nav.q_b_l, prev_dth=prev.dtheta_b, prev_dv=prev.dv_b,
        accel_bias=sens.accel_bias_m_s2, gyro_bias=sens.gyro_bias_rad_s,
        accel_bias_gm=sens.accel_bias_gm_m_s2, gyro_bias_gm=sens.gyro_bias_gm_rad_s,
        accel_scale=sens.accel_scale, gyro_scale=sens.gyro_scale,
        gnss=c.gnss_est, P=c.P, tracked=c.tracked.astype(bool), elevation=c.elevation,
    )
    obs = inp.obs
    T = inp.keep.shape[0]
    outs = []
    for k in range(T):
        ep = dict(
            dtheta_b=inp.samples.dtheta_b[k], dv_b=inp.samples.dv_b[k],
            code_m=obs.code_m[k], phase_m=obs.phase_m[k], range_rate=obs.range_rate_m_s[k],
            available=obs.available[k], slip=obs.slip[k], code_bias_m=obs.code_bias_m[k],
            sat_pos=obs.sat.pos_ecef[k], sat_vel=obs.sat.vel_ecef[k],
            sat_clock=obs.sat.clock_m[k], sat_clock_rate=obs.sat.clock_rate_m_s[k],
            keep=inp.keep[k], doy=float(inp.day_of_year[k]),
        )
        st, out = _epoch(nf, st, ep, mechanize)
        outs.append(out)
    names = ("llh", "vel_enu", "euler", "P_nav", "nis", "dof", "clock_bias_m")
    res = {name: np.array([o[j] for o in outs]) for j, name in enumerate(names)}
    res["final"] = st
    return res
