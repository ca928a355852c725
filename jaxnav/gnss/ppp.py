"""PPP measurement models: the GNSS error states, their dynamics, and the rows of an epoch.

One configuration (:class:`PppConfig`) selects the flavour by name; the flavours themselves are
classes in ``gnss/modes/`` (one module each, behind ``modes.base.AbstractPppMode``; the registry
``gnss/modes/__init__.py`` lists them: ``sf_code``, ``df_code``, ``sdf_code``, ``float_ppp``,
``ic_ppp``). This module assembles what every mode shares: the receiver clock, inter-system
biases for GLONASS and Galileo (S002, S004) and a zenith wet delay, the geometry, troposphere and
weights, Doppler rows, and between-satellite single differences (S004) as an option. The same
epoch step in ``filter/tight.py`` uses the returned (residual, H, R, mask) for any mode.

Conventions: residual dz = h(x_hat) - z, H = dh/dx (core/states.py). The GNSS states hold
totals in ``gnss_est`` (a vector in the GNSS part of the layout) and errors in the filter's x.
All per-slot arrays are [S]; masks select what is used.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from jaxnav import geodesy
from jaxnav.core.states import StateLayout
from jaxnav.gnss import corrections, models, signals
from jaxnav.gnss import modes as ppp_modes
from jaxnav.gnss.modes.base import RowContext, column, iono_model_var
from jaxnav.gnss.modes.ic_ppp import iono_rw_sigma
from jaxnav.gnss.modes.sdf_code import hatch_update
from jaxnav.gnss.ppp_data import (
    KIND_CODE,
    KIND_DOPPLER,
    KIND_IONO,
    KIND_PHASE,
    Combos,
    GnssObs,
    HatchState,
    Receiver,
    Rows,
    SlotInfo,
    combos,
)

#: Re-exported for callers that use ``ppp.<name>`` (they live in ppp_data and the modes).
__all__ = [
    "KIND_CODE", "KIND_DOPPLER", "KIND_IONO", "KIND_PHASE", "Combos", "GnssObs", "HatchState",
    "PppConfig", "Receiver", "Rows", "SlotInfo", "combos", "gnss_blocks", "gnss_dynamics",
    "gnss_nominal_predict",
    "gnss_initial_std", "hatch_update", "iono_model_var", "iono_rw_sigma", "measurement_rows",
    "slot_state_resets",
]

_CLOCK_H0 = 2.0e-19  # S001 eq 16 (Brown & Hwang), white frequency noise
_CLOCK_H_M2 = 2.0e-20  # random-walk frequency noise
_CLOCK_K = 4.0  # S001's empirical inflation
_SQRT_H = 60.0  # sqrt(3600 s): converts "per sqrt(hour)" to "per sqrt(second)"
#: Receiver-clock bias PSD [m^2/s] on recorded data (chosen): 1e4 m^2/s is a 550 m 1-sigma step
#: per 30 s epoch, i.e. white noise for practical purposes (S002 §5.2.2), yet far from float64
#: trouble. ``io/prepare.py`` removes the single-point clock first, so what is left is a
#: metre-level residual that changes freely from epoch to epoch.
RECORDED_CLOCK_PSD_M2_S = 1.0e4
#: White zenith sigma [m] of one raw code on recorded data (issue 16). The simulator's 0.2 m
#: P-code noise plus its 30-s multipath leaves a real receiver's slow code errors out: ESBC's
#: code-minus-carrier keeps ~4 % of its variance correlated beyond 20 min
#: (experiments/esbc_multipath_calibration.py), and no antenna phase-centre model is applied
#: (docs/validation.md), which leaves per-satellite errors varying over a pass. Chosen from
#: ESBC's kinematic dual-frequency run against the ITRF coordinate (24 h, mean (error /
#: sigma)^2 E, N, U): 14.7, 3.8, 2.8 at 0.2 m; 5.6, 1.5, 1.4 at 0.5 m; 1.75, 0.56, 0.99 at 1.0 m.
#: A calibration on the one station we have, not a property of every receiver.
RECORDED_CODE_SIGMA_M = 1.0


class PppConfig(eqx.Module):
    """A PPP flavour and its stochastic model. Every number states its source."""

    mode: str = eqx.field(static=True, default="float_ppp")
    systems: tuple[int, ...] = eqx.field(static=True, default=(signals.SYS_GPS,))
    n_slots: int = eqx.field(static=True, default=16)
    doppler: bool = eqx.field(static=True, default=True)
    estimate_zwd: bool = eqx.field(static=True, default=True)
    bssd: bool = eqx.field(static=True, default=False)
    # Stochastic model of the raw observables: white noise plus multipath, both with S001 eq 11's
    # elevation law, and the products' residuals. Each error a filter cannot follow as a state
    # enters the rows with its white-equivalent variance (``models.white_equivalent_var``: the
    # same low-frequency power at the update interval), so that the filter's long averages are
    # as uncertain as the correlated errors make them (issue 16: before, a white 0.5 m code and a
    # white 3 cm product term, position NEES 7-32 in the realistic simulator).
    code_sigma_m: float = 0.2  # white, zenith: S001 eq 11 (P1/P2; also Galileo E1/E5a)
    sf_code_sigma_m: float = 0.3  # white, zenith, C/A code of the single-frequency modes: chosen
    phase_sigma_m: float = 0.002  # white, zenith: S001 eq 11
    doppler_sigma_m_s: float = 0.1  # S001 eq 11
    # Multipath: first-order Gauss-Markov per band (zenith sigma with the elevation law, tau).
    # Code sigma from the ESBC code-minus-carrier calibration (docs/simulation.md); tau chosen
    # for a moving antenna (a static one decorrelates over minutes); phase: code / 100 (S002).
    multipath_code_sigma_m: float = 0.2
    multipath_phase_sigma_m: float = 0.002
    multipath_tau_s: float = 30.0
    glonass_code_factor: float = 3.0  # S002
    glonass_phase_factor: float = 1.5  # S002
    # Ionosphere model residual (SF rows and IC-PPP pseudo-observations): 1-sigma =
    # sqrt((fraction * model)^2 + floor^2). Chosen: a broadcast (Klobuchar) model leaves 30-50 %
    # (the simulator leaves 30 %); a GIM ~ 2 TECU (0.3 m at L1, S001 eq 7 sigma_ion,0).
    iono_model_residual_fraction: float = 0.3
    iono_model_residual_floor_m: float = 0.3
    # Its correlation time: sf_code's per-slot residual state is first-order Gauss-Markov with
    # it (chosen: the model's errors follow the ionosphere's tens-of-minutes structures).
    iono_model_residual_tau_s: float = 1800.0
    # Precise-product residuals (truth - product), first-order Gauss-Markov per satellite,
    # common to its code and phase: IGS final orbits ~2.5 cm per axis (so along any line of
    # sight) and clocks ~75 ps RMS (2.2 cm); correlation times chosen (an orbit arc, a clock
    # session). Phase rows: a random walk on the ambiguity with the processes' PSD
    # 2 sigma^2 / tau (their drift over a pass; the constant part is the ambiguity's); code rows:
    # the white sigma^2 (negligible beside the code's multipath).
    orbit_sigma_m: float = 0.025
    orbit_tau_s: float = 3600.0
    sat_clock_sigma_m: float = 0.02
    sat_clock_tau_s: float = 1800.0
    hatch_window: int = eqx.field(static=True, default=100)  # chosen: 100 epochs (S000: silent)
    elevation_mask_rad: float = 0.17453292519943295  # 10 deg (S000 QC mask; S002 used 7 deg)
    prefit_code_m: float = 20.0  # S002: coarse pre-fit threshold for code
    gate_chi2: float = 25.0  # chosen: 5-sigma innovation gate (normalised by H P H^T + R)
    # S002: normalised post-fit residual threshold. None: no post-fit test (one update per
    # epoch instead of two; roofline.py measures what the second update costs).
    postfit_sigma: float | None = 3.0
    # post-fit passes: each removes the worst outlier and redoes the update (S002 5.3 repeats
    # the test until none is left; 2 bounds the cost: chosen)
    postfit_passes: int = eqx.field(static=True, default=2)
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
        ppp_modes.get(self.mode).check(self)  # the name is registered, the mode can run this
        if self.iono_constraint not in ("prior", "epoch"):
            raise ValueError(
                f"iono_constraint = {self.iono_constraint!r}: expected 'prior' or 'epoch'"
            )

    def for_recorded_data(self) -> PppConfig:
        """This configuration with the receiver clock and code noise of recorded data
        (``RECORDED_CLOCK_PSD_M2_S``, ``RECORDED_CODE_SIGMA_M``: ``jaxnav ppp`` and the replay
        source, whose observations come from a real receiver)."""
        return dataclasses.replace(
            self,
            clock_bias_psd_m2_s=RECORDED_CLOCK_PSD_M2_S,
            code_sigma_m=RECORDED_CODE_SIGMA_M,
            sf_code_sigma_m=RECORDED_CODE_SIGMA_M,
        )

    @property
    def model(self) -> ppp_modes.AbstractPppMode:
        """The mode's class instance (rows, blocks, resets: ``gnss/modes/``)."""
        return ppp_modes.get(self.mode)

    @property
    def uses_phase(self) -> bool:
        return self.model.uses_phase

    def zenith_sigmas(self, epoch_dt_s: Float[ArrayLike, ""]
                      ) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Zenith sigmas [m] of one raw code and one raw phase per update every ``epoch_dt_s``:
        sqrt(white^2 + white-equivalent multipath variance) (``models.white_equivalent_var``)."""
        white = self.sf_code_sigma_m if self.model.single_frequency else self.code_sigma_m
        code = white**2 + models.white_equivalent_var(
            self.multipath_code_sigma_m, self.multipath_tau_s, epoch_dt_s)
        phase = self.phase_sigma_m**2 + models.white_equivalent_var(
            self.multipath_phase_sigma_m, self.multipath_tau_s, epoch_dt_s)
        return jnp.sqrt(code), jnp.sqrt(phase)

    @property
    def product_var_m2(self) -> Float[ArrayLike, ""]:
        """Variance of the products' residual on one line of sight: orbit^2 + clock^2."""
        return self.orbit_sigma_m**2 + self.sat_clock_sigma_m**2

    @property
    def ambiguity_psd_m2_s(self) -> Float[ArrayLike, ""]:
        """Random-walk PSD on a carrier ambiguity that follows the products' residual over a
        pass: 2 sigma^2 / tau of each first-order Gauss-Markov process (its low-lag increments)."""
        return (2.0 * self.orbit_sigma_m**2 / self.orbit_tau_s
                + 2.0 * self.sat_clock_sigma_m**2 / self.sat_clock_tau_s)


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
    blocks += [(b.name, S if b.per_slot else 1) for b in cfg.model.blocks]
    return tuple(blocks)


def gnss_dynamics(
    cfg: PppConfig, layout: StateLayout, elevation_rad: Float[Array, " S"], obs: GnssObs,
    skip=()
) -> tuple[Float[Array, "n n"], Float[Array, " n"]]:
    """Continuous F and diagonal process-noise PSD q (n-vector) of the GNSS blocks in ``layout``.

    Clock: bias' = drift, PSDs of S001 eq 16; ISB and ZWD: random walks; carrier ambiguities:
    random walks of ``PppConfig.ambiguity_psd_m2_s`` (the products' residual); blocks with a
    correlation time: x' = -x / tau; the rest of the mode's blocks as its ``process_noise``
    says (from the epoch's observations ``obs``). Blocks absent from ``layout`` or named in
    ``skip`` (modelled by the navigation system, e.g. the clock of seed 000's 16-state RISS)
    are left zero.
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
    for b in cfg.model.blocks:
        if not layout.has(b.name):
            continue
        if b.ambiguity:
            q = q.at[layout.sl(b.name)].set(cfg.ambiguity_psd_m2_s)
        if b.tau is not None:
            idx = jnp.arange(layout.sl(b.name).start, layout.sl(b.name).stop)
            F = F.at[idx, idx].set(-1.0 / getattr(cfg, b.tau))
    q = cfg.model.process_noise(cfg, layout, elevation_rad, q, obs)
    return F, q


def gnss_nominal_predict(cfg: PppConfig, layout: StateLayout, gnss_est: Float[Array, " n"],
                         dt_s: Float[ArrayLike, ""]) -> Float[Array, " n"]:
    """x_hat <- Phi x_hat of the GNSS totals over dt: clock bias += drift dt, and the blocks
    with a correlation time decay as exp(-dt / tau) (the other states are random walks)."""
    if layout.has("clock_bias"):
        drift = gnss_est[layout.i("clock_drift")]
        gnss_est = gnss_est.at[layout.i("clock_bias")].add(drift * dt_s)
    for b in cfg.model.blocks:
        if b.tau is not None and layout.has(b.name):
            sl = layout.sl(b.name)
            gnss_est = gnss_est.at[sl].multiply(jnp.exp(-dt_s / getattr(cfg, b.tau)))
    return gnss_est


def gnss_initial_std(cfg: PppConfig, layout: StateLayout) -> Float[Array, " n"]:
    """Initial standard deviations of the GNSS blocks (zeros elsewhere)."""
    std = jnp.zeros(layout.size)
    init = {
        "clock_bias": cfg.clock_init_sigma_m,
        "clock_drift": cfg.clock_drift_init_sigma_m_s,
        "isb_glo": cfg.isb_init_sigma_m,
        "isb_gal": cfg.isb_init_sigma_m,
        "zwd": cfg.zwd_init_sigma_m,
        **{b.name: getattr(cfg, b.init_sigma) for b in cfg.model.blocks},
    }
    for name, sigma in init.items():
        if layout.has(name):
            std = std.at[layout.sl(name)].set(sigma)
    return std


def slot_state_resets(
    cfg: PppConfig, layout: StateLayout, reset_slot: Bool[Array, " S"], variances=None
) -> tuple[Bool[Array, " n"], Float[Array, " n"]]:
    """Per-state reset flags and variances for slots that rose, slipped or returned ([S] bool).

    The variances are the initial ones of ``gnss_initial_std`` on the mode's per-slot blocks,
    except the blocks named in ``variances`` ({name: [S]}, the mode's ``reset_variance``: e.g.
    IC-PPP's slant ionosphere at the model's variance).
    """
    flags = jnp.zeros(layout.size, bool)
    in_block = jnp.zeros(layout.size, bool)
    for b in cfg.model.blocks:
        if b.per_slot and layout.has(b.name):
            flags = flags.at[layout.sl(b.name)].set(reset_slot)
            in_block = in_block.at[layout.sl(b.name)].set(True)
    var = jnp.where(in_block, gnss_initial_std(cfg, layout) ** 2, 0.0)
    for name, v in (variances or {}).items():
        if layout.has(name):
            var = var.at[layout.sl(name)].set(v)
    return flags, var


def _block_value(layout, gnss_est, name, default=0.0):
    return gnss_est[layout.i(name)] if layout.has(name) else jnp.asarray(default)


def slot_usable(cfg: PppConfig, obs: GnssObs, keep: Bool[Array, " S"],
                elevation: Float[Array, " S"]) -> Bool[Array, " S"]:
    """Slots whose rows may enter: tracked, kept by the study, above the elevation mask, and with
    the model ionosphere where the mode needs it (a missing model is never a zero delay)."""
    model_ok = obs.iono_model_ok | (not cfg.model.uses_iono_model)
    return obs.available & keep & (elevation >= cfg.elevation_mask_rad) & model_ok


def reference_slot(slots: SlotInfo, elevation: Float[Array, " S"],
                   usable: Bool[Array, " S"]) -> Int[Array, ""]:
    """Highest-elevation usable GPS slot (S004 uses a GPS reference satellite)."""
    score = jnp.where(usable & (slots.system == signals.SYS_GPS), elevation, -10.0)
    return jnp.argmax(score)


def _difference(
    dz: Float[Array, " S"],
    H: Float[Array, "S n"],
    var: Float[Array, " S"],
    mask: Bool[Array, " S"],
    ref: Int[Array, ""],
) -> tuple[Float[Array, " S"], Float[Array, "S n"], Float[Array, "S S"], Bool[Array, " S"]]:
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
    gnss_est: Float[Array, " n"],
    outage_keep: Bool[Array, " S"],
    hatch: HatchState,
    day_of_year: Real[ArrayLike, ""],
    epoch_dt_s: Float[ArrayLike, ""],
) -> tuple[Rows, Float[Array, " S"]]:
    """All rows of the configured mode at one epoch, and the per-slot elevation [rad].

    ``outage_keep`` [S] bool is the study's availability mask (False = withheld). Rows of one
    kind are blocks of S (code, then phase, then Doppler, then ionosphere pseudo-observations).
    ``epoch_dt_s``: the update interval, which sets the white-equivalent variance of multipath.
    """
    S = cfg.n_slots
    geo = models.geometry(rx.pos_ecef, rx.vel_ecef, obs.sat)
    C_e_l = geodesy.C_l_e(rx.llh[0], rx.llh[1]).T
    el, az = models.elevation_azimuth(geo.los_ecef, C_e_l)
    usable = slot_usable(cfg, obs, outage_keep, el)

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
    H_common = H_geo + column(layout, "clock_bias", S)
    for sys, name in _ISB_BLOCK.items():
        if layout.has(name):
            H_common = H_common + column(layout, name, S, (slots.system == sys).astype(float))
    if layout.has("zwd"):
        H_common = H_common + column(layout, "zwd", S, m_w)

    cmb = combos(slots, obs)
    sig_scale = models.elevation_sigma(1.0, el)
    glo = slots.system == signals.SYS_GLO
    code_zenith, phase_zenith = cfg.zenith_sigmas(epoch_dt_s)
    code_sigma = code_zenith * jnp.where(glo, cfg.glonass_code_factor, 1.0) * sig_scale
    phase_sigma = phase_zenith * jnp.where(glo, cfg.glonass_phase_factor, 1.0) * sig_scale
    if_noise = jnp.sqrt(cmb.alpha**2 + cmb.beta**2)
    geo_pred = geo.range_m + rx_clock + trop

    ctx = RowContext(
        layout=layout,
        gnss_est=gnss_est,
        obs=obs,
        cmb=cmb,
        hatch=hatch,
        usable=usable,
        geo_pred=geo_pred,
        H_common=H_common,
        code_sigma=code_sigma,
        phase_sigma=phase_sigma,
        if_noise=if_noise,
        iono_var=iono_model_var(cfg, obs.iono_model_l1_m, el),
        product_var=cfg.product_var_m2,  # not amplified by the IF combination: added after
    )
    mode = cfg.model
    blocks = [tuple(b) for b in mode.rows(cfg, ctx)]  # (dz, H, var, mask, kind)
    if cfg.doppler:
        drift = _block_value(layout, gnss_est, "clock_drift")
        pred = geo.range_rate_m_s + drift - obs.sat.clock_rate_m_s
        H = u_pos @ rx.J_vel + column(layout, "clock_drift", S)
        var = (cfg.doppler_sigma_m_s * sig_scale) ** 2
        blocks.append((pred - obs.range_rate_m_s, H, var, usable & obs.doppler_ok, KIND_DOPPLER))

    if cfg.bssd:
        ref = reference_slot(slots, el, usable)
        # Doppler rows are uncorrelated with code and phase and lose the clock drift against any
        # reference: their own one where the main reference has no Doppler (else none is used).
        ref_doppler = jnp.where(
            obs.doppler_ok[ref], ref, reference_slot(slots, el, usable & obs.doppler_ok)
        )
        diffed = []
        for dz, H, var, mask, kind in blocks:
            r = ref_doppler if kind == KIND_DOPPLER else ref
            dz, H, R, mask = _difference(dz, H, var, mask, r)
            diffed.append((dz, H, R, mask, kind))
    else:
        diffed = [(dz, H, jnp.diag(var), mask, kind) for dz, H, var, mask, kind in blocks]

    # Rows of a state's pseudo-observation (IC-PPP's ionosphere) are never differenced.
    diffed += [(b.dz, b.H, jnp.diag(b.var), b.mask, b.kind) for b in mode.pseudo_rows(cfg, ctx)]

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
