"""Tightly coupled PPP/INS and PPP/RISS: one GNSS epoch = mechanize, propagate, update, feed back.

Two rates, nested scans (DESIGN invariant 4): ``epoch_step`` runs the IMU-rate mechanization over
the epoch's samples (inner ``lax.scan`` in the system), then covariance propagation, the masked
update with every row of the configured PPP mode, and closed-loop feedback. ``run`` scans it over
the epochs. Everything is a pure function of (carry, inputs), so a batch of scenarios is a
``jax.vmap`` of ``run`` and an outage is only a mask (``EpochInput.keep``).

Outlier control (S002 §5.3): a coarse pre-fit test on code residuals (after removing their
common median, so a clock jump or a drift after an outage is not mistaken for an outlier), a
chi-square gate on each innovation, and a normalised post-fit residual test (covariance
R - H P+ H^T), repeated ``postfit_passes`` times: when the worst used row exceeds
``postfit_sigma``, it is removed (a code row takes every row of its satellite with it, as S002
rejects the same satellite's phase and Doppler with its code) and the rows left are tested
again; the satellite's ambiguity is kept (an outlier is not a slip).

Optional non-holonomic constraint (full-IMU ``InsSystem`` only; ``TightFilter.nhc_sigma_m_s``,
off by default, and then the step is unchanged): the two NHC rows of
``filter.constraints.nhc_rows`` (lateral and vertical body velocity of the IMU = 0, S003 eq 8 /
S002 eq 4.27-4.29 corrected), linearised at the predicted state, join the GNSS rows in the same
masked update (one ``core.rows.Rows`` type). They are not gated and not tested post-fit (a
vehicle model, not an observation); the epoch's NIS and dof include them.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxnav import geodesy
from jaxnav.core import rows as core_rows
from jaxnav.core.states import StateLayout
from jaxnav.filter import constraints, ekf, smoother
from jaxnav.filter.systems import AbstractNavSystem, NavSigmas, nav_block_size  # noqa: F401  (re-exported)
from jaxnav.gnss import corrections, models, ppp
from jaxnav.gnss.ppp_data import EpochInput  # noqa: F401  (the filter's input, re-exported)


class TightFilter(eqx.Module):
    """A navigation system coupled with a PPP configuration (both static in shape)."""

    system: AbstractNavSystem
    cfg: ppp.PppConfig
    slots: ppp.SlotInfo
    imu_dt_s: float
    epoch_dt_s: float
    # NHC noise [m/s] (S003: 1 m/s); None = no NHC (module docstring). InsSystem only.
    nhc_sigma_m_s: float | None = eqx.field(static=True, default=None)
    # Covariance steps per GNSS epoch: 1 = one Phi, Qd over the epoch from its end state and
    # mean inputs (the seeds' 1-Hz form); n > 1 mechanizes the epoch's samples in n equal
    # pieces and re-linearises F after each (long epochs, e.g. 30-s recorded data, where the
    # vehicle turns a corner within one epoch). The samples per epoch must divide by n.
    covariance_steps: int = eqx.field(static=True, default=1)

    @property
    def layout(self) -> StateLayout:
        have_clock = self.system.layout.has("clock_bias")
        return self.system.layout.extend(*ppp.gnss_blocks(self.cfg, have_clock))


class Carry(NamedTuple):
    """Filter memory between epochs."""

    nav: Any  # system navigation state
    sensors: Any  # system sensor-error estimates
    gnss_est: Float[Array, " n"]  # totals of the GNSS states (other entries unused)
    P: Float[Array, "n n"]  # error covariance
    hatch: ppp.HatchState
    tracked: Bool[Array, " S"]  # slot used (phase continuous) at the previous epoch
    elevation: Float[Array, " S"]  # previous elevations (for the ionosphere random walk)


class EpochOutput(NamedTuple):
    """Per-epoch solution and diagnostics."""

    llh: Float[Array, "3"]  # navigation (IMU) position
    vel_enu: Float[Array, "3"]
    euler: Float[Array, "3"]  # roll, pitch, azimuth
    P_nav: Float[Array, "k k"]  # covariance of the navigation block (pos, vel, attitude)
    nis: Float[Array, ""]  # normalised innovation squared of the used rows
    dof: Int[Array, ""]  # number of used rows
    logdet: Float[Array, ""]  # log det of the used rows' innovation covariance (filter/tune.py)
    n_sat: Int[Array, ""]  # slots with at least one used row
    used_by_kind: Int[Array, "4"]  # used rows per kind (code, phase, Doppler, ionosphere)
    gated_by_kind: Int[Array, "4"]  # offered rows rejected by the gates / outlier tests
    clock_bias_m: Float[ArrayLike, ""]


def initial_carry(
    tf: TightFilter, nav0, obs0: ppp.GnssObs, sigmas: NavSigmas | None = None, sensors0=None
) -> Carry:
    """Start from a navigation state (e.g. GNSS-initialised) and the first epoch's code.

    The receiver clock starts at the median code residual (0 if the epoch has no code: the
    first epoch with data then re-levels it, see ``_clock_jump``); per-slot states start on the
    slots' first use (``tracked`` all false). ``sensors0``: initial sensor-error estimates
    (e.g. from ``system.calibrate_static``); zero by default.
    """
    sigmas = NavSigmas() if sigmas is None else sigmas
    layout = tf.layout
    sensors = tf.system.zero_sensors() if sensors0 is None else sensors0
    std = jnp.zeros(layout.size)
    std = std.at[: tf.system.layout.size].set(tf.system.initial_std(nav0, sigmas))
    gstd = ppp.gnss_initial_std(tf.cfg, layout)
    std = jnp.where(jnp.arange(layout.size) >= tf.system.layout.size, gstd, std)
    if tf.system.layout.has("clock_bias"):
        std = std.at[layout.i("clock_bias")].set(tf.cfg.clock_init_sigma_m)
        std = std.at[layout.i("clock_drift")].set(tf.cfg.clock_drift_init_sigma_m_s)
    gnss_est = jnp.zeros(layout.size)
    if layout.has("zwd"):
        llh = tf.system.llh(nav0)
        gnss_est = gnss_est.at[layout.i("zwd")].set(corrections.saastamoinen_zwd_m(llh[2]))
    if layout.has("clock_bias"):
        rx = tf.system.antenna(nav0, tf.system.idle_inputs(nav0), sensors, layout)
        geo = models.geometry(rx.pos_ecef, rx.vel_ecef, obs0.sat)
        cmb = ppp.combos(tf.slots, obs0)
        code = tf.cfg.model.clock_code(cmb)
        resid = jnp.where(obs0.available, code - geo.range_m + obs0.sat.clock_m, jnp.nan)
        gnss_est = gnss_est.at[layout.i("clock_bias")].set(jnp.nan_to_num(jnp.nanmedian(resid)))
    S = tf.cfg.n_slots
    return Carry(
        nav=nav0,
        sensors=sensors,
        gnss_est=gnss_est,
        P=jnp.diag(std**2),
        hatch=ppp.HatchState.empty(S),
        tracked=jnp.zeros(S, bool),
        elevation=jnp.full(S, jnp.pi / 2),
    )


def _propagate_covariance(
    tf: TightFilter, layout: StateLayout, carry: Carry, nav, mean_inputs, obs: ppp.GnssObs,
    dt_s: Float[ArrayLike, ""] | None = None, with_phi: bool = False,
) -> Float[Array, "n n"] | tuple[Float[Array, "n n"], Float[Array, "n n"]]:
    """P <- Phi P Phi^T + Qd for the joint navigation + GNSS error model over ``dt_s`` (default:
    the epoch).

    The two blocks are independent (no F or noise couples them) and discretised apart: the
    system's by ``ekf.discretize`` with its squarings (RISS16's Gauss-Markov velocity terms have
    beta dt = 1), the GNSS block's (clock bias' = drift, random walks) exactly by its
    third-order series alone (nilpotent but for the slow Gauss-Markov blocks, |F dt| << 1).
    ``obs``: the epoch's observations, for process noise that scales with a model (sf_code's
    ionosphere residual). ``with_phi``: return (P, Phi) (the smoother's record)."""
    dt_s = tf.epoch_dt_s if dt_s is None else dt_s
    n_sys = tf.system.layout.size
    n = layout.size
    F_sys, G_sys, Qc_sys = tf.system.dynamics(nav, mean_inputs, carry.sensors)
    F_g, q_g = ppp.gnss_dynamics(tf.cfg, layout, carry.elevation, obs,
                                 skip=tf.system.layout.names)
    Phi_s, Qd_s = ekf.discretize(F_sys, G_sys, Qc_sys, dt_s)
    Phi_g, Qd_g = ekf.discretize(F_g[n_sys:, n_sys:], jnp.eye(n - n_sys), jnp.diag(q_g[n_sys:]),
                                 dt_s, squarings=0)
    Phi = jax.scipy.linalg.block_diag(Phi_s, Phi_g)
    Qd = jax.scipy.linalg.block_diag(Qd_s, Qd_g)
    _, P = ekf.predict(jnp.zeros(n), carry.P, Phi, Qd)
    return (P, Phi) if with_phi else P


def _mechanize_and_propagate(tf: TightFilter, layout: StateLayout, carry: Carry,
                             inp: EpochInput, record: bool = False):
    """The epoch's mechanization and P <- Phi P Phi^T + Qd, in ``tf.covariance_steps`` pieces
    (P_{j+1} = Phi_j P_j Phi_j^T + Qd_j, F_j at the state mechanized to the end of piece j).
    Returns (nav, mean inputs, P, Phi): Phi the product of the pieces' with ``record``, else
    None."""
    n = tf.covariance_steps
    if n == 1:
        nav, mean = tf.system.propagate(carry.nav, carry.sensors, inp.samples, tf.imu_dt_s)
        if record:
            return nav, mean, *_propagate_covariance(tf, layout, carry, nav, mean, inp.obs,
                                                     with_phi=True)
        return nav, mean, _propagate_covariance(tf, layout, carry, nav, mean, inp.obs), None
    pieces = jax.tree.map(lambda x: x.reshape(n, x.shape[0] // n, *x.shape[1:]), inp.samples)

    def piece(state, samples):
        c, Phi = state
        nav, mean = tf.system.propagate(c.nav, c.sensors, samples, tf.imu_dt_s)
        if record:
            P, Phi_j = _propagate_covariance(tf, layout, c, nav, mean, inp.obs,
                                             tf.epoch_dt_s / n, with_phi=True)
            Phi = Phi_j @ Phi
        else:
            P = _propagate_covariance(tf, layout, c, nav, mean, inp.obs, tf.epoch_dt_s / n)
        return (c._replace(nav=nav, P=P), Phi), mean

    Phi0 = jnp.eye(layout.size) if record else None
    (c, Phi), means = jax.lax.scan(piece, (carry, Phi0), pieces)
    return c.nav, jax.tree.map(lambda x: x[-1], means), c.P, Phi


def _slot_usable(
    tf: TightFilter, rx: ppp.Receiver, obs: ppp.GnssObs, keep: Bool[Array, " S"]
) -> tuple[Bool[Array, " S"], Float[Array, " S"]]:
    geo = models.geometry(rx.pos_ecef, rx.vel_ecef, obs.sat)
    C_e_l = geodesy.C_l_e(rx.llh[0], rx.llh[1]).T
    el, _ = models.elevation_azimuth(geo.los_ecef, C_e_l)
    return ppp.slot_usable(tf.cfg, obs, keep, el), el


def _reset_slots(
    tf: TightFilter,
    layout: StateLayout,
    gnss_est: Float[Array, " n"],
    P: Float[Array, "n n"],
    obs: ppp.GnssObs,
    restart: Bool[Array, " S"],
    el: Float[Array, " S"],
    return_flags: bool = False,
):
    """Re-initialise the mode's per-slot states (ambiguities, slant ionosphere) of restarted
    slots: variances from the mode's ``reset_variance`` or the initial ones, values from its
    ``reset_values`` (e.g. an ambiguity from phase minus code). Returns (gnss_est, P), and the
    [n] reset flags with ``return_flags``."""
    cfg = tf.cfg
    mode = cfg.model
    flags, var = ppp.slot_state_resets(cfg, layout, restart, mode.reset_variance(cfg, obs, el))
    _, P = ekf.reset_states(jnp.zeros(layout.size), P, flags, var)
    cmb = ppp.combos(tf.slots, obs)
    gnss_est = mode.reset_values(cfg, layout, obs, cmb, restart, gnss_est)
    return (gnss_est, P, flags) if return_flags else (gnss_est, P)


#: The pre-fit test never leaves fewer code satellites than this (position + receiver clock).
MIN_PREFIT_SATELLITES = 4


def _prefit_mask(cfg: ppp.PppConfig, rows: ppp.Rows) -> Bool[Array, " m"]:
    """Coarse pre-fit test on code rows: |dz - median(dz_code)| <= prefit_code_m (S002: 20 m).

    Lock-out guard (chosen): when the test would leave fewer than ``MIN_PREFIT_SATELLITES`` of
    at least that many code satellites, it is skipped for the epoch and the chi-square gate,
    which scales with the predicted covariance, decides alone. Otherwise a filter whose
    prediction drifted far during a long outage (a PPP-only constant-velocity filter after 3
    minutes: ~1 km) sees satellite-dependent residuals of hundreds of metres, rejects them all
    and never fixes again (seed002 LC study, measured before the guard)."""
    is_code = (rows.kind == ppp.KIND_CODE) & rows.mask
    med = jnp.nanmedian(jnp.where(is_code, rows.dz, jnp.nan))
    bad = is_code & (jnp.abs(rows.dz - jnp.nan_to_num(med)) > cfg.prefit_code_m)
    bad_slot = jnp.zeros(cfg.n_slots, bool).at[rows.slot].max(bad)
    code_slot = jnp.zeros(cfg.n_slots, bool).at[rows.slot].max(is_code)
    lockout = (jnp.sum(code_slot) >= MIN_PREFIT_SATELLITES) & (
        jnp.sum(code_slot & ~bad_slot) < MIN_PREFIT_SATELLITES
    )
    bad_row = jnp.where(rows.slot >= 0, bad_slot[rows.slot], False)  # constraints: no slot
    return rows.mask & ~(bad_row & ~lockout)


def _clock_jump(
    cfg: ppp.PppConfig,
    layout: StateLayout,
    gnss_est: Float[Array, " n"],
    P: Float[Array, "n n"],
    rows: ppp.Rows,
) -> tuple[Float[Array, " n"], Float[Array, "n n"], ppp.Rows, Bool[Array, " n"]]:
    """Re-level the receiver clock when every code residual moved together by more than the
    pre-fit threshold (a millisecond clock jump, or a first epoch without data): the clock
    estimate takes the median code residual and its variance restarts, so the innovation gate
    cannot lock the filter out. Rows are linear in the clock, so dz is shifted, not recomputed.
    Returns (gnss_est, P, rows, reset flags [n]: the clock bias when it was re-levelled).
    """
    if not layout.has("clock_bias"):
        return gnss_est, P, rows, jnp.zeros(layout.size, bool)
    i = layout.i("clock_bias")
    is_code = (rows.kind == ppp.KIND_CODE) & rows.mask
    med = jnp.nan_to_num(jnp.nanmedian(jnp.where(is_code, rows.dz, jnp.nan)))
    jump = jnp.where(jnp.abs(med) > cfg.prefit_code_m, med, 0.0)
    gnss_est = gnss_est.at[i].add(-jump)
    dz = rows.dz - jump * rows.H[:, i]
    keep = jnp.arange(layout.size) != i
    P_reset = jnp.where(keep[:, None] & keep[None, :], P, 0.0).at[i, i].set(
        cfg.clock_init_sigma_m**2
    )
    return (gnss_est, jnp.where(jump != 0.0, P_reset, P), rows._replace(dz=dz),
            ~keep & (jump != 0.0))


def _update_with_postfit(
    cfg: ppp.PppConfig, P: Float[Array, "n n"], rows: ppp.Rows, mask: Bool[Array, " m"]
) -> tuple[ekf.UpdateResult, Bool[Array, " S"]]:
    """Masked update, with up to ``postfit_passes`` post-fit tests before it: if the worst
    normalised post-fit residual (``ekf.postfit_normalized``) exceeds the threshold, it is
    dropped and the rows left are tested again, as an update redone from the same prior would
    be. A code outlier drops every row of its satellite (S002 5.3: its phase and Doppler go with
    it); another row only itself. Returns the update and the slots whose rows were dropped
    (their ambiguities are kept: an outlier is not a slip).

    Cost (issue 19): H P and S are formed once; each test is an m x m Cholesky factorisation
    and solve, and only the final set of rows is applied to P (one Joseph update instead of
    one per pass; ``ekf.masked_update`` + ``ekf.normalized_residuals`` per pass are the
    reference it agrees with, tests/test_postfit_update.py)."""
    n = P.shape[0]
    x0 = jnp.zeros(n)
    # constraint rows are neither gated nor tested post-fit: they are a vehicle model, not an
    # observation that can be an outlier
    gnss = rows.kind != core_rows.KIND_CONSTRAINT
    gate = jnp.where(gnss, cfg.gate_chi2, jnp.inf)
    inn = ekf.innovations(x0, P, rows.dz, rows.H, rows.R, mask, gate)
    used = inn.offered
    dropped = jnp.zeros(cfg.n_slots, bool)
    if cfg.postfit_sigma is not None:  # decided at trace time: a None field has no leaves
        is_code = rows.kind == ppp.KIND_CODE
        for _ in range(cfg.postfit_passes):
            resid = ekf.postfit_normalized(inn, rows.R, used)
            score = jnp.where(used & gnss, jnp.abs(resid), 0.0)
            worst = jnp.argmax(score)
            reject = score[worst] > cfg.postfit_sigma
            drop = jnp.where(is_code[worst], rows.slot == rows.slot[worst],
                             jnp.arange(rows.dz.shape[0]) == worst) & gnss
            used = used & ~(drop & reject)
            dropped = dropped.at[rows.slot[worst]].max(reject & is_code[worst])
    return ekf.apply_update(x0, P, inn, rows.H, rows.R, used), dropped


def _nhc_rows(tf: TightFilter, layout: StateLayout, nav) -> core_rows.Rows:
    """The two NHC rows (module docstring) at the predicted state. The body rate at t_k is the
    last compensated sample's (as in ``loose``); the IMU is taken to be at the vehicle's
    no-slip point."""
    if not layout.has("att"):
        raise ValueError("the tight NHC update needs a full-IMU system (attitude states)")
    state, last = nav.state, nav.prev
    w_now_b = last.dtheta_b / tf.imu_dt_s
    return constraints.nhc_rows(
        layout, state.llh, state.vel_enu, state.C_b_l, w_now_b, jnp.zeros(3), tf.nhc_sigma_m_s
    )


def epoch_step(tf: TightFilter, carry: Carry, inp: EpochInput, record: bool = False):
    """One GNSS epoch: mechanize, propagate P, reset per-slot states, update, feed back.

    Returns (carry, EpochOutput), or with ``record`` (static) (carry, (EpochOutput,
    smoother.Record)) for the RTS smoother (``run_smoother``): Phi is the propagation's with
    the rows of the restarted per-slot states and of a re-levelled clock zero."""
    layout = tf.layout
    cfg = tf.cfg
    nav, mean_inputs, P, Phi = _mechanize_and_propagate(tf, layout, carry, inp, record)
    # x_hat <- Phi x_hat for the sensor estimates: Gauss-Markov shares decay (issue 16, defect 4)
    carry = carry._replace(sensors=tf.system.predict_sensors(carry.sensors, tf.epoch_dt_s))
    gnss_est = ppp.gnss_nominal_predict(cfg, layout, carry.gnss_est, tf.epoch_dt_s)

    rx = tf.system.antenna(nav, mean_inputs, carry.sensors, layout)
    usable, el = _slot_usable(tf, rx, inp.obs, inp.keep)
    restart = usable & (~carry.tracked | inp.obs.slip)
    # a slip restarts the carrier's states (and the Hatch window), not a code mode's ionosphere
    restart_states = restart if cfg.uses_phase else usable & ~carry.tracked
    gnss_est, P, reset = _reset_slots(tf, layout, gnss_est, P, inp.obs, restart_states, el,
                                      return_flags=True)
    hatch = cfg.model.update_memory(cfg, carry.hatch, ppp.combos(tf.slots, inp.obs), usable,
                                    restart)

    rows, _ = ppp.measurement_rows(
        cfg, layout, tf.slots, inp.obs, rx, gnss_est, inp.keep, hatch, inp.day_of_year,
        tf.epoch_dt_s,
    )
    if tf.nhc_sigma_m_s is not None:  # the constraint joins the same update (module docstring)
        rows = core_rows.stack_rows(rows, _nhc_rows(tf, layout, nav))
    gnss_est, P, rows, clock_reset = _clock_jump(cfg, layout, gnss_est, P, rows)
    if record:
        Phi = smoother.reset_rows(Phi, reset | clock_reset)
    mask = _prefit_mask(cfg, rows)
    res, dropped = _update_with_postfit(cfg, P, rows, mask)

    nav, sensors = tf.system.feedback(nav, carry.sensors, res.x, layout)
    gnss_est = gnss_est - jnp.where(jnp.arange(layout.size) >= tf.system.layout.size, res.x, 0.0)
    if tf.system.layout.has("clock_bias"):  # the system owns the clock: fold it in here too
        for name in ("clock_bias", "clock_drift"):
            gnss_est = gnss_est.at[layout.i(name)].add(-res.x[layout.i(name)])

    used_slot = jnp.zeros(cfg.n_slots, bool).at[rows.slot].max(res.used & (rows.slot >= 0))
    phase_used = (
        jnp.zeros(cfg.n_slots, bool).at[rows.slot].max(res.used & (rows.kind == ppp.KIND_PHASE))
    )
    if cfg.bssd:
        # Between-satellite differences have no row of the reference satellite, yet its
        # observations are in every differenced row: it is used (and its ambiguity tracked)
        # whenever any row is. Without this its ambiguity restarted every epoch (issue 16).
        ref = ppp.reference_slot(tf.slots, el, usable)
        used_slot = used_slot.at[ref].max(jnp.any(used_slot))
        phase_used = phase_used.at[ref].max(jnp.any(phase_used))
    # a satellite removed by the post-fit test keeps its ambiguity (not a slip)
    tracked = (phase_used | (dropped & carry.tracked & ~inp.obs.slip)) if cfg.uses_phase \
        else usable
    out = EpochOutput(
        llh=tf.system.llh(nav),
        vel_enu=tf.system.vel_enu(nav),
        euler=tf.system.euler(nav),
        P_nav=tf.system.nav_covariance(nav, res.P, layout),
        nis=res.nis,
        dof=res.dof,
        logdet=res.logdet,
        n_sat=jnp.sum(used_slot),
        # the GNSS kinds only (constraint rows, kind 4, are dropped from the counts)
        used_by_kind=jnp.zeros(core_rows.N_GNSS_KINDS, int).at[rows.kind].add(
            res.used.astype(int), mode="drop"),
        gated_by_kind=jnp.zeros(core_rows.N_GNSS_KINDS, int).at[rows.kind].add(
            (rows.mask & ~res.used).astype(int), mode="drop"),
        clock_bias_m=gnss_est[layout.i("clock_bias")] if layout.has("clock_bias") else 0.0,
    )
    el_mem = jnp.where(usable, el, carry.elevation)
    new = Carry(nav, sensors, gnss_est, res.P, hatch, tracked, el_mem)
    if record:
        return new, (out, smoother.Record(Phi, P, res.P, res.x, nav, sensors,
                                          jnp.zeros(layout.size)))
    return new, out


def run(tf: TightFilter, carry: Carry, inputs: EpochInput) -> tuple[Carry, EpochOutput]:
    """Scan ``epoch_step`` over stacked epochs; returns (final carry, stacked EpochOutput)."""
    return jax.lax.scan(lambda c, i: epoch_step(tf, c, i), carry, inputs)


def run_smoother(tf: TightFilter, carry: Carry, inputs: EpochInput, n_valid=None
                 ) -> tuple[EpochOutput, EpochOutput]:
    """Forward filter and RTS smoother (``jaxnav.filter.smoother``) over stacked epochs.

    Returns (forward EpochOutput, smoothed EpochOutput): the smoothed one has each epoch's
    forward nominal with the smoothed error fed back (``system.feedback``) and P_nav from P^s;
    its NIS, dof, row counts and clock are the forward pass's. Memory: 3 n^2 + O(n) float64 per
    epoch (n = navigation + GNSS states: 27.7 kB for INS15 + float PPP, n = 34 with the
    simulator's slots; 2.9 kB for RISS9 + DF code, n = 11).
    """
    _, (out, rec) = jax.lax.scan(lambda c, i: epoch_step(tf, c, i, record=True), carry, inputs)
    return out, smoothed_outputs(tf, out, rec, n_valid)


def smoothed_outputs(tf: TightFilter, out: EpochOutput, rec: smoother.Record,
                     n_valid=None) -> EpochOutput:
    """The forward outputs with the RTS-smoothed navigation states and covariances in place
    (``n_valid``: ``smoother.error_state``)."""
    layout = tf.layout
    dx_s, P_s = smoother.error_state(rec, n_valid)

    def one(nav, sensors, dx, P):
        nav_s, _ = tf.system.feedback(nav, sensors, dx, layout)
        return (tf.system.llh(nav_s), tf.system.vel_enu(nav_s), tf.system.euler(nav_s),
                tf.system.nav_covariance(nav_s, P, layout))

    llh, vel, euler, P_nav = jax.vmap(one)(rec.nav, rec.sensors, dx_s, P_s)
    return out._replace(llh=llh, vel_enu=vel, euler=euler, P_nav=P_nav)
