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
  likewise; a G/E slot without a navigation record (or a record without the group delay) is
  unavailable (never TGD = 0), and so is GLONASS with precise clocks (no P1-P2 DCB). The C/A
  code of GPS and GLONASS is levelled to P1 with the satellite's P1-C1 bias (C1 + DCB_P1C1,
  up to ~1 m): from a CODE DCB file, from the receiver's own C1W - C1C (``p1c1_from_
  observations``), or knowingly not (``ignore_p1c1``); with none of them single frequency
  stops with an error, and a slot missing from the table is unavailable.
- Model ionosphere on f1 (single-frequency users and the ic_ppp GIM pseudo-observation):
  broadcast Klobuchar (IS-GPS-200 20.3.3.5.2.5) scaled by (f_L1/f1)^2, or an IONEX map at the
  350-km (file height) thin-shell pierce point with the single-layer mapping function. Where
  the model has no value (no navigation file; a pierce point or epoch outside the IONEX maps)
  ``iono_model_ok`` is False and a mode that needs the model does not use the slot.
- Doppler: ``doppler_ok`` is False where the receiver gave none (no Doppler row, never 0 m/s).
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
  Single frequency has no GF / MW: the carrier's change against the Doppler's integral
  (``gnss.slips.detect_slips_doppler``, on the phase before the SPP clock is removed, so the
  receiver clock's change cancels against the Doppler's drift) beside the LLI.
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
from jaxnav.gnss.slips import (
    DEFAULT_SLIP_THRESHOLDS,
    SlipThresholds,
    detect_slips_doppler,
    detect_slips_dual,
)
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


#: The P-code read next to C/A to measure the satellites' P1-C1 biases (``p1c1_from_observations``).
P1_CODES = {"G": "C1W", "R": "C1P"}


def rinex_requests(freq: str, systems, *, p1_codes: bool = False) -> dict[str, tuple[str, ...]]:
    """The RINEX 3 codes to ask ``read_rinex_obs`` for, per constellation letter (with
    ``p1_codes`` also the P-code beside C/A, for ``p1c1_from_observations``)."""
    table = DUAL_SIGNALS if freq == "dual" else SINGLE_SIGNALS
    out = {s: tuple(c for c in table[s] if c is not None) for s in systems}
    if p1_codes:  # the P code and C/A on L1, each once (dual frequency already has the P code)
        out = {
            s: v + tuple(c for c in (P1_CODES[s], "C1C") if c not in v) if s in P1_CODES else v
            for s, v in out.items()
        }
    return out


def p1c1_from_observations(obs: RinexObs) -> dict[str, float]:
    """Satellite P1-C1 biases [m] measured by a receiver that tracks P and C/A on L1.

    DCB^s = median_t(P1 - C1) - mean_s(median_t(P1 - C1)) per constellation: P1 - C1 holds the
    satellite's and the receiver's bias (the latter common to all satellites, absorbed by the
    clock; CODE's satellite DCBs are zero-mean per constellation likewise); the median over the
    file removes the code noise and multipath.
    """
    out: dict[str, float] = {}
    for letter, p_code in P1_CODES.items():
        so = obs.systems.get(letter)
        if so is None:
            continue
        if p_code not in so.obs or "C1C" not in so.obs:
            raise ValueError(
                f"P1-C1 from the observations needs {p_code} and C1C of constellation {letter} "
                "in the observation file (read with rinex_requests(..., p1_codes=True))"
            )
        d = so.obs[p_code] - so.obs["C1C"]  # [T, n]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # satellites never seen with both
            med = np.nanmedian(d, axis=0)
        seen = np.isfinite(med)
        if not seen.any():
            raise ValueError(f"no epoch of constellation {letter} has both {p_code} and C1C")
        med = med - np.mean(med[seen])
        out.update({str(sv): float(m) for sv, m, ok in zip(so.sv, med, seen, strict=True) if ok})
    return out


@dataclass
class PrepareOptions:
    """Choices of the preparation step (every number says where it comes from)."""

    freq: str = "dual"  # "single" (C1 + model ionosphere) or "dual" (P1/P2, L1/L2)
    systems: tuple[str, ...] = ("G",)
    iono: str = "klobuchar"  # "klobuchar", "ionex" (needs maps) or "none"
    apply_windup: bool = True
    apply_tides: bool = True
    antenna_delta_hen_m: tuple[float, float, float] | None = None  # None: from the RINEX header
    gf_slip_m: float = DEFAULT_SLIP_THRESHOLDS.gf_m  # gnss.slips.SlipThresholds (sources there)
    mw_slip_sigmas: float = DEFAULT_SLIP_THRESHOLDS.mw_sigmas
    mw_floor_cycles: float = DEFAULT_SLIP_THRESHOLDS.mw_floor_cycles
    sp3_points: int = 10  # io.products default (mm agreement with 12 points)
    sp3_one_sided: bool = False  # allow one-sided SP3 windows at the ends of the orbit table
    clock_max_gap_s: float | None = None  # None: io.products default (2 x interval)
    spp_mask_rad: float = math.radians(10.0)  # chosen: the filter's default mask (S000 QC)
    leap_seconds: float = gpstime.GPS_UTC_LEAP_S
    remove_spp_clock: bool = True  # subtract the SPP receiver clock from code and phase
    p1c1_m: dict[str, float] | None = None  # satellite P1-C1 [m] (io.read_code_dcb or measured)
    ignore_p1c1: bool = False  # single frequency: use C/A as P1 (up to ~1 m of bias, knowingly)
    # (code f1, code f2, phase f1, phase f2, Doppler f1) per constellation letter; None: the
    # tables above. f2 is the constellation's second carrier of gnss.signals (GPS L2, Galileo
    # E5a): e.g. a u-blox receiver's GPS L2C is ("C1C", "C2L", "L1C", "L2L", "D1C").
    signals: dict[str, tuple[str | None, ...]] | None = None

    def slip_thresholds(self) -> SlipThresholds:
        """The detector's thresholds (GF / MW from these options, the rest the defaults)."""
        return DEFAULT_SLIP_THRESHOLDS._replace(
            gf_m=self.gf_slip_m, mw_sigmas=self.mw_slip_sigmas,
            mw_floor_cycles=self.mw_floor_cycles)

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
    slip_counts: dict  # {"lli": n, "gf": n, "mw": n, "doppler": n}
    lost_counts: dict  # slot-epochs tracked but unusable: {"no_tgd", "no_p1c1", "no_doppler",
    # "no_iono_model"} (the last two only for the rows that need them)
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
    table = {**(DUAL_SIGNALS if opt.freq == "dual" else SINGLE_SIGNALS), **(opt.signals or {})}
    T = obs.time_gps_s.size
    cols = {k: [] for k in ("code1", "code2", "phase1", "phase2", "dopp", "lli")}
    sv_list, sys_list, f_list = [], [], []
    for letter in sorted(opt.systems, key=lambda s: LETTER_TO_SYS[s]):
        if letter not in obs.systems:
            raise ValueError(f"constellation {letter} was not read from the observation file")
        so = obs.systems[letter]
        c1, c2, l1, l2, d1 = table[letter]
        missing = [c for c in (c1, c2 if opt.freq == "dual" else None) if c and c not in so.obs]
        if missing:
            raise ValueError(f"constellation {letter}: no {'/'.join(missing)} observations "
                             f"(the file has {sorted(so.obs)})")
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
    """Broadcast TGD / BGD(E1,E5a) [s] per slot from the record nearest to t_mid, and whether
    the slot has one (GLONASS broadcasts none: 0 and True with broadcast clocks; with precise
    clocks ``prepare_gnss`` drops GLONASS single-frequency slots)."""
    out = np.zeros(len(sv))
    found = np.array([s[0] not in ("G", "E") for s in sv])
    if nav is None:
        return out, found
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
        age = np.where(valid[i] & np.isfinite(tgd[i]), np.abs(toe[i] - t_mid_gps), np.inf)
        if np.isfinite(age.min()):
            out[k] = tgd[i, int(np.argmin(age))]
            found[k] = True
    return out, found


def _p1c1_per_slot(opt: PrepareOptions, sv) -> tuple[np.ndarray, np.ndarray]:
    """P1-C1 [m] per slot (Galileo: 0, its E1 code is the BGD's reference) and whether known."""
    needs = np.array([s[0] in P1_CODES for s in sv])
    if opt.ignore_p1c1 or not needs.any():
        return np.zeros(len(sv)), np.ones(len(sv), bool)
    if opt.p1c1_m is None:
        raise ValueError(
            "single-frequency C/A code needs the satellites' P1-C1 biases (up to ~1 m): give a "
            "CODE DCB file (--dcb P1C1yymm.DCB), measure them (--p1c1-from-obs, needs C1W in "
            "the observation file) or accept the bias (--no-p1c1)"
        )
    value = np.array([opt.p1c1_m.get(s, 0.0) for s in sv])
    known = ~needs | np.array([s in opt.p1c1_m for s in sv])
    return value, known


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
    bias_known = np.ones(S, bool)
    p1c1_known = np.ones(S, bool)
    if not dual:
        if products.nav is None and any(s[0] in ("G", "E") for s in arr.sv):
            raise ValueError(
                "single-frequency code needs the broadcast group delays (TGD / BGD) of the "
                "navigation file: give --nav"
            )
        tgd, bias_known = _tgd_per_slot(products.nav, arr.sv, float(np.median(t_rx)))
        if products.sp3 is not None:
            # precise GLONASS clocks refer to the P1/P2 ionosphere-free code: a C/A user needs
            # the satellite's P1-P2 DCB, which no product here gives (never 0: unusable)
            bias_known = bias_known & (arr.system != signals.SYS_GLO)
        p1c1, p1c1_known = _p1c1_per_slot(opt, arr.sv)
        # C1 + DCB_P1C1 = P1; P1 - c TGD refers to the ionosphere-free clock (IS-GPS-200
        # 20.3.3.3.3.2); the filter subtracts code_bias from the code.
        code_bias[..., 0] = C_LIGHT * tgd - p1c1
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
        iono_first, iono_first_ok = _iono_model(opt, products, rx_first, sat, t_rx, f1)
        iono_for_spp = jnp.asarray(iono_first)
        pr_ok = pr_ok & iono_first_ok
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
    iono_l1, iono_ok = _iono_model(opt, products, approx, sat, t_rx, f1)

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
        have_mw = have_phase & np.isfinite(code[..., 0]) & np.isfinite(code[..., 1])
        gf_slip, mw_slip = detect_slips_dual(
            jnp.asarray(phase_m),
            jnp.asarray(code_m),
            jnp.asarray(have_mw),
            jnp.asarray(el),
            jnp.asarray(f1),
            jnp.asarray(f2),
            opt.slip_thresholds(),
        )
        gf_slip, mw_slip = np.asarray(gf_slip), np.asarray(mw_slip)
        dop_slip = np.zeros((T, S), bool)
    else:
        gf_slip = mw_slip = np.zeros((T, S), bool)
        have_dop = have_phase & np.isfinite(range_rate)
        # the phase with its receiver clock, whose change the range rate's drift matches (the
        # SPP clock removed above may be held where the SPP failed)
        phase_clock = phase_m[..., 0] + rx_clock[:, None]
        dop_slip = np.asarray(detect_slips_doppler(
            jnp.asarray(np.where(have_dop, phase_clock, 0.0)),
            jnp.asarray(np.where(have_dop, range_rate, 0.0)), jnp.asarray(have_dop),
            jnp.asarray(el), jnp.asarray(t_rx), opt.slip_thresholds()))
    slip = lli_slip | gf_slip | mw_slip | dop_slip

    # --- availability ---------------------------------------------------------------------------
    if dual:
        need = np.isfinite(code[..., 0]) & np.isfinite(code[..., 1]) & have_phase
    else:
        need = np.isfinite(code[..., 0])
    plausible = (code[..., 0] > _MIN_RANGE_M) & (code[..., 0] < _MAX_RANGE_M)
    tracked = need & plausible & np.asarray(sat.valid)
    available = tracked & bias_known[None, :] & p1c1_known[None, :]
    doppler_ok = np.isfinite(arr.doppler_hz)
    lost = {
        "no_tgd": int(np.sum(tracked & ~bias_known[None, :])),
        "no_p1c1": int(np.sum(tracked & bias_known[None, :] & ~p1c1_known[None, :])),
        "no_doppler": int(np.sum(available & ~doppler_ok)),
        "no_iono_model": int(np.sum(available & ~iono_ok)) if opt.iono != "none" else 0,
    }
    for what, text in (("no_tgd", "no broadcast TGD / BGD"), ("no_p1c1", "no P1-C1 bias")):
        if lost[what]:
            warnings.warn(f"{lost[what]} tracked slot-epochs are unusable: {text}", stacklevel=2)

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
        doppler_ok=jnp.asarray(doppler_ok & available),
        iono_model_ok=jnp.asarray(iono_ok),
    )
    slots = SlotInfo(jnp.asarray(arr.system), jnp.asarray(f1), jnp.asarray(f2))
    counts = {
        "lli": int(np.sum(lli_slip & available)),
        "gf": int(np.sum(gf_slip & available)),
        "mw": int(np.sum(mw_slip & available)),
        "doppler": int(np.sum(dop_slip & available)),
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
        lost_counts=lost,
        elevation_rad=np.asarray(el),
    )


def _iono_model(opt: PrepareOptions, products: Products, rx_pos, sat, t_rx, f1):
    """Model slant ionosphere on each slot's f1 [m] ([T, S]) at receiver positions [T, 3], and
    where the model has a value ([T, S] bool; "none" has none anywhere)."""
    T, S = sat.clock_m.shape
    if opt.iono == "klobuchar":
        if products.nav is None:
            return np.zeros((T, S)), np.zeros((T, S), bool)
        values = np.asarray(series.klobuchar_slots(products.nav, rx_pos, sat.pos, t_rx, f1))
        return values, np.ones((T, S), bool)
    if opt.iono == "ionex":
        maps = products.ionex
        t0, t1 = float(maps.time_gps_s[0]), float(maps.time_gps_s[-1])
        if t_rx[-1] < t0 or t_rx[0] > t1:
            raise ValueError(
                f"the IONEX maps span GPS seconds {t0:.0f}..{t1:.0f}, the observations "
                f"{t_rx[0]:.0f}..{t_rx[-1]:.0f}: give the maps of the observation day"
            )
        _, el, az, llh, _ = series.geometry_series(jnp.asarray(rx_pos), sat.pos, sat.clock_m)
        values, ok = series.ionex_slots(maps, llh, el, az, t_rx, f1)
        return np.asarray(values), np.asarray(ok)
    return np.zeros((T, S)), np.zeros((T, S), bool)
