"""Code-multipath calibration (sigma0 and correlation time) from the static station ESBC00DNK.

Data: ../shared/data/esbc_static (24 h at 30 s, 2020-06-25, Septentrio PolaRx5, ASH701945E_M
choke ring); read with ``jaxnav.io.rinex.read_rinex_obs``; elevations from the GRG SP3 orbits
(``gnss.interp.sp3_position`` + ``gnss.series.geometry_series``) at the ITRF position below.

Multipath combination (Estey & Meertens 1999, TEQC), a = (f1/f2)^2, phases L in metres:

    MP1 = P1 - (1 + 2/(a-1)) L1 + (2/(a-1)) L2
    MP2 = P2 - (2a/(a-1)) L1 + (2a/(a-1) - 1) L2

It cancels geometry, clocks, troposphere and first-order ionosphere; what is left is code
multipath + code noise + a constant per arc (ambiguities, hardware biases). Arcs break at a
gap > 30 s, a loss-of-lock indicator (bit 0, either phase) or a geometry-free phase jump
|GF_k - GF_k-1| > 0.05 m (GF = L1 - L2); each arc's mean is removed and arcs shorter than
20 min are dropped. Elevation mask 10 deg.

Elevation law (S001 eq 11, ``gnss.models.elevation_sigma``): sigma(E) = sigma0 g(E) with
g = 1 for E >= 30 deg and g = 1 / (2 sin E) below. The maximum-likelihood sigma0 for
independent Gaussian residuals r_i is

    sigma0 = sqrt(mean_i (r_i / g(E_i))^2)

(also printed: the robust 1.4826 median |r / g|, the RMS per elevation bin and its ratio to
the law, and the same for the alternative law sigma_z / sin E).

Correlation: the normalised residual z = r / g(E) of each arc gives
rho_a(k) = [sum_t z_t z_t+k / (n_a - k)] / [sum_t z_t^2 / n_a]; arcs are averaged with weights
n_a - k (the number of lag-k pairs). Model rho(0) = 1, rho(lag > 0) = A exp(-lag / tau): a
first-order Gauss-Markov part of variance A sigma0^2 plus white noise of variance
(1 - A) sigma0^2 (white_fraction = 1 - A). (A, tau) by least squares on ln rho over the lags
30 s ... the 1/e point of the correlated part (rho >= A / e; at least 3 lags; iterated from
A = 1, i.e. from the 1/e point of rho itself), with A <= 1. Also reported: the lag where rho
first drops below 1/e (log-interpolated), tau_exp of the one-parameter fit rho = exp(-lag/tau)
up to that lag, the raw drop 1 - rho(30 s), and the lag-0 correlation of two codes' residuals.

A static antenna's multipath repeats with the satellite geometry (reflector at distance h:
period ~ lambda / (2 h dE/dt cos E), minutes to tens of minutes), so tau here is a property of a
static antenna and its site; a moving car's multipath decorrelates much faster, set by speed
and environment: this data says nothing about it.

Run ``python experiments/esbc_multipath_calibration.py [--data DIR] [--json PATH] [--hours H]``.
The last line printed is the JSON summary {"<sys>/<code>": {"sigma0_m", "tau_s",
"white_fraction", "n_epochs", ...}}.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import interp, models, satellites, series, signals
from jaxnav.io.products import Sp3Orbit, read_sp3
from jaxnav.io.rinex import RinexObs, read_rinex_obs

DEFAULT_DATA = Path("/work/shared/data/esbc_static")
OBS_FILE = "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
SP3_GLOB = "*ORB.SP3.gz"
DAY_START = _dt.datetime(2020, 6, 25)

#: ESBC ITRF position (ECEF) [m].
STATION_ECEF_M = np.array([3582104.7619, 532590.1856, 5232755.1356])
MASK_DEG = 10.0
MAX_GAP_S = 30.0
GF_JUMP_M = 0.05  # = PrepareOptions.gf_slip_m
MIN_ARC_S = 1200.0
MAX_LAG_S = 1200.0
ELEV_EDGES_DEG = (10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0)
ACF_SHOW_LAGS_S = (30, 60, 120, 300, 600, 1200)
NOMINAL_TRAVEL_S = 0.075  # transmission time only moves the elevation by ~1e-5 rad

#: Requests to read_rinex_obs (codes and phases of jaxnav.io.prepare: GPS C1C, C1W, C2W, L1C,
#: L2W; Galileo band 1 and 5 through the reader's priority, C1C/C1X, C5Q/C5X, L1C/L1X, L5Q/L5X).
REQUESTS = {"G": ("C1C", "C1W", "C2W", "L1C", "L2W"), "E": ("C1", "C5", "L1", "L5")}
PHASES = {"G": ("L1C", "L2W"), "E": ("L1", "L5")}
CODE_BANDS = {"G": {"C1C": 0, "C1W": 0, "C2W": 1}, "E": {"C1": 0, "C5": 1}}  # request -> band
SYS_ID = {"G": signals.SYS_GPS, "E": signals.SYS_GAL}

SAMPLING_NOTE = (
    "note: at 30 s sampling 'white' means uncorrelated from one epoch to the next: receiver "
    "noise and any multipath with tau below ~15 s (a single GM with rho(30 s) = 0.12 has "
    "tau = 14 s) cannot be told apart."
)
STATIC_NOTE = (
    "note: a static antenna's multipath repeats with the satellite geometry (slow, minutes); "
    "a moving car's decorrelates much faster (speed, surroundings): tau here is a static-site "
    "value, not a car's; this data does not give the car's."
)


# --------------------------------------------------------------------------------------------
# Pure estimators (numpy arrays [T, S]: epochs x satellite slots; NaN where missing)
# --------------------------------------------------------------------------------------------


def mp_coefficients(f1_hz: float, f2_hz: float, band: int) -> tuple[float, float]:
    """(c1, c2) of MP = P + c1 L1 + c2 L2 for the code of ``band`` (0: P1, 1: P2)."""
    a = (f1_hz / f2_hz) ** 2
    if band == 0:
        return -(1.0 + 2.0 / (a - 1.0)), 2.0 / (a - 1.0)
    return -2.0 * a / (a - 1.0), 2.0 * a / (a - 1.0) - 1.0


def multipath_m(code_m, phase1_m, phase2_m, f1_hz: float, f2_hz: float, band: int):
    """The multipath combination MP [m] (still holding a constant per arc)."""
    c1, c2 = mp_coefficients(f1_hz, f2_hz, band)
    return code_m + c1 * phase1_m + c2 * phase2_m


def arc_labels(ok, gf_m, slip, time_s, max_gap_s=MAX_GAP_S, gf_jump_m=GF_JUMP_M):
    """Continuous-arc label per epoch and slot ([T, S] int, -1 where not ``ok``).

    An arc continues from epoch k-1 to k when both are ``ok``, t_k - t_k-1 <= max_gap_s, no
    ``slip`` flag (loss of lock) at k and |GF_k - GF_k-1| <= gf_jump_m. Labels increase slot
    by slot, in time order within a slot.
    """
    ok = np.asarray(ok, bool)
    gap_ok = np.diff(np.asarray(time_s, np.float64)) <= max_gap_s + 1e-6  # [T-1]
    with np.errstate(invalid="ignore"):
        gf_ok = np.abs(np.diff(gf_m, axis=0)) <= gf_jump_m
    cont = np.zeros_like(ok)
    cont[1:] = ok[1:] & ok[:-1] & gap_ok[:, None] & gf_ok & ~np.asarray(slip, bool)[1:]
    start = ok & ~cont
    count = np.cumsum(start.T.ravel()).reshape(start.T.shape).T  # slot-major numbering
    return np.where(ok, count - 1, -1)


def remove_arc_means(x, labels, min_epochs: int):
    """x minus its arc's mean; arcs of fewer than ``min_epochs`` become NaN / label -1."""
    lab = np.asarray(labels)
    good = lab >= 0
    n = np.bincount(lab[good], minlength=1)
    s = np.bincount(lab[good], weights=x[good], minlength=1)
    keep = good.copy()
    keep[good] = n[lab[good]] >= min_epochs
    out = np.full(x.shape, np.nan)
    out[keep] = x[keep] - (s / np.maximum(n, 1))[lab[keep]]
    return out, np.where(keep, lab, -1)


def elevation_gain(el_rad):
    """g(E) = sigma(E) / sigma0 of the simulator's law (S001 eq 11, models.elevation_sigma)."""
    return np.asarray(models.elevation_sigma(1.0, jnp.asarray(el_rad, jnp.float64)))


def sine_gain(el_rad):
    """g(E) = 1 / sin E: the alternative law sigma(E) = sigma_z / sin E, for comparison."""
    return 1.0 / np.sin(el_rad)


def sigma0_ml_m(res_m, el_rad, gain=elevation_gain) -> float:
    """Maximum-likelihood sigma0 [m]: sqrt(mean((r / g(E))^2)) over the finite residuals."""
    good = np.isfinite(res_m)
    z = res_m[good] / gain(el_rad[good])
    return float(np.sqrt(np.mean(z**2))) if z.size else math.nan


def sigma0_mad_m(res_m, el_rad, gain=elevation_gain) -> float:
    """Robust sigma0 [m]: 1.4826 median |r / g(E)| (equals sigma0 for Gaussian residuals)."""
    good = np.isfinite(res_m)
    z = res_m[good] / gain(el_rad[good])
    return float(1.4826 * np.median(np.abs(z))) if z.size else math.nan


def rms_by_elevation_m(res_m, el_rad, edges_deg=ELEV_EDGES_DEG):
    """RMS [m] and count of the residuals in each elevation bin [lo, hi) deg."""
    el_deg = np.degrees(el_rad)
    good = np.isfinite(res_m)
    rms, count = [], []
    for lo, hi in zip(edges_deg[:-1], edges_deg[1:], strict=True):
        sel = good & (el_deg >= lo) & (el_deg < hi)
        count.append(int(sel.sum()))
        rms.append(float(np.sqrt(np.mean(res_m[sel] ** 2))) if sel.any() else math.nan)
    return np.array(rms), np.array(count)


def split_arcs(z, labels) -> list[np.ndarray]:
    """The arcs of z as 1-D arrays in time order (slot-major label order)."""
    z_f, lab_f = z.T.ravel(), np.asarray(labels).T.ravel()
    keep = lab_f >= 0
    z_f, lab_f = z_f[keep], lab_f[keep]
    return np.split(z_f, np.flatnonzero(np.diff(lab_f)) + 1) if z_f.size else []


def residual_correlation(res_a_m, res_b_m) -> float:
    """Correlation coefficient of two codes' residuals at the same epochs and slots."""
    both = np.isfinite(res_a_m) & np.isfinite(res_b_m)
    if both.sum() < 3:
        return math.nan
    return float(np.corrcoef(res_a_m[both], res_b_m[both])[0, 1])


def mean_acf(arcs: Sequence[np.ndarray], max_lag: int) -> np.ndarray:
    """ACF rho(k), k = 0..max_lag, of each arc averaged over arcs with weights n_a - k."""
    num = np.zeros(max_lag + 1)
    den = np.zeros(max_lag + 1)
    for z in arcs:
        n = z.size
        c0 = np.dot(z, z) / n
        if n < 2 or c0 <= 0.0:
            continue
        for k in range(min(max_lag, n - 1) + 1):
            num[k] += np.dot(z[: n - k], z[k:]) / c0
            den[k] += n - k
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def efold_lag_s(lag_s, acf) -> float:
    """First lag [s] where the ACF drops below 1/e (NaN if never), interpolated linearly in
    ln rho between the two samples around it (exact for an exponential segment)."""
    below = np.flatnonzero(acf < math.exp(-1.0))
    if below.size == 0 or below[0] == 0:
        return math.nan
    k = int(below[0])
    x0, x1 = float(lag_s[k - 1]), float(lag_s[k])
    y0, y1 = float(acf[k - 1]), float(acf[k])
    if y1 > 0.0:
        return x0 + math.log(y0 * math.e) / math.log(y0 / y1) * (x1 - x0)
    return x0 + (y0 - math.exp(-1.0)) / (y0 - y1) * (x1 - x0)


def _log_fit(lag_s, acf, free_amplitude: bool) -> tuple[float, float]:
    """(A, tau) of ln rho = ln A - lag / tau by least squares (ln A <= 0; A = 1 if fixed)."""
    x, y = lag_s[acf > 0], np.log(acf[acf > 0])
    if x.size == 0 or (free_amplitude and x.size < 2):
        return math.nan, math.nan
    if free_amplitude:
        slope, intercept = np.polyfit(x, y, 1)
        if intercept <= 0.0:
            return float(math.exp(intercept)), (-1.0 / slope if slope < 0 else math.inf)
    slope = float(np.dot(x, y) / np.dot(x, x))  # through the origin: A = 1
    return 1.0, (-1.0 / slope if slope < 0 else math.inf)


def fit_exponential_tau_s(lag_s, acf) -> float:
    """tau [s] of rho = exp(-lag / tau) (no white part) fitted on 0 < lag <= the 1/e lag
    (at least the first lag)."""
    lag_s, acf = np.asarray(lag_s, np.float64), np.asarray(acf, np.float64)
    upto = efold_lag_s(lag_s, acf)
    sel = (lag_s > 0) & ((lag_s <= upto) | (lag_s <= lag_s[1]) | ~np.isfinite(upto))
    return _log_fit(lag_s[sel], acf[sel], free_amplitude=False)[1]


def fit_gauss_markov(lag_s, acf, min_points: int = 3, max_iter: int = 20) -> tuple[float, float]:
    """(A, tau_s) of rho(lag > 0) = A exp(-lag / tau), 0 < A <= 1 (white fraction 1 - A).

    Least squares on ln rho over the first n lags > 0, n = max(min_points, the number of
    leading lags with rho >= A / e), i.e. up to the 1/e point of the correlated part; starts
    from A = 1 (the 1/e point of rho itself) and iterates until n is stable.
    """
    lag_s, acf = np.asarray(lag_s, np.float64)[1:], np.asarray(acf, np.float64)[1:]
    amp, tau, n = 1.0, math.nan, -1
    for _ in range(max_iter):
        lead = np.cumprod(acf >= amp * math.exp(-1.0))
        n_new = min(max(min_points, int(lead.sum())), acf.size)
        if n_new == n:
            break
        n = n_new
        amp, tau = _log_fit(lag_s[:n], acf[:n], free_amplitude=True)
        if not math.isfinite(amp):
            break
    return amp, tau


def calibrate_code(mp_m, gf_m, slip, el_rad, time_s, interval_s: float) -> dict:
    """Every figure of one code from its raw MP [T, S], GF phase, slip flags and elevations."""
    ok = np.isfinite(mp_m) & np.isfinite(gf_m) & np.isfinite(el_rad)
    ok &= el_rad >= math.radians(MASK_DEG)
    labels = arc_labels(ok, gf_m, slip, time_s)
    res_m, labels = remove_arc_means(np.where(ok, mp_m, 0.0), labels, _min_epochs(interval_s))
    sigma0 = sigma0_ml_m(res_m, el_rad)
    rms, count = rms_by_elevation_m(res_m, el_rad)
    z = np.where(np.isfinite(res_m), res_m, 0.0) / elevation_gain(np.where(ok, el_rad, 1.0))
    arcs = split_arcs(z, labels)
    max_lag = int(round(MAX_LAG_S / interval_s))
    lag_s = interval_s * np.arange(max_lag + 1)
    acf = mean_acf(arcs, max_lag)
    efold = efold_lag_s(lag_s, acf)
    amp, tau = fit_gauss_markov(lag_s, acf)
    return {
        "res_m": res_m,
        "n_arcs": len(arcs),
        "n_epochs": int(np.isfinite(res_m).sum()),
        "sigma0_m": sigma0,
        "sigma0_mad_m": sigma0_mad_m(res_m, el_rad),
        "sigma_z_sine_m": sigma0_ml_m(res_m, el_rad, sine_gain),
        "rms_bin_m": rms,
        "count_bin": count,
        "lag_s": lag_s,
        "acf": acf,
        "efold_lag_s": efold,
        "tau_single_s": fit_exponential_tau_s(lag_s, acf),
        "tau_s": tau,
        "white_fraction": 1.0 - amp,
        "acf_drop_30s": float(1.0 - acf[1]) if acf.size > 1 else math.nan,
    }


def _min_epochs(interval_s: float) -> int:
    return int(math.ceil(MIN_ARC_S / interval_s - 1e-9))


# --------------------------------------------------------------------------------------------
# Data: observations, elevations, per-code series
# --------------------------------------------------------------------------------------------


def read_observations(data_dir: Path, systems=("G", "E"), hours: float = 24.0) -> RinexObs:
    """The ESBC codes and phases (with loss-of-lock indicators) of the first ``hours``."""
    tlim = None
    if hours < 24.0:
        tlim = (DAY_START, DAY_START + _dt.timedelta(hours=hours, seconds=-1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gap-filling notices
        return read_rinex_obs(
            data_dir / OBS_FILE, {s: REQUESTS[s] for s in systems}, tlim=tlim, indicators=True
        )


def read_orbits(data_dir: Path) -> Sp3Orbit:
    paths = sorted(data_dir.glob(SP3_GLOB))
    if not paths:
        raise FileNotFoundError(f"no SP3 orbit file ({SP3_GLOB}) in {data_dir}")
    return read_sp3(paths)


def elevation_rad(orbit: Sp3Orbit, sv: Sequence[str], time_gps_s, rx_ecef_m=STATION_ECEF_M):
    """Elevation [T, S] (NaN without orbit) of satellites ``sv`` seen from ``rx_ecef_m``.

    SP3 Lagrange interpolation at t_rx - 75 ms, one-sided windows allowed at the file end
    (metre-level orbit error there is nothing in an elevation); Earth rotation during the
    travel time by ``series.geometry_series``.
    """
    sp3_sv = orbit.sv.tolist()
    have = np.array([s in sp3_sv for s in sv])
    cols = np.array([sp3_sv.index(s) if s in sp3_sv else 0 for s in sv])
    tab = satellites.sub_grid(interp.orbit_table(orbit), cols)
    t_tx = jnp.asarray(np.asarray(time_gps_s, np.float64) - NOMINAL_TRAVEL_S)
    pos, valid = jax.vmap(lambda t: interp.sp3_position(tab, t, 10, True))(t_tx)
    T, S = pos.shape[:2]
    rx = jnp.tile(jnp.asarray(rx_ecef_m, jnp.float64), (T, 1))
    _, el, _, _, _ = series.geometry_series(rx, pos, jnp.zeros((T, S)))
    ok = np.asarray(valid) & have[None, :]
    return np.where(ok, np.asarray(el), np.nan)


def code_inputs(obs: RinexObs, letter: str) -> dict[str, tuple]:
    """code label -> (MP [T, S] m, GF [T, S] m, slip [T, S] bool) of one constellation."""
    so = obs.systems[letter]
    f1 = float(signals.carrier_frequency_hz(SYS_ID[letter], 0))
    f2 = float(signals.carrier_frequency_hz(SYS_ID[letter], 1))
    p1, p2 = PHASES[letter]
    l1_m = so.obs[p1] * (C_LIGHT / f1)
    l2_m = so.obs[p2] * (C_LIGHT / f2)
    slip = np.zeros(l1_m.shape, bool)
    for p in (p1, p2):
        if p in so.lli:
            slip |= (so.lli[p].astype(np.int64) & 1) > 0
    out = {}
    for req, band in CODE_BANDS[letter].items():
        code = so.codes.get(req)
        if code is None:
            continue
        out[code] = (multipath_m(so.obs[req], l1_m, l2_m, f1, f2, band), l1_m - l2_m, slip)
    return out


def calibrate(data_dir: Path, systems=("G", "E"), hours: float = 24.0) -> dict[str, dict]:
    """'<sys>/<code>' -> ``calibrate_code`` figures, for the ESBC data in ``data_dir``."""
    obs = read_observations(data_dir, systems, hours)
    orbit = read_orbits(data_dir)
    out = {}
    for letter in systems:
        el = elevation_rad(orbit, [str(s) for s in obs.systems[letter].sv], obs.time_gps_s)
        for code, (mp_m, gf_m, slip) in code_inputs(obs, letter).items():
            out[f"{letter}/{code}"] = calibrate_code(
                mp_m, gf_m, slip, el, obs.time_gps_s, obs.interval_s
            )
    return out


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def _f(x, fmt=".3f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def _bin_names() -> list[str]:
    pairs = zip(ELEV_EDGES_DEG[:-1], ELEV_EDGES_DEG[1:], strict=True)
    return [f"{lo:g}-{hi:g}" for lo, hi in pairs]


def _bin_mid_rad() -> np.ndarray:
    edges = np.radians(ELEV_EDGES_DEG)
    return 0.5 * (edges[:-1] + edges[1:])


def _elevation_table(results: dict[str, dict]) -> list[str]:
    bins = _bin_names()
    head = ["code", "arcs", "epochs", "sigma0_m", "sig0_mad_m", *[f"rms{b}" for b in bins]]
    rows = [
        [k, r["n_arcs"], r["n_epochs"], _f(r["sigma0_m"]), _f(r["sigma0_mad_m"])]
        + [_f(v) for v in r["rms_bin_m"]]
        for k, r in results.items()
    ]
    counts = [[k, *r["count_bin"]] for k, r in results.items()]
    return [
        "Code multipath + noise (MP, arc mean removed, mask 10 deg): sigma0 of the S001 law "
        "(ML, and robust 1.4826 MAD), RMS [m] per elevation bin [deg]:",
        _columns(head, rows),
        "",
        "Epochs per elevation bin:",
        _columns(["code", *[f"n{b}" for b in bins]], counts),
        "",
    ]


def _law_tables(results: dict[str, dict]) -> list[str]:
    bins, mid = _bin_names(), _bin_mid_rad()
    out = []
    for title, key, gain in (
        ("S001 law sigma0 g(E), g = 1 (E >= 30), 1/(2 sin E) below", "sigma0_m", elevation_gain),
        ("alternative law sigma_z / sin E", "sigma_z_sine_m", sine_gain),
    ):
        rows = [
            [k, _f(r[key]), *[_f(v, ".2f") for v in r["rms_bin_m"] / (r[key] * gain(mid))]]
            for k, r in results.items()
        ]
        out += [
            f"RMS / model at the bin centre, {title} (1 = fits):",
            _columns(["code", "sigma_m", *[f"r{b}" for b in bins]], rows),
            "",
        ]
    return out


def _correlation_table(results: dict[str, dict]) -> list[str]:
    idx = [int(round(s / _interval(results))) for s in ACF_SHOW_LAGS_S]
    keys = ("white_fraction", "acf_drop_30s", "efold_lag_s", "tau_single_s", "tau_s")
    head = ["code", "white_frac", "drop30s", "1/e_lag_s", "tau_exp_s", "tau_gm_s"]
    head += [f"rho({s}s)" for s in ACF_SHOW_LAGS_S]
    rows = [
        [k, *[_f(r[q], ".2f" if q in keys[:2] else ".0f") for q in keys]]
        + [_f(r["acf"][i], ".3f") for i in idx]
        for k, r in results.items()
    ]
    names = list(results)
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :] if a[0] == b[0]]
    corr = [
        f"  {a} ~ {b}: {_f(residual_correlation(results[a]['res_m'], results[b]['res_m']))}"
        for a, b in pairs
    ]
    return [
        "Correlation of r / g(E): white_frac = 1 - A and tau_gm of rho = A exp(-lag/tau) "
        "(lag > 0); tau_exp of rho = exp(-lag/tau) up to the 1/e lag; drop30s = 1 - rho(30 s):",
        _columns(head, rows),
        "",
        "Correlation coefficient of the residuals of two codes at the same epochs (lag 0):",
        *corr,
        "",
    ]


def format_tables(results: dict[str, dict]) -> str:
    """The printed report: elevation table, fit-of-the-law tables, correlation table, notes."""
    lines = _elevation_table(results) + _law_tables(results) + _correlation_table(results)
    return "\n".join([*lines, SAMPLING_NOTE, STATIC_NOTE])


def _interval(results: dict[str, dict]) -> float:
    lag_s = next(iter(results.values()))["lag_s"]
    return float(lag_s[1] - lag_s[0])


def _columns(head, rows) -> str:
    width = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    fmt_row = lambda r: "  ".join(str(x).rjust(w) for x, w in zip(r, width, strict=True))
    return "\n".join([fmt_row(head), *[fmt_row(r) for r in rows]])


def summary(results: dict[str, dict]) -> dict[str, dict]:
    def num(x, nd):
        return round(float(x), nd) if math.isfinite(x) else None

    return {
        key: {
            "sigma0_m": num(r["sigma0_m"], 4),
            "tau_s": num(r["tau_s"], 1),
            "white_fraction": num(r["white_fraction"], 3),
            "n_epochs": r["n_epochs"],
            "white_sigma0_m": num(r["sigma0_m"] * math.sqrt(max(r["white_fraction"], 0.0)), 4),
            "gm_sigma0_m": num(r["sigma0_m"] * math.sqrt(max(1.0 - r["white_fraction"], 0.0)), 4),
            "tau_exp_s": num(r["tau_single_s"], 1),
            "sigma0_mad_m": num(r["sigma0_mad_m"], 4),
            "sigma_z_sine_m": num(r["sigma_z_sine_m"], 4),
            "n_arcs": r["n_arcs"],
            "efold_lag_s": num(r["efold_lag_s"], 1),
            "acf_drop_30s": num(r["acf_drop_30s"], 3),
        }
        for key, r in results.items()
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="experiments/esbc_multipath_calibration.py",
        description="Calibrate code-multipath sigma0 and correlation time from ESBC00DNK.",
    )
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="ESBC data folder")
    ap.add_argument("--json", type=Path, default=None, help="also write the JSON summary here")
    ap.add_argument("--hours", type=float, default=24.0, help="use the first H hours (<= 24)")
    args = ap.parse_args(argv)
    if not (args.data / OBS_FILE).is_file():
        print(
            f"error: ESBC data folder {args.data} missing (or without {OBS_FILE})", file=sys.stderr
        )
        return 2
    t0 = time.perf_counter()
    results = calibrate(args.data, hours=args.hours)
    print(format_tables(results))
    print(f"runtime: {time.perf_counter() - t0:.1f} s")
    out = summary(results)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
