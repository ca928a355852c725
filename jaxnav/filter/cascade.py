"""Loosely coupled PPP/INS as one pure epoch step: a GNSS-only PPP filter feeding a LC INS filter.

A loosely coupled system is a cascade of two filters (S003 §3.1, S002 §4.2): a stand-alone PPP
filter (``filter/ppp_only.py``, a ``GnssOnlySystem`` with the constant-velocity motion model run
through ``filter/tight.py``, so the same measurement models, slot resets and outlier tests as
the tightly coupled filter) whose position / velocity solution is the measurement of the loosely
coupled INS filter (``filter/loose.py``). In a study both must run in the same epoch, so that a
GNSS outage (``keep`` mask of the PPP input) reaches the INS the way it does in a real receiver:
with fewer than four satellites the PPP update cannot fix a position and the INS gets no fix.

One epoch (``epoch_step``):

1. the PPP epoch (``tight.epoch_step`` of ``CascadeFilter.ppp``) with the epoch's GNSS
   observations and availability mask;
2. its solution becomes a ``loose.GnssFix`` (``fix_from_ppp``): the antenna llh and ENU
   velocity, with the PPP covariance blocks converted to ENU metres,
   cov_pos_enu = T P_pos T^T with T = [[0, m_E, 0], [m_N, 0, 0], [0, 0, 1]] (m_N, m_E metres per
   radian of latitude and longitude, ``geodesy.metres_per_radian``) and cov_vel_enu = P_vel
   (S003 §3.1: "the full position and velocity variance covariance matrix" of the PPP filter is
   the LC measurement noise; the position-velocity cross-covariance is dropped because
   ``loose`` takes the two blocks as independent);
3. the LC epoch (``loose.epoch_step`` of ``CascadeFilter.lc``) with the epoch's IMU samples, that
   fix and the vehicle-constraint inputs.

Validity rule (chosen; the seeds only say a LC solution needs a GNSS fix): the fix is valid (its
position and its velocity) when the PPP update of that epoch used at least ``min_sats``
satellites (``tight.EpochOutput.n_sat``: slots with at least one used code, phase or Doppler
row; default 4 = three position coordinates and the receiver clock). With 0-3 satellites kept
the PPP filter still updates with what it has (its position is then mostly its own
constant-velocity prediction), but that solution is not a GNSS fix and the LC filter coasts on
the INS (plus NHC / odometer / ZUPT when configured). The first epoch back with four satellites
is a valid fix again, with the PPP covariance (grown during the outage, phase ambiguities reset)
as its weight.

The PPP solution's errors are correlated in time (S003 does not model it): with
``LooseConfig.fix_bias_tau_s`` the LC filter estimates the fix's position error as states whose
variance follows the PPP covariance (``filter.loose`` docstring); the study factory sets it per
mode when ``[scenario] lc_fix_errors = "correlated"`` (not the default, docs/models.md). The
velocity fixes are always weighted as independent.

Carry = ``Carry(ppp, lc)``; ``run`` = ``lax.scan`` of ``epoch_step``; ``run_smoother`` adds an
RTS smoother of the LC part over the forward PPP fixes; ``cascade_ops()`` adapts both
to the sweep engine (``core.ops.FilterOps``): the keep mask is the PPP input's, the readout is
the LC INS navigation solution and its 9x9 navigation covariance (pos rad/rad/m, vel, att), the
same as the tight INS filters give.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxnav import geodesy
from jaxnav.core.ops import FilterOps
from jaxnav.core.track import track
from jaxnav.filter import loose, ppp_only, tight
from jaxnav.filter.systems import NavSigmas
from jaxnav.gnss import ppp
from jaxnav.ins import strapdown

#: Minimum satellites used by the PPP update for its solution to be a fix (module docstring).
MIN_FIX_SATELLITES = 4


class CascadeFilter(eqx.Module):
    """A GNSS-only PPP filter (``TightFilter`` over a ``GnssOnlySystem``) feeding a LC filter."""

    ppp: tight.TightFilter
    lc: loose.LooseFilter
    min_sats: int = eqx.field(static=True, default=MIN_FIX_SATELLITES)


class Carry(NamedTuple):
    """Memory of both filters."""

    ppp: tight.Carry
    lc: loose.Carry


class EpochInput(NamedTuple):
    """One epoch: the PPP input (its ``samples`` a dummy [K_ppp], ``ppp_only.dummy_samples``) and
    the LC filter's IMU samples and constraint inputs (``loose.EpochInput`` without the fix)."""

    gnss: tight.EpochInput
    imu: strapdown.ImuIncrements  # raw IMU samples over (t_{k-1}, t_k], [K, 3] each
    odo_speed_m_s: jnp.ndarray
    odo_valid: jnp.ndarray
    nhc_valid: jnp.ndarray
    zupt_allowed: jnp.ndarray


class EpochOutput(NamedTuple):
    """Both filters' outputs and the fix handed from one to the other."""

    ppp: tight.EpochOutput
    lc: loose.EpochOutput
    fix: loose.GnssFix


def fix_from_ppp(ppp_tf: tight.TightFilter, out: tight.EpochOutput, min_sats=MIN_FIX_SATELLITES):
    """A ``loose.GnssFix`` from a PPP epoch's output (module docstring, step 2 and the validity
    rule). Works on one epoch or stacked epochs (leading axes of ``out``)."""
    layout = ppp_tf.layout
    if not layout.has("vel"):
        raise ValueError("the PPP filter of a cascade needs a velocity state (constant_velocity)")
    pos, vel = layout.sl("pos"), layout.sl("vel")

    def one(llh, vel_enu, P_nav, n_sat):
        T = geodesy.llh_error_to_enu_matrix(llh)
        cov_pos = T @ P_nav[pos, pos] @ T.T
        cov_vel = P_nav[vel, vel]
        ok = n_sat >= min_sats
        return loose.GnssFix(llh, 0.5 * (cov_pos + cov_pos.T), vel_enu, cov_vel, ok, ok)

    fn = one
    for _ in range(out.llh.ndim - 1):
        fn = jax.vmap(fn)
    return fn(out.llh, out.vel_enu, out.P_nav, out.n_sat)


def epoch_step(cf: CascadeFilter, carry: Carry, inp: EpochInput, record: bool = False):
    """One epoch: PPP update, its fix, then the LC epoch with that fix (module docstring).

    With ``record`` (static) returns (carry, (EpochOutput, smoother.Record of the LC filter)),
    for ``run_smoother``."""
    ppp_carry, ppp_out = tight.epoch_step(cf.ppp, carry.ppp, inp.gnss)
    fix = fix_from_ppp(cf.ppp, ppp_out, cf.min_sats)
    lc_inp = loose.EpochInput(
        inp.imu, fix, inp.odo_speed_m_s, inp.odo_valid, inp.nhc_valid, inp.zupt_allowed
    )
    if record:
        lc_carry, (lc_out, rec) = loose.epoch_step(cf.lc, carry.lc, lc_inp, record=True)
        return Carry(ppp_carry, lc_carry), (EpochOutput(ppp_out, lc_out, fix), rec)
    lc_carry, lc_out = loose.epoch_step(cf.lc, carry.lc, lc_inp)
    return Carry(ppp_carry, lc_carry), EpochOutput(ppp_out, lc_out, fix)


def run(cf: CascadeFilter, carry: Carry, inputs: EpochInput):
    """Scan ``epoch_step`` over stacked epochs; returns (final carry, stacked EpochOutput)."""
    return jax.lax.scan(lambda c, i: epoch_step(cf, c, i), carry, inputs)


def run_smoother(cf: CascadeFilter, carry: Carry, inputs: EpochInput, n_valid=None):
    """Forward cascade and an RTS smoother of its LC INS filter over stacked epochs.

    Returns (forward EpochOutput, smoothed EpochOutput). Only the LC part is smoothed
    (``loose.smoothed_outputs``; ``n_valid``: ``smoother.error_state``): its measurements are the
    forward PPP fixes, taken as independent from epoch to epoch as in the forward LC filter, so
    this is what a post-processor gets by smoothing a loosely coupled solution over a recorded
    PPP track. The PPP part and the fixes in the smoothed output are the forward ones. Honest
    sigmas need the fix-bias states (``LooseConfig.fix_bias_tau_s``): with white fix errors the
    smoother averages correlated PPP errors as independent (benchmarks/RESULTS.md, position
    ANEES 68.9 against 2.97 with the fix-bias states)."""
    _, (out, rec) = jax.lax.scan(lambda c, i: epoch_step(cf, c, i, record=True), carry, inputs)
    return out, out._replace(lc=loose.smoothed_outputs(cf.lc, out.lc, rec, n_valid))


# ---- construction helpers ---------------------------------------------------------------------
def make_filter(
    pcfg: ppp.PppConfig,
    slots: ppp.SlotInfo,
    lf: loose.LooseFilter,
    ppp_system: ppp_only.GnssOnlySystem | None = None,
    min_sats: int = MIN_FIX_SATELLITES,
) -> CascadeFilter:
    """A cascade whose PPP part runs at the LC filter's epoch interval (one dummy sample per
    epoch); default PPP motion model: ``GnssOnlySystem(model="constant_velocity")``."""
    system = ppp_system
    if system is None:
        system = ppp_only.GnssOnlySystem(model="constant_velocity")
    ptf = tight.TightFilter(system, pcfg, slots, lf.epoch_dt_s, lf.epoch_dt_s)
    return CascadeFilter(ptf, lf, min_sats)


def epoch_inputs(
    gnss: tight.EpochInput,
    imu: strapdown.ImuIncrements | None = None,
    odo_speed_m_s=None,
    odo_valid=None,
    nhc_valid=True,
    zupt_allowed=True,
) -> EpochInput:
    """Stacked cascade inputs from the tight filter's INS inputs (``gnss.samples`` = the IMU
    samples [E, K, 3], replaced by one dummy PPP sample per epoch) or an explicit ``imu``.
    Missing odometer = invalid (as ``loose.epoch_inputs``)."""
    imu = gnss.samples if imu is None else imu
    n_ep = imu.dv_b.shape[0]
    lc = loose.epoch_inputs(
        imu, _dummy_fix(n_ep), odo_speed_m_s, odo_valid, nhc_valid, zupt_allowed
    )
    return EpochInput(
        gnss._replace(samples=ppp_only.dummy_samples(n_ep)),
        imu,
        lc.odo_speed_m_s,
        lc.odo_valid,
        lc.nhc_valid,
        lc.zupt_allowed,
    )


def _dummy_fix(n_ep: int) -> loose.GnssFix:
    return loose.gnss_fix(jnp.zeros((n_ep, 3)), jnp.zeros((n_ep, 3)), 1.0, 1.0, False, False)


def initial_carry(
    cf: CascadeFilter,
    ins_nav0,
    obs0: ppp.GnssObs,
    sigmas: NavSigmas | None = None,
    sensors0=None,
    ppp_nav0: ppp_only.GnssNav | None = None,
) -> Carry:
    """Both filters' start: the LC filter at ``ins_nav0`` (``loose.initial_carry``; sensor-error
    estimates ``sensors0``, e.g. a static calibration), the PPP filter at ``ppp_nav0`` or else the
    INS antenna position and velocity (``tight.initial_carry`` with the first epoch's code)."""
    sigmas = NavSigmas() if sigmas is None else sigmas
    lc = loose.initial_carry(cf.lc, ins_nav0, sigmas)
    if sensors0 is not None:
        lc = lc._replace(sensors=sensors0)
    if ppp_nav0 is None:
        system = cf.lc.system
        rx = system.antenna(ins_nav0, system.idle_inputs(ins_nav0), lc.sensors, cf.lc.layout)
        C_e_l = geodesy.C_l_e(rx.llh[0], rx.llh[1]).T
        ppp_nav0 = ppp_only.GnssNav(rx.llh, C_e_l @ rx.vel_ecef)
    return Carry(tight.initial_carry(cf.ppp, ppp_nav0, obs0, sigmas), lc)


# ---- the sweep engine's view ------------------------------------------------------------------
def _readout(out: EpochOutput):
    return track(out.lc.llh, out.lc.vel_enu, out.lc.euler), out.lc.P_nav


@functools.cache
def cascade_ops():
    """``core.ops.FilterOps`` of the cascade: keep mask on the PPP part, readout = the LC INS
    solution and its navigation covariance. Cached, so compiled sweep functions are reused."""
    return FilterOps(
        run=run,
        readout=_readout,
        get_keep=lambda inp: inp.gnss.keep,
        with_keep=lambda inp, keep: inp._replace(gnss=inp.gnss._replace(keep=keep)),
        smooth=run_smoother,
    )
