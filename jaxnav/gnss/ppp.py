"""PPP measurement models: GNSS error states, their dynamics, and the rows of every mode.

One configuration (:class:`PppConfig`) selects the flavour; the same epoch step in
``filter/tight.py`` uses the returned (residual, H, R, mask) for any of them:

- ``sf_code``   C1 minus a model ionosphere (Klobuchar / GIM), its residual in R (S000, S002).
- ``df_code``   ionosphere-free P1/P2 code (S000).
- ``sdf_code``  Hatch-smoothed ionosphere-free code (S000 eqs 4.48-4.59 as a growing window,
                capped at ``hatch_window`` epochs and restarted whenever the slot loses phase).
- ``float_ppp`` IF code + IF carrier with a float ambiguity per slot in metres (S002/S003/S004).
- ``ic_ppp``    uncombined P1, P2, L1, L2 with per-slot slant ionosphere, L1 and L2 ambiguities,
                a receiver DCB and GIM pseudo-observations (S001 eqs 1-9).
plus Doppler rows in every mode, inter-system bias states for GLONASS and Galileo (S002, S004),
a zenith wet delay state, and between-satellite single differences (S004) as an option.

Conventions: residual dz = h(x_hat) - z, H = dh/dx (filter/states.py). The GNSS states hold
totals in ``gnss_est`` (a vector in the GNSS part of the layout) and errors in the filter's x.
All per-slot arrays are [S]; masks select what is used.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp

from jaxnav import geodesy
from jaxnav.filter.states import StateLayout
from jaxnav.gnss import corrections, models, signals

_CLOCK_H0 = 2.0e-19  # S001 eq 16 (Brown & Hwang), white frequency noise
_CLOCK_H_M2 = 2.0e-20  # random-walk frequency noise
_CLOCK_K = 4.0  # S001's empirical inflation
_SQRT_H = 60.0  # sqrt(3600 s): converts "per sqrt(hour)" to "per sqrt(second)"


class SlotInfo(NamedTuple):
    """Static description of the satellite slots of a scenario (one entry per slot)."""

    system: jnp.ndarray  # [S] int: signals.SYS_GPS / SYS_GLO / SYS_GAL
    f1_hz: jnp.ndarray  # [S] first PPP frequency (GLONASS: FDMA channel dependent)
    f2_hz: jnp.ndarray  # [S] second PPP frequency


class GnssObs(NamedTuple):
    """One epoch of observations and products, per slot [S] (band index 0 = f1, 1 = f2)."""

    code_m: jnp.ndarray  # [S, 2] pseudoranges (C1 or P1, P2) [m]
    phase_m: jnp.ndarray  # [S, 2] carrier phase times wavelength [m]
    range_rate_m_s: jnp.ndarray  # [S] f1 Doppler as range rate, -lambda1 * D_Hz [m/s]
    available: jnp.ndarray  # [S] bool: all signals of the slot tracked this epoch
    slip: jnp.ndarray  # [S] bool: loss of lock / cycle slip flagged this epoch
    code_bias_m: jnp.ndarray  # [S, 2] known satellite code biases w.r.t. the clock datum [m]
    iono_model_l1_m: jnp.ndarray  # [S] model (broadcast / GIM) slant f1 ionosphere [m]
    sat: models.SatEpoch


class PppConfig(eqx.Module):
    """A PPP flavour and its stochastic model. Every number states its source."""

    mode: str = eqx.field(static=True, default="float_ppp")
    systems: tuple[int, ...] = eqx.field(static=True, default=(signals.SYS_GPS,))
    n_slots: int = eqx.field(static=True, default=16)
    doppler: bool = eqx.field(static=True, default=True)
    estimate_zwd: bool = eqx.field(static=True, default=True)
    bssd: bool = eqx.field(static=True, default=False)
    # Zenith a-priori sigmas of the raw observables, scaled by S001 eq 11 with elevation.
    # S001 uses 0.2 m for P1/P2. Chosen 0.5 m: the simulator adds a 0.2 m multipath with a 30 s
    # correlation time, which a filter weighting each epoch as independent must absorb
    # (measured: position NEES 4.6 at 0.6 m, 17 at 0.3 m over a 15-min drive).
    code_sigma_m: float = 0.5
    phase_sigma_m: float = 0.003  # S002: phase = code / 100
    doppler_sigma_m_s: float = 0.1  # S001 eq 11
    glonass_code_factor: float = 3.0  # S002
    glonass_phase_factor: float = 1.5  # S002
    # Ionosphere model residual (SF rows and IC-PPP pseudo-observations): 1-sigma =
    # sqrt((fraction * model)^2 + floor^2). Chosen: a broadcast (Klobuchar) model leaves 30-50 %
    # (the simulator leaves 30 %); a GIM ~ 2 TECU (0.3 m at L1, S001 eq 7 sigma_ion,0).
    iono_model_residual_fraction: float = 0.3
    iono_model_residual_floor_m: float = 0.3
    # Orbit + clock residual of the products, common to code and phase of a satellite (chosen:
    # IGS-final level, 2.5 cm orbit + 2 cm clock; the filter has no state for it).
    product_sigma_m: float = 0.03
    sdf_sigma_floor_fraction: float = 0.35  # chosen: smoothed code keeps >= 35 % of its noise
    hatch_window: int = eqx.field(static=True, default=100)  # chosen: 100 epochs (S000: silent)
    elevation_mask_rad: float = 0.17453292519943295  # 10 deg (S000 QC mask; S002 used 7 deg)
    prefit_code_m: float = 20.0  # S002: coarse pre-fit threshold for code
    gate_chi2: float = 25.0  # chosen: 5-sigma innovation gate (normalised by H P H^T + R)
    # S002: normalised post-fit residual threshold. None: no post-fit test (one update per
    # epoch instead of two; roofline.py measures what the second update costs).
    postfit_sigma: float | None = 3.0
    # Process noise.
    clock_bias_psd_m2_s: float = _CLOCK_K * geodesy.C_LIGHT**2 * _CLOCK_H0 / 2.0  # S001 eq 16
    clock_drift_psd_m2_s3: float = 2.0 * _CLOCK_K * jnp.pi**2 * geodesy.C_LIGHT**2 * _CLOCK_H_M2
    isb_psd_m2_s: float = (0.01 / _SQRT_H) ** 2  # chosen: 1 cm/sqrt(h) random walk
    zwd_psd_m2_s: float = (0.01 / _SQRT_H) ** 2  # chosen: 1 cm/sqrt(h) (common PPP setting)
    # Slant-ionosphere random walk (S001 eqs 4-5 form). S001 prints 0.03 m/sqrt(h); chosen
    # 1 m/sqrt(h): a slant delay drifts with the satellite's elevation and the local time by
    # 0.3-0.55 m per 10 min (measured on the simulator's Klobuchar-based truth, RW-equivalent
    # 0.8-1.3 m/sqrt(h)), which the stiff value cannot follow; the unfollowed change then leaks
    # into position through the phase rows (seed001 report: IC-PPP 2D RMS 0.23 vs 0.17 m).
    iono_sigma_m_sqrt_h: float = 1.0
    dcb_sigma_m_sqrt_h: float = 0.03  # S001 eqs 8-9
    # Initial / reset variances.
    clock_init_sigma_m: float = 1e3
    clock_drift_init_sigma_m_s: float = 10.0
    isb_init_sigma_m: float = 10.0  # S004: a-priori constraint on the ISBs
    zwd_init_sigma_m: float = 0.1
    ambiguity_init_sigma_m: float = 10.0
    iono_init_sigma_m: float = 3.0
    # How IC-PPP uses the ionosphere model (S001 eqs 6-7): "prior" = the model value and its
    # sigma (``iono_model_var``) initialise each slant-ionosphere state when its slot (re)starts;
    # "epoch" = S001 as printed, a white pseudo-observation at every epoch. Chosen default
    # "prior": the model error is correlated over tens of minutes, so re-applying it each epoch
    # as independent pins the state to the model's bias (measured, airborne IC-PPP/INS: 1.4 m
    # 2D error after 20 min with "epoch" vs 0.1 m for IF-PPP/INS).
    iono_constraint: str = eqx.field(static=True, default="prior")
    dcb_init_sigma_m: float = 10.0

    def __check_init__(self):
        if self.mode not in models.MODES:
            raise ValueError(f"unknown PPP mode {self.mode!r}; expected one of {models.MODES}")
        if self.mode == "ic_ppp" and self.bssd:
            raise ValueError("ic_ppp with between-satellite differences is not supported")
        if self.iono_constraint not in ("prior", "epoch"):
            raise ValueError(
                f"iono_constraint = {self.iono_constraint!r}: expected 'prior' or 'epoch'"
            )

    @property
    def uses_phase(self) -> bool:
        return self.mode in models.PHASE_MODES


_ISB_BLOCK = {signals.SYS_GLO: "isb_glo", signals.SYS_GAL: "isb_gal"}


def gnss_blocks(cfg: PppConfig, have_clock: bool = False) -> tuple[tuple[str, int], ...]:
    """GNSS error-state blocks of a configuration (``have_clock``: the system already has them).

    BSSD removes the receiver clock and drift (S004 eq 25); ISBs persist for non-GPS systems.
    """
    S = cfg.n_slots
    blocks = []
    if not cfg.bssd and not have_clock:
        blocks += [("clock_bias", 1), ("clock_drift", 1)]
    blocks += [(_ISB_BLOCK[s], 1) for s in cfg.systems if s in _ISB_BLOCK]
    if cfg.estimate_zwd:
        blocks.append(("zwd", 1))
    if cfg.mode == "float_ppp":
        blocks.append(("amb", S))
    elif cfg.mode == "ic_ppp":
        blocks += [("amb1", S), ("amb2", S), ("iono", S), ("dcb", 1)]
    return tuple(blocks)


def iono_rw_sigma(cfg: PppConfig, elevation_rad):
    """S001 eq 5: q_ion = sigma for E >= 30 deg, sigma / (2 sin E) below [m/sqrt(h)]."""
    return models.elevation_sigma(cfg.iono_sigma_m_sqrt_h, elevation_rad)


def gnss_dynamics(cfg: PppConfig, layout: StateLayout, elevation_rad, skip=()):
    """Continuous F and diagonal process-noise PSD q (n-vector) of the GNSS blocks in ``layout``.

    Clock: bias' = drift, PSDs of S001 eq 16; ISB, ZWD, slant ionosphere and DCB: random walks;
    ambiguities: constants. Blocks absent from ``layout`` or named in ``skip`` (modelled by the
    navigation system, e.g. the clock of seed 000's 16-state RISS) are left zero.
    """
    n = layout.size
    F = jnp.zeros((n, n))
    q = jnp.zeros(n)
    if layout.has("clock_bias") and "clock_bias" not in skip:
        F = F.at[layout.i("clock_bias"), layout.i("clock_drift")].set(1.0)
        q = q.at[layout.i("clock_bias")].set(cfg.clock_bias_psd_m2_s)
        q = q.at[layout.i("clock_drift")].set(cfg.clock_drift_psd_m2_s3)
    for name in _ISB_BLOCK.values():
        if layout.has(name):
            q = q.at[layout.i(name)].set(cfg.isb_psd_m2_s)
    if layout.has("zwd"):
        q = q.at[layout.i("zwd")].set(cfg.zwd_psd_m2_s)
    if layout.has("iono"):
        q = q.at[layout.sl("iono")].set((iono_rw_sigma(cfg, elevation_rad) / _SQRT_H) ** 2)
        q = q.at[layout.i("dcb")].set((cfg.dcb_sigma_m_sqrt_h / _SQRT_H) ** 2)
    return F, q


def gnss_initial_std(cfg: PppConfig, layout: StateLayout):
    """Initial standard deviations of the GNSS blocks (zeros elsewhere)."""
    std = jnp.zeros(layout.size)
    init = {
        "clock_bias": cfg.clock_init_sigma_m,
        "clock_drift": cfg.clock_drift_init_sigma_m_s,
        "isb_glo": cfg.isb_init_sigma_m,
        "isb_gal": cfg.isb_init_sigma_m,
        "zwd": cfg.zwd_init_sigma_m,
        "amb": cfg.ambiguity_init_sigma_m,
        "amb1": cfg.ambiguity_init_sigma_m,
        "amb2": cfg.ambiguity_init_sigma_m,
        "iono": cfg.iono_init_sigma_m,
        "dcb": cfg.dcb_init_sigma_m,
    }
    for name, sigma in init.items():
        if layout.has(name):
            std = std.at[layout.sl(name)].set(sigma)
    return std


_PER_SLOT_BLOCKS = ("amb", "amb1", "amb2", "iono")


def iono_model_var(cfg: PppConfig, iono_model_l1_m, elevation_rad):
    """Variance [m^2] of the model (broadcast / GIM) slant L1 ionosphere:
    (fraction * I_model)^2 + (floor * s(E))^2, s(E) the S001 eq 11 elevation factor."""
    floor = models.elevation_sigma(cfg.iono_model_residual_floor_m, elevation_rad)
    return (cfg.iono_model_residual_fraction * iono_model_l1_m) ** 2 + floor**2


def slot_state_resets(cfg: PppConfig, layout: StateLayout, reset_slot, iono_var=None):
    """Per-state reset flags and variances for slots that rose, slipped or returned ([S] bool).

    The variances are the initial ones of ``gnss_initial_std`` on the per-slot blocks; with
    ``iono_var`` [S] (IC-PPP, ``iono_constraint = "prior"``) the slant ionosphere restarts at
    the model's variance instead.
    """
    flags = jnp.zeros(layout.size, bool)
    in_block = jnp.zeros(layout.size, bool)
    for name in _PER_SLOT_BLOCKS:
        if layout.has(name):
            flags = flags.at[layout.sl(name)].set(reset_slot)
            in_block = in_block.at[layout.sl(name)].set(True)
    var = jnp.where(in_block, gnss_initial_std(cfg, layout) ** 2, 0.0)
    if iono_var is not None and layout.has("iono"):
        var = var.at[layout.sl("iono")].set(iono_var)
    return flags, var


class Combos(NamedTuple):
    """Per-slot observation combinations shared by the row builders."""

    alpha: jnp.ndarray  # [S] IF weight of f1
    beta: jnp.ndarray  # [S] IF weight of f2 (alpha + beta = 1)
    gamma: jnp.ndarray  # [S] (f1/f2)^2
    code_if_m: jnp.ndarray  # [S]
    phase_if_m: jnp.ndarray  # [S]
    code_corr_m: jnp.ndarray  # [S, 2] bias-corrected raw codes


def combos(slots: SlotInfo, obs: GnssObs) -> Combos:
    """Ionosphere-free code and phase after removing the known satellite code biases."""
    alpha, beta = signals.if_coefficients(slots.f1_hz, slots.f2_hz)
    code = obs.code_m - obs.code_bias_m
    return Combos(
        alpha,
        beta,
        (slots.f1_hz / slots.f2_hz) ** 2,
        alpha * code[:, 0] + beta * code[:, 1],
        alpha * obs.phase_m[:, 0] + beta * obs.phase_m[:, 1],
        code,
    )


class HatchState(NamedTuple):
    """Per-slot carrier-smoothing memory (S000 eqs 4.48-4.59 as a recursive Hatch filter)."""

    smoothed_m: jnp.ndarray  # [S] smoothed IF code
    prev_phase_m: jnp.ndarray  # [S] IF phase at the previous epoch
    count: jnp.ndarray  # [S] epochs in the current window (0 = restart)

    @classmethod
    def empty(cls, n_slots):
        z = jnp.zeros(n_slots)
        return cls(z, z, z)


def hatch_update(cfg: PppConfig, state: HatchState, cmb: Combos, tracked, restart):
    """Hatch: P_bar_k = P_k/n + (n-1)/n (P_bar_{k-1} + Phi_k - Phi_{k-1}), n = min(k, N) (SEED 2.4).

    ``tracked`` slots advance; ``restart`` (rise, slip, return after an outage) sets n = 1.
    Untracked slots keep count 0 so their next epoch restarts the window.
    """
    n = jnp.where(restart, 1.0, jnp.minimum(state.count + 1.0, cfg.hatch_window))
    propagated = state.smoothed_m + cmb.phase_if_m - state.prev_phase_m
    smoothed = cmb.code_if_m / n + (n - 1.0) / n * propagated
    return HatchState(
        jnp.where(tracked, smoothed, state.smoothed_m),
        jnp.where(tracked, cmb.phase_if_m, state.prev_phase_m),
        jnp.where(tracked, n, 0.0),
    )


class Receiver(NamedTuple):
    """The antenna as the navigation system predicts it, with Jacobians w.r.t. the full dx."""

    pos_ecef: jnp.ndarray  # [3]
    vel_ecef: jnp.ndarray  # [3]
    llh: jnp.ndarray  # [3]
    J_pos: jnp.ndarray  # [3, n] d(pos_ecef)/d(dx)
    J_vel: jnp.ndarray  # [3, n] d(vel_ecef)/d(dx)


class Rows(NamedTuple):
    """Stacked measurement rows of one epoch: residual dz = h(x_hat) - z, H, R, mask."""

    dz: jnp.ndarray  # [m]
    H: jnp.ndarray  # [m, n]
    R: jnp.ndarray  # [m, m]
    mask: jnp.ndarray  # [m] bool
    slot: jnp.ndarray  # [m] int: slot of each row (-1 for none)
    kind: jnp.ndarray  # [m] int: 0 code, 1 phase, 2 Doppler, 3 ionosphere pseudo-observation


KIND_CODE, KIND_PHASE, KIND_DOPPLER, KIND_IONO = 0, 1, 2, 3


def _column(layout: StateLayout, name, n_rows, values=1.0):
    """[n_rows, n] block with ``values`` in column ``name`` (zeros if the layout lacks it)."""
    out = jnp.zeros((n_rows, layout.size))
    if layout.has(name):
        out = out.at[:, layout.i(name)].set(values)
    return out


def _per_slot(layout: StateLayout, name, values):
    """[S, n] block with values[i] at (i, first index of block ``name`` + i)."""
    S = values.shape[0]
    out = jnp.zeros((S, layout.size))
    start = layout.sl(name).start
    return out.at[jnp.arange(S), start + jnp.arange(S)].set(values)


def _block_value(layout, gnss_est, name, default=0.0):
    return gnss_est[layout.i(name)] if layout.has(name) else jnp.asarray(default)


def _reference_slot(slots: SlotInfo, elevation, usable):
    """Highest-elevation usable GPS slot (S004 uses a GPS reference satellite)."""
    score = jnp.where(usable & (slots.system == signals.SYS_GPS), elevation, -10.0)
    return jnp.argmax(score)


def _difference(dz, H, var, mask, ref):
    """Between-satellite differences against slot ``ref``: D dz, D H, D diag(var) D^T."""
    S = dz.shape[0]
    D = models.single_difference_matrix(S, ref)
    R = D @ jnp.diag(var) @ D.T
    R = R + jnp.diag(jnp.where(jnp.arange(S) == ref, 1.0, 0.0))  # keep the masked row regular
    return D @ dz, D @ H, R, mask & (jnp.arange(S) != ref) & mask[ref]


def measurement_rows(
    cfg: PppConfig,
    layout: StateLayout,
    slots: SlotInfo,
    obs: GnssObs,
    rx: Receiver,
    gnss_est,
    outage_keep,
    hatch: HatchState,
    day_of_year,
) -> tuple[Rows, jnp.ndarray]:
    """All rows of the configured mode at one epoch, and the per-slot elevation [rad].

    ``outage_keep`` [S] bool is the study's availability mask (False = withheld). Rows of one
    kind are blocks of S (code, then phase, then Doppler, then ionosphere pseudo-observations).
    """
    S = cfg.n_slots
    geo = models.geometry(rx.pos_ecef, rx.vel_ecef, obs.sat)
    C_e_l = geodesy.C_l_e(rx.llh[0], rx.llh[1]).T
    el, az = models.elevation_azimuth(geo.los_ecef, C_e_l)
    usable = obs.available & outage_keep & (el >= cfg.elevation_mask_rad)

    # Troposphere: a-priori hydrostatic + wet (Saastamoinen, Niell mapping); the estimated ZWD
    # replaces the a-priori wet part when the state exists.
    lat, h = rx.llh[0], rx.llh[2]
    m_h, m_w = corrections.niell_mapping(el, lat, h, day_of_year)
    zhd = corrections.saastamoinen_zhd_m(lat, h)
    zwd = gnss_est[layout.i("zwd")] if layout.has("zwd") else corrections.saastamoinen_zwd_m(h)
    trop = zhd * m_h + zwd * m_w

    clock = _block_value(layout, gnss_est, "clock_bias")
    isb = jnp.zeros(S)
    for sys, name in _ISB_BLOCK.items():
        if layout.has(name):
            isb = jnp.where(slots.system == sys, gnss_est[layout.i(name)], isb)
    rx_clock = clock + isb - obs.sat.clock_m

    # Geometry and common columns.
    u_pos = models.range_jacobian(geo)  # [S, 3] d(range)/d(r_rx) = -u^T
    H_geo = u_pos @ rx.J_pos
    H_common = H_geo + _column(layout, "clock_bias", S)
    for sys, name in _ISB_BLOCK.items():
        if layout.has(name):
            H_common = H_common + _column(layout, name, S, (slots.system == sys).astype(float))
    if layout.has("zwd"):
        H_common = H_common + _column(layout, "zwd", S, m_w)

    cmb = combos(slots, obs)
    sig_scale = models.elevation_sigma(1.0, el)
    glo = slots.system == signals.SYS_GLO
    code_sigma = cfg.code_sigma_m * jnp.where(glo, cfg.glonass_code_factor, 1.0) * sig_scale
    phase_sigma = cfg.phase_sigma_m * jnp.where(glo, cfg.glonass_phase_factor, 1.0) * sig_scale
    if_noise = jnp.sqrt(cmb.alpha**2 + cmb.beta**2)
    geo_pred = geo.range_m + rx_clock + trop

    blocks = []  # (dz, H, var, mask, kind)
    iono_var = iono_model_var(cfg, obs.iono_model_l1_m, el)
    prod = cfg.product_sigma_m**2  # not amplified by the IF combination: added after it
    if cfg.mode == "sf_code":
        z = cmb.code_corr_m[:, 0] - obs.iono_model_l1_m
        blocks.append((geo_pred - z, H_common, code_sigma**2 + iono_var + prod, usable, KIND_CODE))
    elif cfg.mode in ("df_code", "float_ppp"):
        var = (code_sigma * if_noise) ** 2 + prod
        blocks.append((geo_pred - cmb.code_if_m, H_common, var, usable, KIND_CODE))
    elif cfg.mode == "sdf_code":
        n = jnp.maximum(hatch.count, 1.0)
        frac = jnp.maximum(1.0 / jnp.sqrt(n), cfg.sdf_sigma_floor_fraction)
        var = (code_sigma * if_noise * frac) ** 2 + prod
        blocks.append((geo_pred - hatch.smoothed_m, H_common, var, usable, KIND_CODE))
    if cfg.mode == "float_ppp":
        amb = gnss_est[layout.sl("amb")]
        H_phase = H_common + _per_slot(layout, "amb", jnp.ones(S))
        var = (phase_sigma * if_noise) ** 2 + prod
        blocks.append((geo_pred + amb - cmb.phase_if_m, H_phase, var, usable, KIND_PHASE))
    if cfg.mode == "ic_ppp":
        iono = gnss_est[layout.sl("iono")]
        dcb = gnss_est[layout.i("dcb")]
        H_iono = _per_slot(layout, "iono", jnp.ones(S))
        # With the clock absorbing the IF receiver code bias, P1 keeps beta DCB and P2 -alpha
        # DCB (DCB = b1 - b2); phase receiver biases are absorbed by the ambiguities.
        ones = jnp.ones(S)
        for band, coef, dcb_coef in ((0, ones, cmb.beta), (1, cmb.gamma, -cmb.alpha)):
            pred = geo_pred + coef * iono + dcb_coef * dcb
            H = H_common + H_iono * coef[:, None] + _column(layout, "dcb", S, dcb_coef)
            var = code_sigma**2 + prod
            blocks.append((pred - cmb.code_corr_m[:, band], H, var, usable, KIND_CODE))
        for band, coef, amb_name in ((0, ones, "amb1"), (1, cmb.gamma, "amb2")):
            amb = gnss_est[layout.sl(amb_name)]
            pred = geo_pred - coef * iono + amb
            H = H_common - H_iono * coef[:, None] + _per_slot(layout, amb_name, ones)
            var = phase_sigma**2 + prod
            blocks.append((pred - obs.phase_m[:, band], H, var, usable, KIND_PHASE))
    if cfg.doppler:
        drift = _block_value(layout, gnss_est, "clock_drift")
        pred = geo.range_rate_m_s + drift - obs.sat.clock_rate_m_s
        H = u_pos @ rx.J_vel + _column(layout, "clock_drift", S)
        var = (cfg.doppler_sigma_m_s * sig_scale) ** 2
        blocks.append((pred - obs.range_rate_m_s, H, var, usable, KIND_DOPPLER))

    if cfg.bssd:
        ref = _reference_slot(slots, el, usable)
        diffed = []
        for dz, H, var, mask, kind in blocks:
            dz, H, R, mask = _difference(dz, H, var, mask, ref)
            diffed.append((dz, H, R, mask, kind))
    else:
        diffed = [(dz, H, jnp.diag(var), mask, kind) for dz, H, var, mask, kind in blocks]

    if cfg.mode == "ic_ppp" and cfg.iono_constraint == "epoch":
        # Model (GIM / broadcast) pseudo-observation of each slant ionosphere, S001 eqs 6-7 (its
        # local-time/latitude term folded into the residual model above; SEED_SPEC 2.5).
        iono = gnss_est[layout.sl("iono")]
        diffed.append(
            (
                iono - obs.iono_model_l1_m,
                _per_slot(layout, "iono", jnp.ones(S)),
                jnp.diag(iono_var),
                usable,
                KIND_IONO,
            )
        )

    dz = jnp.concatenate([b[0] for b in diffed])
    H = jnp.concatenate([b[1] for b in diffed])
    R = jnp.zeros((dz.shape[0], dz.shape[0]))
    offset = 0
    for b in diffed:
        R = R.at[offset : offset + S, offset : offset + S].set(b[2])
        offset += S
    mask = jnp.concatenate([b[3] for b in diffed])
    slot = jnp.tile(jnp.arange(S), len(diffed))
    kind = jnp.concatenate([jnp.full(S, b[4]) for b in diffed])
    return Rows(dz, H, R, mask, slot, kind), el
