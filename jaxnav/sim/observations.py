"""Simulated GNSS code, carrier-phase and Doppler observables with every PPP error source.

Per fixed slot (gnss/signals.py) and epoch, for a given receiver-antenna trajectory (ECEF
position and velocity at the epochs; the lever arm is applied by the caller) and a PRNG key.
Pure JAX: one ``lax.scan`` over epochs, vmappable over keys; :func:`init_state` / :func:`step`
expose the per-epoch recursion so a Monte-Carlo sweep can fuse the simulator into its own scan
instead of materialising all epochs (memory bounded by one epoch).

Observation equations (S002 eq 2.25-2.26, in metres; slot s, band b, code type c of band b)::

    P_c  = rho + c dt_r - c(dt^s + dt_rel) + T + I_b + B^r_c - B^s_c + m_b + e_c
    Phi_b = rho + c dt_r - c(dt^s + dt_rel) + T - I_b + lambda_b (N_b + d^r_b - d^s_b)
            + mu_b + eps_b
    D_b  = d/dt [Phi_b without noise / multipath]  (= -lambda_b * doppler_hz, SEED_SPEC 2.6)

- rho = |R3(we tau) r^s(t - tau) - r_r(t)|: the transmit-time satellite position rotated into the
  receive-time ECEF frame (Sagnac), tau solved by light-time iteration; t is true GPS time (the
  epochs are true time; the receiver clock enters only through c dt_r).
- dt_r: receiver clock, two-state [bias, drift] model with the S001 eq 16 PSDs
  S_f = K c^2 h0 / 2, S_g = 2 K pi^2 c^2 h_-2 (h0 = 2e-19, h_-2 = 2e-20, K = 4), sampled exactly.
- dt^s: satellite clock polynomial of the orbit source (referenced to the P1/P2 or E1/E5a
  ionosphere-free code, like precise products); dt_rel = -2 r.v / c^2 (periodic relativity, which
  precise-product users add themselves; zero for the circular nominal orbits).
- T = m_h(E) ZHD + m_w(E) (ZWD0 + dZ_w(t)): Saastamoinen ZHD with Berg pressure (S002 2.3), ZWD0
  from Saastamoinen wet with a standard atmosphere, Niell mapping; dZ_w a first-order GM residual.
- I_b = (f_L1 / f_b)^2 I_L1 with I_L1 = M_SLM(E) c K_v(IPP, t) g (1 + q r_s(t)): the Klobuchar
  vertical delay K_v (broadcast coefficients) evaluated at the thin-shell pierce point and mapped
  with the single-layer factor, scaled by g (``iono_scale``), times a per-satellite correlated
  residual r_s (unit second-order GM, smooth over seconds) of fraction q. The Klobuchar
  *broadcast model* value the SF user would apply (IS-GPS-200 geometry) is returned as
  ``iono_model_l1_m`` (or, with ``ObsParams.gim_error_fraction`` f, a GIM-grade value
  I + f (I_Klob - I)); a filter that applies it sees the residual
  ``truth.iono_l1_m - iono_model_l1_m``.
- B^r_c - B^s_c: code biases. Satellite biases follow the precise-clock convention (zero in the
  P1/P2 ionosphere-free combination): B^s_P1 = beta D, B^s_P2 = -alpha D with D = DCB_P1P2 and
  B^s_C1 = B^s_P1 - DCB_P1C1 (products returned exactly). Receiver biases per system follow the
  same convention plus the inter-system bias ISB (GPS ISB = 0: the clock absorbs GPS biases).
- d^r_b - d^s_b: fractional phase biases (absorbed by float ambiguities); N_b integer ambiguities
  drawn anew at every arc start (first epoch, rise, relock) and changed by an integer jump at a
  cycle slip. Slips and losses of lock are Bernoulli events per tracked slot and epoch
  (``slip_prob``, ``loss_of_lock_prob``; :func:`slip_environment` sets them from rates per
  satellite-hour of an environment). The receiver's loss-of-lock indicator ``lli`` is set at
  every relock and at a fraction ``slip_lli_prob`` of the slips; the rest must be found by the
  GF / MW detector (gnss/slips.py), as on real data (sim/scenario.py runs it).
- m_b, mu_b: elevation-dependent multipath (first-order GM, shared by the codes of one band);
  e, eps: white noise with sigma(E) = sigma0 for E >= 30 deg, sigma0 / (2 sin E) below
  (S001 eq 11 [recon]); Doppler noise likewise.
- Precise products given to the filter = truth - residual errors: orbit (GM per axis) and clock
  (GM), cm level; broadcast values (for SF users) likewise with metre-level GM errors.
Not simulated (the filter's models would remove them exactly, SEED_SPEC 5): phase wind-up,
tides, antenna PCO/PCV, second-order ionosphere, GLONASS inter-frequency code biases.

Values in invalid slots (``valid`` False) are finite but meaningless.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import geodesy
from jaxnav.core import gpstime
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import corrections, signals
from jaxnav.gnss.signals import CODE_BAND, N_CODES, N_SYSTEMS, SYS_GAL
from jaxnav.sim import constellation
from jaxnav.sim.constellation import (
    DEFAULT_ELEVATION_MASK_RAD,
    DEFAULT_T0_GPS_S,
    take_satellites,
)

N_BANDS_SIM = 2  # PPP bands (0, 1) of every system
_MIN_SIN_EL = 0.02  # floor of sin E in the sigma law (keeps invalid, below-horizon slots finite)
_MIN_EL_RAD = math.radians(1.0)  # floor for troposphere / ionosphere models (invalid slots)
_LIGHT_TIME_ITERATIONS = 2
# Columns of the per-epoch block of standard normal draws, per slot.
_NORMAL_WIDTHS = {
    "iono": 2,
    "orbit_err": 3,
    "clock_err": 1,
    "brdc_orbit_err": 3,
    "brdc_clock_err": 1,
    "mp_code": 2,
    "mp_phase": 2,
    "code": N_CODES,
    "phase": 2,
    "doppler": 2,
}
_NORMAL_BLOCKS = tuple(_NORMAL_WIDTHS)
_NORMAL_SPLITS = tuple(np.cumsum(list(_NORMAL_WIDTHS.values()))[:-1].tolist())
_N_NORMAL_COLS = int(sum(_NORMAL_WIDTHS.values()))


class SlipEnvironment(NamedTuple):
    """Rates of carrier-phase cycle slips and losses of lock per tracked satellite-hour."""

    slips_per_sat_hour: float
    losses_per_sat_hour: float
    loss_duration_s: float


#: Chosen rates per environment (docs/simulation.md, "Cycle slips"). Open sky is anchored on
#: ESBC's 24 h (20 GF / MW flags, no LLI, in 145 used GPS satellite-hours of a geodetic
#: receiver at 30 s: 0.14 per satellite-hour, false alarms included); the
#: vehicle environments are chosen from the usual picture of a car under trees (suburban: a slip
#: per satellite every ~10 min, a blockage every ~5 min) and street canyons (urban: a slip every
#: ~2 min, a blockage every minute, lasting 10 s); no source document gives rates.
SLIP_ENVIRONMENTS = {
    "none": SlipEnvironment(0.0, 0.0, 5.0),
    "open_sky": SlipEnvironment(0.14, 0.14, 5.0),
    "suburban": SlipEnvironment(6.0, 12.0, 5.0),
    "urban": SlipEnvironment(30.0, 60.0, 10.0),
}


def _per_epoch(rate_per_hour: float, dt_s: float) -> float:
    """Probability 1 - exp(-r dt / 3600) of at least one Poisson event in an epoch of dt s."""
    return -math.expm1(-rate_per_hour * dt_s / 3600.0)


class ObsParams(NamedTuple):
    """Error-model parameters of the observation simulator (SI units).

    Source of each default in the comment: seed + equation, a standard, or "chosen" + reason.
    """

    elevation_mask_rad: float = DEFAULT_ELEVATION_MASK_RAD  # chosen: 10 deg (S002: 7, S000: 10)
    # White noise sigma0 (zenith) of sigma(E) = sigma0 (E >= 30 deg), sigma0 / (2 sin E) below.
    code_sigma0_m: tuple = (0.3, 0.2, 0.2)  # C1, P1, P2: S001 eq 11 (P: 0.2 m); C/A chosen 0.3
    phase_sigma0_m: float = 0.002  # S001 eq 11
    doppler_sigma0_m_s: float = 0.1  # S001 eq 11
    system_code_scale: tuple = (1.0, 1.0, 1.0)  # GPS, GLONASS, Galileo (chosen: equal; S002
    # weights GLONASS x3 code, x1.5 phase in its filter)
    system_phase_scale: tuple = (1.0, 1.0, 1.0)
    # Multipath: first-order GM with the same elevation law (chosen: typical open-sky vehicle).
    multipath_code_sigma0_m: float = 0.2  # chosen
    multipath_phase_sigma0_m: float = 0.002  # chosen (mm-level carrier multipath)
    multipath_tau_s: float = 30.0  # chosen (decorrelates in tens of seconds on a moving car)
    # Receiver clock (S001 eq 16, Brown & Hwang).
    clock_h0: float = 2.0e-19
    clock_h_m2: float = 2.0e-20
    clock_k: float = 4.0
    clock_bias0_sigma_m: float = 300.0  # chosen: ~1 us initial offset
    clock_drift0_sigma_m_s: float = 1.0  # chosen: ~3e-9 TCXO frequency offset
    # Troposphere.
    rel_humidity: float = 0.5  # chosen: standard atmosphere for the ZWD0 model
    zwd_residual_sigma_m: float = 0.02  # chosen: ZWD0 model error of a few cm
    zwd_residual_tau_s: float = 4.0 * 3600.0  # chosen: equivalent random walk ~1.4 cm/sqrt(h)
    # Ionosphere.
    klobuchar_alpha: tuple = corrections.KLOBUCHAR_ALPHA_DEFAULT  # real broadcast set (2020-06-25)
    klobuchar_beta: tuple = corrections.KLOBUCHAR_BETA_DEFAULT
    iono_scale: float = 1.0  # chosen: multiplier of the truth ionosphere (0 disables it)
    iono_residual_fraction: float = 0.3  # chosen: Klobuchar leaves 30-50 % of the delay
    iono_residual_tau_s: float = 1800.0  # chosen (second-order GM: smooth at 1 s)
    iono_shell_height_m: float = corrections.IONO_SHELL_HEIGHT_M
    # None: ``iono_model_l1_m`` is the Klobuchar broadcast value (what an SF receiver has).
    # A number f: a global ionosphere map (GIM) whose error is f times the Klobuchar residual,
    # I_GIM = I + f (I_Klob - I), so it keeps that residual's slow (tau 30 min) correlation.
    # Chosen for S001 (a GIM of 2-4 TECU against a 30-50 % Klobuchar): f = 0.25.
    gim_error_fraction: float | None = None
    # Precise-product residuals (truth - product), first-order GM.
    orbit_sigma_m: float = 0.025  # per ECEF axis; IGS final orbits ~2.5 cm
    orbit_tau_s: float = 3600.0  # chosen
    sat_clock_sigma_m: float = 0.02  # IGS final clocks ~75 ps RMS (2.2 cm)
    sat_clock_tau_s: float = 1800.0  # chosen
    # Broadcast-ephemeris residuals (for single-frequency users), first-order GM.
    brdc_orbit_sigma_m: float = 0.6  # per axis; chosen from the GPS broadcast-vs-SP3 1.4 m 3D RMS
    brdc_orbit_tau_s: float = 7200.0  # chosen: one upload cycle
    brdc_clock_sigma_m: float = 0.6  # chosen: GPS broadcast clock ~2 ns
    brdc_clock_tau_s: float = 7200.0  # chosen
    # Code biases (drawn once per realisation).
    sat_dcb_p1p2_sigma_m: float = 1.5  # chosen: CODE satellite DCBs are within ~+-10 ns
    sat_dcb_p1c1_sigma_m: float = 0.3  # chosen: P1-C1 satellite DCBs ~1 ns
    rcv_dcb_p1p2_sigma_m: float = 3.0  # chosen
    rcv_dcb_p1c1_sigma_m: float = 0.5  # chosen
    isb_m: tuple = (0.0, 8.0, 3.0)  # GPS, GLONASS, Galileo receiver ISB; chosen (tens of ns)
    # Ambiguities, cycle slips, loss of lock.
    ambiguity_max_cyc: int = 100000  # chosen: |N| bound of the initial integer ambiguities
    # Default: "open_sky" at 1 Hz (SLIP_ENVIRONMENTS; slip_environment for others / other rates).
    slip_prob: float = _per_epoch(SLIP_ENVIRONMENTS["open_sky"].slips_per_sat_hour, 1.0)
    slip_max_cyc: int = 3  # slip size uniform in [-max, max] per band (at least one nonzero)
    loss_of_lock_prob: float = _per_epoch(SLIP_ENVIRONMENTS["open_sky"].losses_per_sat_hour, 1.0)
    loss_of_lock_epochs: int = 5  # epochs without lock after a loss (then a new arc)
    slip_lli_prob: float = 0.0  # chosen: fraction of slips the receiver flags itself (LLI); 0
    # makes the detector find every slip (ESBC's PolaRx5 set no LLI in 24 h, docs/simulation.md)


def slip_environment(params: ObsParams, name: str, epoch_interval_s: float = 1.0) -> ObsParams:
    """``params`` with the slip and loss-of-lock probabilities of environment ``name``.

    Poisson events at rate r per satellite-hour: p = 1 - exp(-r dt / 3600) per epoch of dt s;
    a loss of lock lasts ``loss_duration_s`` rounded to whole epochs (at least one).
    """
    if name not in SLIP_ENVIRONMENTS:
        raise ValueError(f"unknown slip environment {name!r}; use {', '.join(SLIP_ENVIRONMENTS)}")
    env = SLIP_ENVIRONMENTS[name]
    dt = float(epoch_interval_s)
    return params._replace(
        slip_prob=_per_epoch(env.slips_per_sat_hour, dt),
        loss_of_lock_prob=_per_epoch(env.losses_per_sat_hour, dt),
        loss_of_lock_epochs=max(1, round(env.loss_duration_s / dt)),
    )


DEFAULT_PARAMS = ObsParams()


class SimConstants(NamedTuple):
    """Per-realisation constants: frequencies and biases drawn at :func:`init_state`."""

    freq_hz: jnp.ndarray  # [n, 2]
    wavelength_m: jnp.ndarray  # [n, 2]
    code_bias_m: jnp.ndarray  # [n, 3] B^r_c - B^s_c
    phase_bias_cyc: jnp.ndarray  # [n, 2] d^r_b - d^s_b
    sat_dcb_p1p2_m: jnp.ndarray  # [n]
    sat_dcb_p1c1_m: jnp.ndarray  # [n]
    rcv_dcb_p1p2_m: jnp.ndarray  # [3] per system
    rcv_dcb_p1c1_m: jnp.ndarray  # [3]


class SimState(NamedTuple):
    """Carry of the epoch recursion."""

    key: jnp.ndarray
    t_prev: jnp.ndarray  # scalar, s
    clock: jnp.ndarray  # [2] bias m, drift m/s
    zwd_res: jnp.ndarray  # scalar, m
    iono_res: jnp.ndarray  # [n, 2] unit second-order GM (value, rate)
    orbit_err: jnp.ndarray  # [n, 3] m
    clock_err: jnp.ndarray  # [n] m
    brdc_orbit_err: jnp.ndarray  # [n, 3]
    brdc_clock_err: jnp.ndarray  # [n]
    mp_code: jnp.ndarray  # [n, 2] unit GM per band
    mp_phase: jnp.ndarray  # [n, 2] unit GM
    ambiguity_cyc: jnp.ndarray  # [n, 2] integer-valued
    lock_wait: jnp.ndarray  # [n] int32 epochs left without lock
    prev_valid: jnp.ndarray  # [n] bool
    const: SimConstants


class ObsTruth(NamedTuple):
    """True error components per epoch (stacked [n_ep, ...] by simulate_observations)."""

    range_m: jnp.ndarray  # [n] geometric range incl. Sagnac
    tau_s: jnp.ndarray  # [n] signal travel time
    rcv_clock_m: jnp.ndarray  # [] c dt_r
    rcv_clock_drift_m_s: jnp.ndarray  # []
    sat_clock_m: jnp.ndarray  # [n] c (dt^s + dt_rel), what the signal carries
    relativity_m: jnp.ndarray  # [n] c dt_rel
    trop_m: jnp.ndarray  # [n] slant troposphere
    zhd_m: jnp.ndarray  # []
    zwd_m: jnp.ndarray  # [] ZWD0 + residual
    map_wet: jnp.ndarray  # [n] Niell wet mapping
    iono_l1_m: jnp.ndarray  # [n] slant ionosphere at GPS L1 (1575.42 MHz)
    iono_m: jnp.ndarray  # [n, 2] per band
    orbit_err_ecef: jnp.ndarray  # [n, 3] truth - precise product
    sat_clock_err_m: jnp.ndarray  # [n] truth - precise product (m)
    brdc_orbit_err_ecef: jnp.ndarray  # [n, 3]
    brdc_clock_err_m: jnp.ndarray  # [n]
    code_bias_m: jnp.ndarray  # [n, 3]
    phase_bias_cyc: jnp.ndarray  # [n, 2]
    ambiguity_cyc: jnp.ndarray  # [n, 2]
    multipath_code_m: jnp.ndarray  # [n, 3]
    multipath_phase_m: jnp.ndarray  # [n, 2]
    noise_code_m: jnp.ndarray  # [n, 3]
    noise_phase_m: jnp.ndarray  # [n, 2]
    noise_doppler_m_s: jnp.ndarray  # [n, 2]


class EpochObs(NamedTuple):
    """One epoch of observables and products (fields of :class:`Observations` without [n_ep])."""

    t_s: jnp.ndarray
    code_m: jnp.ndarray  # [n, 3] C1, P1, P2
    phase_cyc: jnp.ndarray  # [n, 2]
    doppler_hz: jnp.ndarray  # [n, 2]
    valid: jnp.ndarray  # [n] bool
    slip: jnp.ndarray  # [n] bool
    cycle_slip: jnp.ndarray  # [n] bool
    lli: jnp.ndarray  # [n] bool
    elevation_rad: jnp.ndarray  # [n]
    azimuth_rad: jnp.ndarray  # [n]
    sat_pos_ecef: jnp.ndarray  # [n, 3]
    sat_vel_ecef: jnp.ndarray  # [n, 3]
    sat_clock_m: jnp.ndarray  # [n]
    sat_clock_rate_m_s: jnp.ndarray  # [n]
    sat_pos_brdc_ecef: jnp.ndarray  # [n, 3]
    sat_clock_brdc_m: jnp.ndarray  # [n]
    iono_model_l1_m: jnp.ndarray  # [n]
    truth: ObsTruth | None


class Observations(NamedTuple):
    """Simulated observables, masks, products and truth ([n_ep] leading axis unless noted).

    - ``code_m`` [n_ep, n, 3]: pseudoranges of code types C1, P1, P2 (signals.CODE_*), metres.
    - ``phase_cyc`` [n_ep, n, 2]: carrier phase of bands 0, 1 in cycles (S002 sign: +lambda N).
    - ``doppler_hz`` [n_ep, n, 2]: Doppler with D[m/s] = -lambda D_Hz (SEED_SPEC 2.6).
    - ``valid`` [n_ep, n]: slot occupied, record usable, elevation >= mask and in lock.
    - ``slip`` [n_ep, n]: truth, a new ambiguity arc starts here (first epoch, rise, relock, or
      slip); ``cycle_slip``: truth, the slips of continuing arcs only (what a detector must
      find); ``lli``: the receiver's loss-of-lock indicator (relocks and the flagged slips).
    - ``sat_pos_ecef`` / ``sat_vel_ecef`` [n_ep, n, 3]: precise-product satellite state at the
      true transmission time, in the ECEF frame of that instant (apply the Earth rotation during
      travel, e.g. corrections.geometric_range_m); ``sat_clock_m`` = c dt^s of the product
      (P1/P2 or E1/E5a IF reference, without periodic relativity: add
      c corrections.relativistic_clock_s). ``*_brdc_*``: broadcast-quality values.
    - ``iono_model_l1_m``: Klobuchar broadcast slant delay at GPS L1 for SF users.
    - Per-slot constants: ``freq_hz``, ``wavelength_m`` [n, 2], satellite DCB products
      ``sat_dcb_p1p2_m``, ``sat_dcb_p1c1_m`` [n].
    - ``truth``: :class:`ObsTruth` (or None when simulated without truth).
    """

    t_s: jnp.ndarray
    code_m: jnp.ndarray
    phase_cyc: jnp.ndarray
    doppler_hz: jnp.ndarray
    valid: jnp.ndarray
    slip: jnp.ndarray
    cycle_slip: jnp.ndarray
    lli: jnp.ndarray
    elevation_rad: jnp.ndarray
    azimuth_rad: jnp.ndarray
    sat_pos_ecef: jnp.ndarray
    sat_vel_ecef: jnp.ndarray
    sat_clock_m: jnp.ndarray
    sat_clock_rate_m_s: jnp.ndarray
    sat_pos_brdc_ecef: jnp.ndarray
    sat_clock_brdc_m: jnp.ndarray
    iono_model_l1_m: jnp.ndarray
    freq_hz: jnp.ndarray
    wavelength_m: jnp.ndarray
    sat_dcb_p1p2_m: jnp.ndarray
    sat_dcb_p1c1_m: jnp.ndarray
    truth: ObsTruth | None


# ------------------------------------------------------------------------------------------------
# Stochastic building blocks
# ------------------------------------------------------------------------------------------------


def elevation_sigma_factor(elevation_rad):
    """S001 eq 11 [recon]: 1 for E >= 30 deg, 1 / (2 sin E) below (continuous at 30 deg)."""
    s = jnp.maximum(jnp.sin(elevation_rad), _MIN_SIN_EL)
    return jnp.where(elevation_rad >= jnp.pi / 6.0, 1.0, 0.5 / s)


def gauss_markov_step(x, z, dt, sigma, tau):
    """Exact first-order GM transition x' = x e^(-dt/tau) + sigma sqrt(1 - e^(-2 dt/tau)) z.

    ``z`` standard normal draws shaped like x. Stationary variance sigma^2 (S001 eq 13 with
    q = 2 sigma^2 / tau, discretised exactly).
    """
    phi = jnp.exp(-dt / tau)
    return x * phi + sigma * jnp.sqrt(1.0 - phi * phi) * z


def _uniform(z):
    """U(0, 1) from standard normals: u = Phi(z) = erfc(-z / sqrt 2) / 2."""
    return 0.5 * jax.scipy.special.erfc(-z / math.sqrt(2.0))


def _chol2(q11, q12, q22):
    """Lower Cholesky factor of a 2x2 covariance, safe when it is (near) singular."""
    l11 = jnp.sqrt(jnp.maximum(q11, 0.0))
    l21 = jnp.where(l11 > 0.0, q12 / jnp.where(l11 > 0.0, l11, 1.0), 0.0)
    l22 = jnp.sqrt(jnp.maximum(q22 - l21 * l21, 0.0))
    return l11, l21, l22


def gauss_markov2_step(x, z, dt, sigma, tau):
    """Exact step of a critically damped second-order GM, state [..., 2] = (value, rate).

    ``z``: standard normal draws shaped like x. x'' = -2 b x' - b^2 x + w, b = 1/tau,
    PSD(w) = 4 b^3 sigma^2: stationary value variance sigma^2, rate variance b^2 sigma^2,
    autocorrelation (1 + b|t|) e^(-b|t|). Transition
    Phi = e^(-b dt) [[1 + b dt, dt], [-b^2 dt, 1 - b dt]] and, because the process is
    stationary, Q = P_inf - Phi P_inf Phi^T with P_inf = diag(sigma^2, b^2 sigma^2). Unlike a
    first-order GM its short-term increments are smooth (rate-continuous), as for ionospheric
    delays whose changes over 1 s are sub-millimetre.
    """
    b = 1.0 / tau
    e = jnp.exp(-b * dt)
    p11, p22 = sigma**2, (b * sigma) ** 2
    f11, f12, f21, f22 = e * (1.0 + b * dt), e * dt, -e * b * b * dt, e * (1.0 - b * dt)
    q11 = p11 - (f11 * f11 * p11 + f12 * f12 * p22)
    q12 = -(f11 * f21 * p11 + f12 * f22 * p22)
    q22 = p22 - (f21 * f21 * p11 + f22 * f22 * p22)
    l11, l21, l22 = _chol2(q11, q12, q22)
    x0 = f11 * x[..., 0] + f12 * x[..., 1] + l11 * z[..., 0]
    x1 = f21 * x[..., 0] + f22 * x[..., 1] + l21 * z[..., 0] + l22 * z[..., 1]
    return jnp.stack([x0, x1], axis=-1)


def clock_psd(params: ObsParams):
    """(S_f [m^2/s], S_g [m^2/s^3]) = (K c^2 h0 / 2, 2 K pi^2 c^2 h_-2) (S001 eq 16)."""
    s_f = params.clock_k * C_LIGHT**2 * params.clock_h0 / 2.0
    s_g = 2.0 * params.clock_k * math.pi**2 * C_LIGHT**2 * params.clock_h_m2
    return s_f, s_g


def receiver_clock_step(clock, z, dt, params: ObsParams):
    """Exact discretisation of the [bias m, drift m/s] clock over dt (``z``: 2 normal draws).

    x' = [[1, dt], [0, 1]] x + w, Cov(w) = [[S_f dt + S_g dt^3/3, S_g dt^2/2], [S_g dt^2/2, S_g dt]]
    (SEED_SPEC 1.6, the standard two-state form of the S001 eq 16 PSDs).
    """
    s_f, s_g = clock_psd(params)
    q11 = s_f * dt + s_g * dt**3 / 3.0
    q12 = s_g * dt**2 / 2.0
    q22 = s_g * dt
    l11, l21, l22 = _chol2(q11, q12, q22)
    w = jnp.stack([l11 * z[0], l21 * z[0] + l22 * z[1]])
    return jnp.stack([clock[0] + dt * clock[1], clock[1]]) + w


def simulate_receiver_clock(key, n_epochs, dt, params: ObsParams = DEFAULT_PARAMS):
    """Receiver clock [n_epochs, 2] (bias m, drift m/s) starting from zero, step dt."""

    def body(x, z):
        x = receiver_clock_step(x, z, dt, params)
        return x, x

    _, xs = jax.lax.scan(body, jnp.zeros(2), jax.random.normal(key, (n_epochs, 2)))
    return xs


# ------------------------------------------------------------------------------------------------
# Set-up and per-epoch step
# ------------------------------------------------------------------------------------------------


def _frequencies(slots):
    freq = signals.slot_frequencies_hz(slots)
    return freq, C_LIGHT / freq


def init_state(key, t_start, slots: signals.SlotTable, params: ObsParams = DEFAULT_PARAMS):
    """Initial :class:`SimState`: stationary GM draws, clock offset, biases (one realisation)."""
    n = slots.n_slots
    # A single block of normal draws (every PRNG call is a sizeable piece of compiled code).
    key, k_norm = jax.random.split(key)
    zz = jax.random.normal(k_norm, (n * 17 + 2 * N_SYSTEMS + 3 + (n + N_SYSTEMS) * N_BANDS_SIM,))
    zs = zz[: n * 17].reshape(n, 17)
    zr = zz[n * 17 : n * 17 + 2 * N_SYSTEMS + 3]
    us = _uniform(zz[n * 17 + 2 * N_SYSTEMS + 3 :]).reshape(n + N_SYSTEMS, N_BANDS_SIM) - 0.5
    freq, lam = _frequencies(slots)
    alpha, beta = signals.if_coefficients(freq[:, 0], freq[:, 1])
    gal = slots.system == SYS_GAL

    sat_dcb = params.sat_dcb_p1p2_sigma_m * zs[:, 0]
    # Galileo has a single E1 code: its "C1" and "P1" types share the signal (no P1-C1 bias).
    sat_p1c1 = jnp.where(gal, 0.0, params.sat_dcb_p1c1_sigma_m * zs[:, 1])
    rcv_dcb = params.rcv_dcb_p1p2_sigma_m * zr[:N_SYSTEMS]
    rcv_p1c1 = params.rcv_dcb_p1c1_sigma_m * zr[N_SYSTEMS : 2 * N_SYSTEMS]
    rcv_p1c1 = rcv_p1c1.at[SYS_GAL].set(0.0)
    isb = jnp.asarray(params.isb_m, dtype=jnp.float64)[slots.system]
    rd = rcv_dcb[slots.system]
    # IF-neutral split of a P1-P2 DCB D: B_P1 = beta D, B_P2 = -alpha D (alpha B_P1 + beta B_P2 = 0)
    sat_b = jnp.stack([beta * sat_dcb - sat_p1c1, beta * sat_dcb, -alpha * sat_dcb], axis=-1)
    rcv_b = (
        jnp.stack([beta * rd - rcv_p1c1[slots.system], beta * rd, -alpha * rd], axis=-1)
        + isb[:, None]
    )
    sat_phase = us[:n]
    rcv_phase = us[n:]
    const = SimConstants(
        freq_hz=freq,
        wavelength_m=lam,
        code_bias_m=rcv_b - sat_b,
        phase_bias_cyc=rcv_phase[slots.system] - sat_phase,
        sat_dcb_p1p2_m=sat_dcb,
        sat_dcb_p1c1_m=sat_p1c1,
        rcv_dcb_p1p2_m=rcv_dcb,
        rcv_dcb_p1c1_m=rcv_p1c1,
    )
    base = 2 * N_SYSTEMS
    clock0 = jnp.stack(
        [
            params.clock_bias0_sigma_m * zr[base],
            params.clock_drift0_sigma_m_s * zr[base + 1],
        ]
    )
    return SimState(
        key=key,
        t_prev=jnp.asarray(t_start, dtype=jnp.float64),
        clock=clock0,
        zwd_res=params.zwd_residual_sigma_m * zr[base + 2],
        iono_res=zs[:, 2:4] * jnp.array([1.0, 1.0 / params.iono_residual_tau_s]),
        orbit_err=params.orbit_sigma_m * zs[:, 4:7],
        clock_err=params.sat_clock_sigma_m * zs[:, 7],
        brdc_orbit_err=params.brdc_orbit_sigma_m * zs[:, 8:11],
        brdc_clock_err=params.brdc_clock_sigma_m * zs[:, 11],
        mp_code=zs[:, 12:14],
        mp_phase=zs[:, 14:16],
        ambiguity_cyc=jnp.zeros((n, N_BANDS_SIM)),
        lock_wait=jnp.zeros(n, dtype=jnp.int32),
        prev_valid=jnp.zeros(n, dtype=bool),
        const=const,
    )


class _Smooth(NamedTuple):
    """Differentiable (in t and r_r) parts of one epoch's geometry and propagation."""

    range_m: jnp.ndarray
    tau_s: jnp.ndarray
    sat_clock_poly_m: jnp.ndarray
    relativity_m: jnp.ndarray
    trop_m: jnp.ndarray
    zhd_m: jnp.ndarray
    map_wet: jnp.ndarray
    iono_l1_m: jnp.ndarray
    iono_model_l1_m: jnp.ndarray
    el: jnp.ndarray
    az: jnp.ndarray
    pos_tx: jnp.ndarray
    vel_tx: jnp.ndarray
    clock_rate_m_s: jnp.ndarray
    ok: jnp.ndarray


def _smooth(t, pos_rcv, orbits, orbit_dt, sow0, doy0, zwd_total_fn, iono_factor, params):
    """Geometry + smooth propagation terms at reception time t for receiver position pos_rcv."""
    # Light time: tau <- |R3(we tau) r^s(t - tau) - r_r| / c contracts by ~|v_s|/c = 1e-5 per
    # iteration from tau0 = 75 ms (|error| < 15 ms): two position-only iterations leave < 2e-12 s,
    # then one full evaluation (with velocity) at the converged transmission time.
    tau = jnp.full(orbits.system.shape, 0.075)
    for _ in range(_LIGHT_TIME_ITERATIONS):
        p_tx = constellation.satellite_position_clock(orbits, t + orbit_dt - tau)[0]
        tau = jnp.linalg.norm(corrections.earth_rotation_correct(p_tx, tau) - pos_rcv, axis=-1)
        tau = tau / C_LIGHT
    st = constellation.satellite_state(orbits, t + orbit_dt - tau)
    rot = corrections.earth_rotation_correct(st.pos_ecef, tau)
    rng = jnp.linalg.norm(rot - pos_rcv, axis=-1)
    tau = rng / C_LIGHT
    llh = geodesy.ecef_to_llh(pos_rcv)
    el, az = corrections.elevation_azimuth(pos_rcv, rot, llh)
    el_m = jnp.maximum(el, _MIN_EL_RAD)
    lat, lon, h = llh[0], llh[1], llh[2]
    doy = doy0 + t / 86400.0
    zhd = corrections.saastamoinen_zhd_m(lat, h)
    m_h, m_w = corrections.niell_mapping(el_m, lat, h, doy)
    trop = m_h * zhd + m_w * zwd_total_fn(h)
    sow = sow0 + t
    alpha = jnp.asarray(params.klobuchar_alpha)
    beta = jnp.asarray(params.klobuchar_beta)
    ipp_lat, ipp_lon = corrections.ionosphere_pierce_point(
        lat, lon, az, el_m, params.iono_shell_height_m
    )
    vert = corrections.klobuchar_vertical_delay_s(ipp_lat, ipp_lon, sow, alpha, beta)
    iono = corrections.thin_shell_mapping(el_m, params.iono_shell_height_m) * C_LIGHT * vert
    iono = iono * iono_factor
    model = C_LIGHT * corrections.klobuchar_delay_s(lat, lon, az, el_m, sow, alpha, beta)
    rel = C_LIGHT * corrections.relativistic_clock_s(st.pos_ecef, st.vel_ecef)
    return _Smooth(
        range_m=rng,
        tau_s=tau,
        sat_clock_poly_m=C_LIGHT * st.clock_s,
        relativity_m=rel,
        trop_m=trop,
        zhd_m=zhd,
        map_wet=m_w,
        iono_l1_m=iono,
        iono_model_l1_m=model,
        el=el,
        az=az,
        pos_tx=st.pos_ecef,
        vel_tx=st.vel_ecef,
        clock_rate_m_s=C_LIGHT * st.clock_rate_s_s,
        ok=st.ok,
    )


def step(
    state: SimState,
    t_s,
    pos_rcv_ecef,
    vel_rcv_ecef,
    orbits_slots,
    slots: signals.SlotTable,
    params: ObsParams,
    orbit_dt,
    sow0,
    doy0,
    with_truth=True,
):
    """Advance the simulator to epoch t_s and return (new_state, :class:`EpochObs`).

    ``orbits_slots`` is the orbit source already gathered to slot order
    (constellation.take_satellites(orbits, slots.sat_index)); ``orbit_dt`` = t0_gps_s -
    orbits.t_ref_gps_s; ``sow0`` / ``doy0`` the GPS second of week / day of year at scenario t=0.
    """
    n = slots.n_slots
    c = state.const
    # One block of normal draws per epoch, sliced per process (every PRNG call is a sizeable
    # piece of compiled code); uniforms are Phi(z) of normals.
    key, k_norm = jax.random.split(state.key)
    m_norm = n * _N_NORMAL_COLS
    zz = jax.random.normal(k_norm, (m_norm + 3 + 6 * n,))
    z_clock, z_zwd = zz[m_norm : m_norm + 2], zz[m_norm + 2]
    u = _uniform(zz[m_norm + 3 :]).reshape(n, 6)
    zz = zz[:m_norm].reshape(n, _N_NORMAL_COLS)
    z = dict(zip(_NORMAL_BLOCKS, jnp.split(zz, _NORMAL_SPLITS, axis=1), strict=True))
    dt = t_s - state.t_prev

    # --- stochastic processes advanced to t_s
    clock = receiver_clock_step(state.clock, z_clock, dt, params)
    zwd_res = gauss_markov_step(
        state.zwd_res, z_zwd, dt, params.zwd_residual_sigma_m, params.zwd_residual_tau_s
    )
    iono_res = gauss_markov2_step(state.iono_res, z["iono"], dt, 1.0, params.iono_residual_tau_s)
    orbit_err = gauss_markov_step(
        state.orbit_err, z["orbit_err"], dt, params.orbit_sigma_m, params.orbit_tau_s
    )
    clock_err = gauss_markov_step(
        state.clock_err, z["clock_err"][:, 0], dt, params.sat_clock_sigma_m, params.sat_clock_tau_s
    )
    brdc_orbit_err = gauss_markov_step(
        state.brdc_orbit_err,
        z["brdc_orbit_err"],
        dt,
        params.brdc_orbit_sigma_m,
        params.brdc_orbit_tau_s,
    )
    brdc_clock_err = gauss_markov_step(
        state.brdc_clock_err,
        z["brdc_clock_err"][:, 0],
        dt,
        params.brdc_clock_sigma_m,
        params.brdc_clock_tau_s,
    )
    mp_code = gauss_markov_step(state.mp_code, z["mp_code"], dt, 1.0, params.multipath_tau_s)
    mp_phase = gauss_markov_step(state.mp_phase, z["mp_phase"], dt, 1.0, params.multipath_tau_s)

    # --- geometry and smooth terms, with their time derivative along the trajectory (Doppler)
    iono_factor = params.iono_scale * (1.0 + params.iono_residual_fraction * iono_res[:, 0])
    iono_factor = jnp.maximum(iono_factor, 0.0)  # a negative delay is unphysical (rare clip)

    def zwd_total(h):
        return corrections.saastamoinen_zwd_m(h, params.rel_humidity) + zwd_res

    def f(t, r):
        return _smooth(t, r, orbits_slots, orbit_dt, sow0, doy0, zwd_total, iono_factor, params)

    sm, sm_dot = jax.jvp(
        f,
        (jnp.asarray(t_s, dtype=jnp.float64), jnp.asarray(pos_rcv_ecef, dtype=jnp.float64)),
        (jnp.ones((), dtype=jnp.float64), jnp.asarray(vel_rcv_ecef, dtype=jnp.float64)),
    )

    # --- masks, arcs, ambiguities
    tracked_geom = slots.occupied & sm.ok & (sm.el >= params.elevation_mask_rad)
    lol = tracked_geom & state.prev_valid & (u[:, 0] < params.loss_of_lock_prob)
    lock_wait = jnp.where(
        state.lock_wait > 0, state.lock_wait - 1, jnp.where(lol, params.loss_of_lock_epochs, 0)
    ).astype(jnp.int32)
    valid = tracked_geom & (lock_wait == 0)
    new_arc = valid & ~state.prev_valid
    slip_event = valid & state.prev_valid & (u[:, 1] < params.slip_prob)
    n_max = params.ambiguity_max_cyc
    fresh = jnp.minimum(jnp.floor(u[:, 2:4] * (2 * n_max + 1)), 2 * n_max) - n_max
    m = params.slip_max_cyc
    jump = jnp.minimum(jnp.floor(u[:, 4:6] * (2 * m + 1)), 2 * m) - m
    jump = jump.at[:, 0].set(jnp.where(jnp.all(jump == 0, axis=1), 1.0, jump[:, 0]))
    amb = jnp.where(
        new_arc[:, None],
        fresh,
        jnp.where(slip_event[:, None], state.ambiguity_cyc + jump, state.ambiguity_cyc),
    )
    slip = new_arc | slip_event
    # u[:, 1] < slip_prob draws the slip; its lowest fraction slip_lli_prob is the flagged part
    # (one uniform for both keeps every other draw of a realisation unchanged).
    relock = new_arc & (state.lock_wait > 0)  # after a loss of lock (not at a satellite's rise)
    lli = relock | (slip_event & (u[:, 1] < params.slip_prob * params.slip_lli_prob))

    # --- observables
    lam = c.wavelength_m
    iono_band = sm.iono_l1_m[:, None] * signals.iono_scale(signals.GPS_L1_HZ, c.freq_hz)
    iono_band_dot = sm_dot.iono_l1_m[:, None] * signals.iono_scale(signals.GPS_L1_HZ, c.freq_hz)
    sat_clock_true = sm.sat_clock_poly_m + sm.relativity_m
    common = sm.range_m + clock[0] - sat_clock_true + sm.trop_m  # [n]
    common_dot = (
        sm_dot.range_m + clock[1] - sm_dot.sat_clock_poly_m - sm_dot.relativity_m + sm_dot.trop_m
    )
    sys_code = jnp.asarray(params.system_code_scale)[slots.system]
    sys_phase = jnp.asarray(params.system_phase_scale)[slots.system]
    fac = elevation_sigma_factor(sm.el)
    code_sig = jnp.asarray(params.code_sigma0_m)[None, :] * (fac * sys_code)[:, None]
    phase_sig = params.phase_sigma0_m * fac * sys_phase
    dop_sig = params.doppler_sigma0_m_s * fac
    noise_code = code_sig * z["code"]
    noise_phase = phase_sig[:, None] * z["phase"]
    noise_dop = dop_sig[:, None] * z["doppler"]
    band = jnp.asarray(CODE_BAND)
    mp_code_m = params.multipath_code_sigma0_m * fac[:, None] * sys_code[:, None] * mp_code
    mp_phase_m = params.multipath_phase_sigma0_m * fac[:, None] * sys_phase[:, None] * mp_phase

    code_m = common[:, None] + iono_band[:, band] + c.code_bias_m + mp_code_m[:, band] + noise_code
    phase_m = (
        common[:, None] - iono_band + lam * (amb + c.phase_bias_cyc) + mp_phase_m + noise_phase
    )
    range_rate = common_dot[:, None] - iono_band_dot + noise_dop

    iono_model = sm.iono_model_l1_m
    if params.gim_error_fraction is not None:
        iono_model = sm.iono_l1_m + params.gim_error_fraction * (iono_model - sm.iono_l1_m)
    obs = EpochObs(
        t_s=jnp.asarray(t_s, dtype=jnp.float64),
        code_m=code_m,
        phase_cyc=phase_m / lam,
        doppler_hz=-range_rate / lam,
        valid=valid,
        slip=slip,
        cycle_slip=slip_event,
        lli=lli,
        elevation_rad=sm.el,
        azimuth_rad=sm.az,
        sat_pos_ecef=sm.pos_tx - orbit_err,
        sat_vel_ecef=sm.vel_tx,
        sat_clock_m=sm.sat_clock_poly_m - clock_err,
        sat_clock_rate_m_s=sm.clock_rate_m_s,
        sat_pos_brdc_ecef=sm.pos_tx - brdc_orbit_err,
        sat_clock_brdc_m=sm.sat_clock_poly_m - brdc_clock_err,
        iono_model_l1_m=iono_model,
        truth=None,
    )
    if with_truth:
        obs = obs._replace(
            truth=ObsTruth(
                range_m=sm.range_m,
                tau_s=sm.tau_s,
                rcv_clock_m=clock[0],
                rcv_clock_drift_m_s=clock[1],
                sat_clock_m=sat_clock_true,
                relativity_m=sm.relativity_m,
                trop_m=sm.trop_m,
                zhd_m=sm.zhd_m,
                zwd_m=corrections.saastamoinen_zwd_m(
                    geodesy.ecef_to_llh(pos_rcv_ecef)[2], params.rel_humidity
                )
                + zwd_res,
                map_wet=sm.map_wet,
                iono_l1_m=sm.iono_l1_m,
                iono_m=iono_band,
                orbit_err_ecef=orbit_err,
                sat_clock_err_m=clock_err,
                brdc_orbit_err_ecef=brdc_orbit_err,
                brdc_clock_err_m=brdc_clock_err,
                code_bias_m=c.code_bias_m,
                phase_bias_cyc=c.phase_bias_cyc,
                ambiguity_cyc=amb,
                multipath_code_m=mp_code_m[:, band],
                multipath_phase_m=mp_phase_m,
                noise_code_m=noise_code,
                noise_phase_m=noise_phase,
                noise_doppler_m_s=noise_dop,
            )
        )
    new_state = state._replace(
        key=key,
        t_prev=jnp.asarray(t_s, dtype=jnp.float64),
        clock=clock,
        zwd_res=zwd_res,
        iono_res=iono_res,
        orbit_err=orbit_err,
        clock_err=clock_err,
        brdc_orbit_err=brdc_orbit_err,
        brdc_clock_err=brdc_clock_err,
        mp_code=mp_code,
        mp_phase=mp_phase,
        ambiguity_cyc=amb,
        lock_wait=lock_wait,
        prev_valid=valid,
    )
    return new_state, obs


def scenario_time_constants(orbits, t0_gps_s=DEFAULT_T0_GPS_S):
    """(orbit_dt, sow0, doy0) of a scenario starting at t0_gps_s (host floats)."""
    t0 = float(t0_gps_s)
    orbit_dt = t0 - float(orbits.t_ref_gps_s)
    sow0 = math.fmod(t0, gpstime.SECONDS_PER_WEEK)
    doy0 = gpstime.day_of_year(t0)
    return orbit_dt, sow0, doy0


@partial(jax.jit, static_argnames=("with_truth",))
def _simulate(key, t_s, pos, vel, orbits, slots, params, orbit_dt, sow0, doy0, with_truth):
    orbits_slots = take_satellites(orbits, slots.sat_index)
    state0 = init_state(key, t_s[0], slots, params)

    def body(state, inputs):
        t, p, v = inputs
        return step(state, t, p, v, orbits_slots, slots, params, orbit_dt, sow0, doy0, with_truth)

    last, ep = jax.lax.scan(body, state0, (t_s, pos, vel))
    c = last.const
    return Observations(
        t_s=ep.t_s,
        code_m=ep.code_m,
        phase_cyc=ep.phase_cyc,
        doppler_hz=ep.doppler_hz,
        valid=ep.valid,
        slip=ep.slip,
        cycle_slip=ep.cycle_slip,
        lli=ep.lli,
        elevation_rad=ep.elevation_rad,
        azimuth_rad=ep.azimuth_rad,
        sat_pos_ecef=ep.sat_pos_ecef,
        sat_vel_ecef=ep.sat_vel_ecef,
        sat_clock_m=ep.sat_clock_m,
        sat_clock_rate_m_s=ep.sat_clock_rate_m_s,
        sat_pos_brdc_ecef=ep.sat_pos_brdc_ecef,
        sat_clock_brdc_m=ep.sat_clock_brdc_m,
        iono_model_l1_m=ep.iono_model_l1_m,
        freq_hz=c.freq_hz,
        wavelength_m=c.wavelength_m,
        sat_dcb_p1p2_m=c.sat_dcb_p1p2_m,
        sat_dcb_p1c1_m=c.sat_dcb_p1c1_m,
        truth=ep.truth,
    )


def simulate_observations(
    key,
    t_s,
    pos_rcv_ecef,
    vel_rcv_ecef,
    orbits,
    slots: signals.SlotTable,
    params: ObsParams = DEFAULT_PARAMS,
    t0_gps_s=DEFAULT_T0_GPS_S,
    with_truth=True,
) -> Observations:
    """Simulate code / phase / Doppler for every slot and epoch (see the module docstring).

    - ``t_s`` [n_ep]: epoch times, seconds since the scenario start ``t0_gps_s`` (GPS seconds,
      a host float); 1 Hz is typical but any increasing grid works.
    - ``pos_rcv_ecef``, ``vel_rcv_ecef`` [n_ep, 3]: antenna position and velocity (truth).
    - ``orbits``: constellation.NominalOrbits or BroadcastEphemeris; ``slots`` from
      constellation.build_slots on the same source.
    - ``with_truth``: also return the :class:`ObsTruth` components (memory ~2x).
    Pure in ``key``: ``jax.vmap(lambda k: simulate_observations(k, ...))(keys)`` gives
    independent realisations over the same geometry.
    """
    orbit_dt, sow0, doy0 = scenario_time_constants(orbits, t0_gps_s)
    return _simulate(
        key,
        jnp.asarray(t_s, dtype=jnp.float64),
        jnp.asarray(pos_rcv_ecef, dtype=jnp.float64),
        jnp.asarray(vel_rcv_ecef, dtype=jnp.float64),
        orbits,
        slots,
        params,
        orbit_dt,
        sow0,
        doy0,
        with_truth,
    )
