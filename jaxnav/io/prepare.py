"""Real observations + products -> the stacked, fixed-slot ``EpochInput`` of ``filter/tight.py``.

``prepare_gnss`` turns a RINEX observation file (``io.read_rinex_obs``) and the products
(broadcast ephemerides from ``io.read_broadcast_ephemeris``, SP3 orbits, RINEX clocks,
IONEX maps) into one ``ppp.GnssObs`` per epoch (stacked along a leading time axis), the
``ppp.SlotInfo`` of the satellites and the day of year; ``epoch_inputs`` adds the navigation
system's per-epoch samples and the availability mask to make the ``tight.EpochInput`` pytree.
This module is the stage that runs them in order; the computations are pure JAX over [T, S]
arrays in ``gnss/`` (satellites, series, spp, slips).

What each slot gets, per epoch (S002 eqs 2.25-2.26 with the corrections of SEED_SPEC 2.10):

- Satellite position / velocity and clock at *transmission* (``gnss/satellites.py``: SP3 +
  RINEX clock through ``gnss/interp.py``, or the broadcast ephemeris), with the relativistic
  clock term; Earth rotation during the travel time is applied by the filter's geometry.
- Satellite code biases [S, 2] (subtracted from the code by the filter): zero for dual-frequency
  P1/P2 users (precise and broadcast clocks refer to the P1/P2 or E1/E5a ionosphere-free code,
  SEED_SPEC 2.8); for single-frequency users the broadcast group delay: GPS
  B_1 = c TGD, B_2 = (f1/f2)^2 c TGD (IS-GPS-200 20.3.3.3.3.2), Galileo B_1 = c BGD(E1,E5a)
  likewise. The C/A-minus-P(Y) bias (DCB_P1C1, a few dm) is not available here and is ignored.
- Model ionosphere on f1 (single-frequency users and the ic_ppp GIM pseudo-observation):
  broadcast Klobuchar (IS-GPS-200 20.3.3.5.2.5) scaled by (f_L1/f1)^2, or an IONEX map at the
  350-km (file height) thin-shell pierce point with the single-layer mapping function.
- Phase wind-up (gnss.windup, S002 eqs 2.14-2.19): phase_m = lambda (L - phi_w / 2 pi).
- Solid Earth tide (gnss.tides, IERS 2010) and the antenna reference point eccentricity
  (RINEX "ANTENNA: DELTA H/E/N"): the antenna sits at r_marker + d, so each observation is
  corrected by + u . d (u receiver -> satellite), which makes the filter estimate the
  tide-free marker. Receiver and satellite antenna phase-centre offsets/variations (ANTEX) are
  NOT applied (no ANTEX file is available for the shared data; see docs/validation.md).
- Slip flags (S002 §5.3): loss-of-lock indicator bit 0 on either phase, the geometry-free phase
  jump |GF_k - GF_{k-1}| > ``gf_slip_m`` and the Melbourne-Wuebbena test
  |MW_k - mean_arc(MW)| > ``mw_slip_sigmas`` * max(std_arc(MW), floor(E)) with the floor
  ``mw_floor_cycles`` lambda_WL at zenith growing like the S001 eq 11 elevation law;
  either one flags (S002: both detectors run, either one triggers the ambiguity reset).
- A-priori receiver clock: the per-epoch SPP clock is removed from code and phase alike (the
  filter still estimates the clock, now a metre-level residual; millisecond receiver-clock
  offsets and jumps would otherwise exceed the filter's gates).
- ``available``: every signal the mode needs is present, the products are valid, and the code
  is a plausible GNSS range (1.9e7-3.0e7 m).

The approximate receiver position used for elevations, Klobuchar, wind-up and tides comes from
a per-epoch least-squares single-point solution (``spp``), which also initialises the filter.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxnav.core import gpstime
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import ephemeris, models, satellites, series, signals
from jaxnav.gnss.interp import clock_table, orbit_table
from jaxnav.gnss.ppp_data import EpochInput, GnssObs, SlotInfo
from jaxnav.gnss.slips import detect_slips
from jaxnav.gnss.spp import fill_positions, spp
from jaxnav.io.products import ClockTable, IonexMaps, Sp3Orbit
from jaxnav.io.rinex import RinexObs

LETTER_TO_SYS = {"G": signals.SYS_GPS, "R": signals.SYS_GLO, "E": signals.SYS_GAL}

#: Observation codes read per constellation: (code f1, code f2, phase f1, phase f2, Doppler f1).
#: Dual frequency uses the codes the precise (and broadcast) clocks refer to: GPS P(Y) C1W/C2W,
#: GLONASS P C1P/C2P, Galileo E1/E5a pilots C1C/C5Q (SEED_SPEC 2.8). Single frequency uses the
#: civil C/A code (S000, S002 ch. 4).
DUAL_SIGNALS = {
    "G": ("C1W", "C2W", "L1C", "L2W", "D1C"),
    "R": ("C1P", "C2P", "L1P", "L2P", "D1P"),
    "E": ("C1C", "C5Q", "L1C", "L5Q", "D1C"),
}
SINGLE_SIGNALS = {
    "G": ("C1C", None, "L1C", None, "D1C"),
    "R": ("C1C", None, "L1C", None, "D1C"),
    "E": ("C1C", None, "L1C", None, "D1C"),
}

_MIN_RANGE_M = 1.9e7  # plausible pseudorange bounds (MEO satellites seen from the ground)
_MAX_RANGE_M = 3.0e7
_NOMINAL_TRAVEL_S = 0.075  # used only where no code is present (the slot is unavailable anyway)


def rinex_requests(freq: str, systems) -> dict[str, tuple[str, ...]]:
    """The RINEX 3 codes to ask ``read_rinex_obs`` for, per constellation letter."""
    table = DUAL_SIGNALS if freq == "dual" else SINGLE_SIGNALS
    return {s: tuple(c for c in table[s] if c is not None) for s in systems}


@dataclass
class PrepareOptions:
    """Choices of the preparation step (every number says where it comes from)."""

    freq: str = "dual"  # "single" (C1 + model ionosphere) or "dual" (P1/P2, L1/L2)
    systems: tuple[str, ...] = ("G",)
    iono: str = "klobuchar"  # "klobuchar", "ionex" (needs maps) or "none"
    apply_windup: bool = True
    apply_tides: bool = True
    antenna_delta_hen_m: tuple[float, float, float] | None = None  # None: from the RINEX header
    gf_slip_m: float = 0.05  # chosen: RTKLIB's default geometry-free slip threshold (5 cm)
    mw_slip_sigmas: float = 4.0  # chosen: 4-sigma Melbourne-Wuebbena jump
    mw_floor_cycles: float = 0.25  # chosen: floor 0.25 WL cycles: 4 sigma >= 1 cycle (86 cm)
    sp3_points: int = 10  # io.products default (mm agreement with 12 points)
    sp3_one_sided: bool = False  # allow one-sided SP3 windows at the ends of the orbit table
    clock_max_gap_s: float | None = None  # None: io.products default (2 x interval)
    spp_mask_rad: float = math.radians(10.0)  # chosen: the filter's default mask (S000 QC)
    leap_seconds: float = gpstime.GPS_UTC_LEAP_S
    remove_spp_clock: bool = True  # subtract the SPP receiver clock from code and phase

    def __post_init__(self):
        if self.freq not in ("single", "dual"):
            raise ValueError(f"freq must be 'single' or 'dual', got {self.freq!r}")
        if self.iono not in ("klobuchar", "ionex", "none"):
            raise ValueError(f"iono must be 'klobuchar', 'ionex' or 'none', got {self.iono!r}")
        bad = [s for s in self.systems if s not in LETTER_TO_SYS]
        if bad:
            raise ValueError(f"unsupported constellation(s) {bad}; expected G, R or E")


class Products(NamedTuple):
    """The product files a run uses (any may be None; orbits need sp3 or nav)."""

    nav: ephemeris.BroadcastEphemeris | None = None
    sp3: Sp3Orbit | None = None
    clk: ClockTable | None = None
    ionex: IonexMaps | None = None


class PreparedGnss(NamedTuple):
    """Everything the filter needs from the GNSS side, stacked over epochs."""

    obs: GnssObs  # leaves [T, ...]
    day_of_year: jnp.ndarray  # [T]
    slots: SlotInfo
    time_gps_s: np.ndarray  # [T]
    sv: tuple[str, ...]  # [S] satellite ids
    spp_pos_ecef: np.ndarray  # [T, 3] single-point solution (NaN where it failed)
    spp_ok: np.ndarray  # [T] bool
    rx_clock_m: np.ndarray  # [T] a-priori receiver clock removed from code and phase [m]
    approx_pos_ecef: np.ndarray  # [T, 3] position used for the corrections
    windup_cycles: np.ndarray  # [T, S]
    tide_ecef_m: np.ndarray  # [T, 3]
    slip_counts: dict  # {"lli": n, "gf": n, "mw": n}
    elevation_rad: np.ndarray  # [T, S] at the approximate position


def epoch_inputs(prep: PreparedGnss, samples, keep=None) -> EpochInput:
    """``tight.EpochInput`` (leaves [T, ...]) from prepared GNSS data and per-epoch samples."""
    T, S = prep.obs.available.shape
    keep = jnp.ones((T, S), bool) if keep is None else jnp.asarray(keep, bool)
    return EpochInput(samples=samples, obs=prep.obs, keep=keep, day_of_year=prep.day_of_year)


# ------------------------------------------------------------------------------------------------
# Slot selection and observation arrays (host side)
# ------------------------------------------------------------------------------------------------


def _glonass_channel(nav, prn):
    if nav is None:
        return None
    sel = (np.asarray(nav.system) == signals.SYS_GLO) & (np.asarray(nav.prn) == prn)
    return int(np.asarray(nav.glo_channel)[sel][0]) if sel.any() else None


def _product_has(products: Products, sv: str) -> bool:
    letter, prn = sv[0], int(sv[1:])
    if products.sp3 is not None:
        return sv in set(products.sp3.sv.tolist())
    if products.nav is None:
        return False
    nav = products.nav
    return bool(
        np.any((np.asarray(nav.system) == LETTER_TO_SYS[letter]) & (np.asarray(nav.prn) == prn))
    )


class _SlotArrays(NamedTuple):
    sv: tuple[str, ...]
    system: np.ndarray  # [S] int
    f: np.ndarray  # [S, 2] Hz
    code: np.ndarray  # [T, S, 2] m (NaN)
    phase_cyc: np.ndarray  # [T, S, 2] cycles (NaN)
    doppler_hz: np.ndarray  # [T, S]
    lli: np.ndarray  # [T, S] int (OR of both phases)


def _slot_arrays(obs: RinexObs, products: Products, opt: PrepareOptions) -> _SlotArrays:
    table = DUAL_SIGNALS if opt.freq == "dual" else SINGLE_SIGNALS
    T = obs.time_gps_s.size
    cols = {k: [] for k in ("code1", "code2", "phase1", "phase2", "dopp", "lli")}
    sv_list, sys_list, f_list = [], [], []
    for letter in sorted(opt.systems, key=lambda s: LETTER_TO_SYS[s]):
        if letter not in obs.systems:
            raise ValueError(f"constellation {letter} was not read from the observation file")
        so = obs.systems[letter]
        c1, c2, l1, l2, d1 = table[letter]
        sys_id = LETTER_TO_SYS[letter]
        for k, sv in enumerate(so.sv):
            code1 = so.obs[c1][:, k]
            if not np.any(np.isfinite(code1)):
                continue
            if opt.freq == "dual" and not np.any(np.isfinite(so.obs[c2][:, k])):
                continue
            if not _product_has(products, str(sv)):
                continue
            channel = 0
            if letter == "R":
                channel = _glonass_channel(products.nav, int(str(sv)[1:]))
                if channel is None:
                    warnings.warn(
                        f"{sv}: no GLONASS channel in the navigation file; skipped", stacklevel=3
                    )
                    continue
            f1 = float(signals.carrier_frequency_hz(sys_id, 0, channel))
            f2 = float(signals.carrier_frequency_hz(sys_id, 1, channel))
            nan = np.full(T, np.nan)
            cols["code1"].append(code1)
            cols["code2"].append(so.obs[c2][:, k] if c2 else nan)
            cols["phase1"].append(so.obs[l1][:, k] if l1 in so.obs else nan)
            cols["phase2"].append(so.obs[l2][:, k] if l2 else nan)
            cols["dopp"].append(so.obs[d1][:, k] if d1 in so.obs else nan)
            lli = np.zeros(T, np.int64)
            for name in (l1, l2):
                if name and name in so.lli:
                    lli |= so.lli[name][:, k].astype(np.int64)
            cols["lli"].append(lli)
            sv_list.append(str(sv))
            sys_list.append(sys_id)
            f_list.append((f1, f2))
    if not sv_list:
        raise ValueError(
            f"no satellite of {opt.systems} has the {opt.freq}-frequency observations and products"
        )
    stack = {k: np.stack(v, axis=1) for k, v in cols.items()}
    return _SlotArrays(
        tuple(sv_list),
        np.array(sys_list, np.int32),
        np.array(f_list),
        np.stack([stack["code1"], stack["code2"]], axis=-1),
        np.stack([stack["phase1"], stack["phase2"]], axis=-1),
        stack["dopp"],
        stack["lli"],
    )


# ------------------------------------------------------------------------------------------------
# Satellite states at transmission (pure JAX)
# ------------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------------
# Main entry
# ------------------------------------------------------------------------------------------------


def _antenna_delta(obs: RinexObs, opt: PrepareOptions):
    if opt.antenna_delta_hen_m is not None:
        return np.asarray(opt.antenna_delta_hen_m, np.float64)
    rows = obs.header.get("ANTENNA: DELTA H/E/N")
    if rows:
        try:
            return np.array([float(v) for v in rows[0][:42].split()[:3]])
        except ValueError:
            warnings.warn("unparsable ANTENNA: DELTA H/E/N; using 0", stacklevel=3)
    return np.zeros(3)


def _tgd_per_slot(nav, sv, t_mid_gps):
    """Broadcast TGD / BGD(E1,E5a) [s] per slot from the record nearest to t_mid (0 if none)."""
    out = np.zeros(len(sv))
    if nav is None:
        return out
    system, prn = np.asarray(nav.system), np.asarray(nav.prn)
    toe = np.asarray(nav.kepler.toe_s) + float(nav.t_ref_gps_s)
    valid = np.asarray(nav.kepler.valid)
    tgd = np.asarray(nav.kepler.tgd_s)
    for k, s in enumerate(sv):
        if s[0] not in ("G", "E"):
            continue
        sel = np.flatnonzero((system == LETTER_TO_SYS[s[0]]) & (prn == int(s[1:])))
        if sel.size == 0:
            continue
        i = sel[0]
        age = np.where(valid[i], np.abs(toe[i] - t_mid_gps), np.inf)
        if np.isfinite(age.min()):
            out[k] = tgd[i, int(np.argmin(age))]
    return out


def prepare_gnss(
    obs: RinexObs,
    products: Products,
    opt: PrepareOptions | None = None,
    *,
    static_receiver: bool = False,
) -> PreparedGnss:
    """Build the stacked GNSS inputs of the tight filter from real observations and products.

    ``static_receiver`` uses the median single-point position at every epoch for the
    corrections (elevation, Klobuchar, wind-up, tides); otherwise each epoch's own SPP.
    """
    opt = PrepareOptions() if opt is None else opt
    if products.sp3 is None and products.nav is None:
        raise ValueError("orbits are needed: give SP3 files or a navigation file")
    if opt.iono == "ionex" and products.ionex is None:
        raise ValueError("iono='ionex' needs IONEX maps")
    arr = _slot_arrays(obs, products, opt)
    t_rx = np.asarray(obs.time_gps_s, np.float64)
    T, S = arr.code.shape[:2]
    f1, f2 = arr.f[:, 0], arr.f[:, 1]
    lam1, lam2 = C_LIGHT / f1, C_LIGHT / f2
    dual = opt.freq == "dual"

    code = arr.code
    travel = np.where(np.isfinite(code[..., 0]), code[..., 0], code[..., 1]) / C_LIGHT
    travel = jnp.asarray(np.where(np.isfinite(travel), travel, _NOMINAL_TRAVEL_S))

    # --- satellite states -----------------------------------------------------------------
    if products.sp3 is not None:
        sp3_sv = products.sp3.sv.tolist()
        cols = np.array([sp3_sv.index(s) for s in arr.sv])
        sp3_tab = satellites.sub_grid(orbit_table(products.sp3), cols)
        if products.clk is not None:
            clk_sv = products.clk.sv.tolist()
            have_clk = np.array([s in clk_sv for s in arr.sv])
            ccols = np.array([clk_sv.index(s) if s in clk_sv else 0 for s in arr.sv])
            ctab = clock_table(
                products.clk.time_gps_s,
                products.clk.clock_s,
                products.clk.interval_s,
                opt.clock_max_gap_s,
            )
            ctab = satellites.sub_clock(ctab, ccols)
        else:
            warnings.warn(
                "no clock file: using the SP3 clock column (interpolated linearly over the SP3 "
                "interval; expect decimetres of clock error)",
                stacklevel=2,
            )
            have_clk = np.ones(S, bool)
            ctab = clock_table(
                products.sp3.time_gps_s,
                products.sp3.clock_s[:, cols],
                products.sp3.interval_s,
                opt.clock_max_gap_s,
            )
        sat = satellites.precise_states(
            sp3_tab, ctab, jnp.asarray(t_rx), travel, opt.sp3_points, opt.sp3_one_sided
        )
        sat = sat._replace(valid=sat.valid & jnp.asarray(have_clk)[None, :])
    else:
        nav = products.nav
        idx = []
        for s in arr.sv:
            sel = np.flatnonzero(
                (np.asarray(nav.system) == LETTER_TO_SYS[s[0]])
                & (np.asarray(nav.prn) == int(s[1:]))
            )
            idx.append(int(sel[0]))
        eph_sub = ephemeris.take_satellites(nav, np.array(idx))
        sat = satellites.broadcast_states(eph_sub, t_rx, travel)

    # --- model ionosphere inputs (needs geometry: computed after SPP) ------------------------
    doy = np.array([gpstime.day_of_year(t) for t in t_rx])
    code_bias = np.zeros((T, S, 2))
    if not dual:
        tgd = _tgd_per_slot(products.nav, arr.sv, float(np.median(t_rx)))
        code_bias[..., 0] = C_LIGHT * tgd
        code_bias[..., 1] = (f1 / f2) ** 2 * C_LIGHT * tgd

    # --- single-point positioning -----------------------------------------------------------
    alpha, beta = signals.if_coefficients(f1, f2)
    code_corr = code - code_bias
    if dual:
        pr = alpha * code_corr[..., 0] + beta * code_corr[..., 1]
    else:
        pr = code_corr[..., 0]
    pr_ok = np.isfinite(pr) & (pr > _MIN_RANGE_M) & (pr < _MAX_RANGE_M) & np.asarray(sat.valid)
    n_sys = signals.N_SYSTEMS
    x0 = obs.approx_pos_ecef if np.all(np.isfinite(obs.approx_pos_ecef)) else None
    iono_for_spp = None
    if not dual and opt.iono != "none":
        # A first pass without ionosphere gives the position for the ionosphere model; redo.
        first = spp(
            jnp.asarray(np.nan_to_num(pr)),
            sat.pos,
            sat.clock_m,
            jnp.asarray(pr_ok),
            jnp.asarray(arr.system),
            n_sys,
            jnp.asarray(doy),
            x0,
            opt.spp_mask_rad,
        )
        rx_first = fill_positions(np.asarray(first.pos_ecef), np.asarray(first.ok))
        iono_for_spp = jnp.asarray(_iono_model(opt, products, rx_first, sat, t_rx, f1))
    res = spp(
        jnp.asarray(np.nan_to_num(pr)),
        sat.pos,
        sat.clock_m,
        jnp.asarray(pr_ok),
        jnp.asarray(arr.system),
        n_sys,
        jnp.asarray(doy),
        x0,
        opt.spp_mask_rad,
        iono_l1_m=iono_for_spp,
    )
    spp_pos = np.asarray(res.pos_ecef)
    spp_ok = np.asarray(res.ok)
    approx = fill_positions(spp_pos, spp_ok)
    # A-priori receiver clock: the SPP clock of the first constellation (nearest good epoch
    # where SPP failed). Receivers keep offsets of up to a millisecond (ESBC: 0.48 ms = 144 km)
    # and may jump by whole milliseconds; removing it from code and phase alike leaves the
    # filter's clock state a metre-level residual, whatever the receiver does.
    sys0 = int(np.min(arr.system))
    rx_clock = fill_positions(np.asarray(res.clock_m)[:, sys0 : sys0 + 1], spp_ok)[:, 0]
    if not opt.remove_spp_clock:
        rx_clock = np.zeros(T)
    if static_receiver:
        approx = np.broadcast_to(np.median(approx[spp_ok], axis=0), approx.shape).copy()

    # --- geometry at the approximate position --------------------------------------------------
    los, el, az, llh, sat_rot = series.geometry_series(jnp.asarray(approx), sat.pos, sat.clock_m)

    # --- ionosphere model ---------------------------------------------------------------------
    iono_l1 = _iono_model(opt, products, approx, sat, t_rx, f1)

    # --- wind-up and tides ----------------------------------------------------------------------
    if opt.apply_windup:
        phi_w = np.asarray(series.windup_series(
            sat_rot, jnp.asarray(approx), llh, jnp.asarray(t_rx), opt.leap_seconds
        ))
    else:
        phi_w = np.zeros((T, S))
    delta = _antenna_delta(obs, opt)  # (H, E, N)
    arp_enu = np.array([delta[1], delta[2], delta[0]])
    disp = np.zeros((T, 3))
    if opt.apply_tides:
        disp = np.asarray(
            series.tide_series(jnp.asarray(approx), jnp.asarray(t_rx), opt.leap_seconds)
        )
    C = np.asarray(series.enu_axes_series(llh))  # [T, 3, 3]
    disp_total = disp + np.einsum("tij,j->ti", C, arp_enu)
    los_corr = np.einsum("tsi,ti->ts", np.asarray(los), disp_total)  # u . d

    # --- observations in metres, corrected --------------------------------------------------------
    phase_m = arr.phase_cyc * np.stack([lam1, lam2], axis=-1)[None]
    phase_m = phase_m - (phi_w / (2.0 * np.pi))[..., None] * np.stack([lam1, lam2], -1)[None]
    code_m = code + los_corr[..., None] - rx_clock[:, None, None]
    phase_m = phase_m + los_corr[..., None] - rx_clock[:, None, None]
    range_rate = -lam1[None, :] * arr.doppler_hz

    # --- slips ---------------------------------------------------------------------------------
    have_phase = np.isfinite(phase_m[..., 0]) & (np.isfinite(phase_m[..., 1]) | (not dual))
    lli_slip = (arr.lli & 1) > 0
    if dual:
        gf = phase_m[..., 0] - phase_m[..., 1]
        mw = np.asarray(
            signals.melbourne_wubbena_m(
                phase_m[..., 0], phase_m[..., 1], code_m[..., 0], code_m[..., 1], f1, f2
            )
        )
        have_mw = have_phase & np.isfinite(code[..., 0]) & np.isfinite(code[..., 1])
        # MW noise floor: mw_floor_cycles wide-lane cycles at zenith, growing below 30 deg
        # like the code noise it comes from (S001 eq 11 elevation law).
        lam_wl = np.asarray(signals.wl_wavelength_m(f1, f2))
        floor = (
            opt.mw_floor_cycles
            * lam_wl[None, :]
            * np.asarray(models.elevation_sigma(1.0, jnp.asarray(el)))
        )
        gf_slip, mw_slip = detect_slips(
            jnp.asarray(np.nan_to_num(gf)),
            jnp.asarray(np.nan_to_num(mw)),
            jnp.asarray(have_mw),
            jnp.asarray(floor),
            opt.gf_slip_m,
            opt.mw_slip_sigmas,
        )
        gf_slip, mw_slip = np.asarray(gf_slip), np.asarray(mw_slip)
    else:
        gf_slip = mw_slip = np.zeros((T, S), bool)
    slip = lli_slip | gf_slip | mw_slip

    # --- availability ---------------------------------------------------------------------------
    if dual:
        need = np.isfinite(code[..., 0]) & np.isfinite(code[..., 1]) & have_phase
    else:
        need = np.isfinite(code[..., 0])
    plausible = (code[..., 0] > _MIN_RANGE_M) & (code[..., 0] < _MAX_RANGE_M)
    available = need & plausible & np.asarray(sat.valid)

    def fin(a):
        return jnp.asarray(np.nan_to_num(np.where(np.isfinite(a), a, 0.0)))

    gobs = GnssObs(
        code_m=fin(code_m),
        phase_m=fin(np.where(np.isfinite(phase_m), phase_m, 0.0)),
        range_rate_m_s=fin(range_rate),
        available=jnp.asarray(available),
        slip=jnp.asarray(slip),
        code_bias_m=jnp.asarray(code_bias),
        iono_model_l1_m=jnp.asarray(iono_l1),
        sat=models.SatEpoch(sat.pos, sat.vel, sat.clock_m, sat.clock_rate_m_s),
    )
    slots = SlotInfo(jnp.asarray(arr.system), jnp.asarray(f1), jnp.asarray(f2))
    counts = {
        "lli": int(np.sum(lli_slip & available)),
        "gf": int(np.sum(gf_slip & available)),
        "mw": int(np.sum(mw_slip & available)),
    }
    return PreparedGnss(
        obs=gobs,
        day_of_year=jnp.asarray(doy),
        slots=slots,
        time_gps_s=t_rx,
        sv=arr.sv,
        spp_pos_ecef=np.where(spp_ok[:, None], spp_pos, np.nan),
        spp_ok=spp_ok,
        rx_clock_m=rx_clock,
        approx_pos_ecef=approx,
        windup_cycles=phi_w / (2.0 * np.pi),
        tide_ecef_m=disp,
        slip_counts=counts,
        elevation_rad=np.asarray(el),
    )


def _iono_model(opt: PrepareOptions, products: Products, rx_pos, sat, t_rx, f1):
    """Model slant ionosphere on each slot's f1 [m] ([T, S]) at receiver positions [T, 3]."""
    T, S = sat.clock_m.shape
    if opt.iono == "klobuchar":
        if products.nav is None:
            warnings.warn("no navigation file: no Klobuchar ionosphere model", stacklevel=3)
            return np.zeros((T, S))
        return np.asarray(series.klobuchar_slots(products.nav, rx_pos, sat.pos, t_rx, f1))
    if opt.iono == "ionex":
        _, el, az, llh, _ = series.geometry_series(jnp.asarray(rx_pos), sat.pos, sat.clock_m)
        return np.asarray(series.ionex_slots(products.ionex, llh, el, az, t_rx, f1))
    return np.zeros((T, S))


