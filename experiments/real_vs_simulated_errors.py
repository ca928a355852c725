"""Real versus simulated GNSS errors: the same outage study on both (issue 17).

The replay source (``configs/esbc_replay.toml``: ESBC00DNK's observations moved onto a circuit
around the station) and its simulated twin (``study.replay.SimulatedTwin``: the same circuit,
IMU noise, satellites from the day's broadcast orbits, 30-s epochs and filters, with the
simulator's GNSS errors) run the same sweep. Where they differ, the simulator's errors are
too optimistic or too pessimistic for that mode. Beside it:

- the same runs without outages: horizontal RMS after convergence, the filter's own consistency
  ((error / sigma)^2 per axis) and its innovations (mean NIS per used row, gated rows) in both
  worlds;
- the error sources taken apart on the observations themselves (no filter), per elevation bin,
  at the true antenna: the ionosphere-free code minus carrier with each arc's mean removed
  (code multipath + noise), and the ionosphere-free carrier minus the true range, product
  satellite clock and the filters' a-priori troposphere, with a receiver clock per epoch and an
  ambiguity per arc fitted (least squares, alternating projections) - once without and once
  with a zenith wet delay per epoch (mapping m_w). What the ZWD column removes is troposphere
  (and anything shaped like it); what remains is products, carrier multipath, noise and the
  unmodelled antenna phase centres.

Run: ``python experiments/real_vs_simulated_errors.py [--quick] [--out DIR] [--report-only]``
(needs ../shared/data; the full run takes ~10 min on 2 cores, sweeps resume; ``--quick`` sweeps
into ``sweep-quick-*`` beside the full run's ``sweep-*``; ``--report-only`` rewrites the report
and figure from the CSV / JSON files of the last run, e.g. after editing the discussion).
Writes ``report.md``, the tables as CSV and ``real_vs_simulated.png`` to
``experiments/results/real_vs_simulated_errors/``; the discussion is hand-written in
``discussion.md`` there, after reading a full run.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import jax  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402

import jaxnav  # noqa: E402, F401
from jaxnav import geodesy  # noqa: E402
from jaxnav.gnss import corrections, models  # noqa: E402
from jaxnav.gnss.ppp_data import combos  # noqa: E402
from jaxnav.study import config, report, sweep  # noqa: E402
from jaxnav.study.reference import single_run  # noqa: E402
from jaxnav.study.replay import SimulatedTwin  # noqa: E402
from jaxnav.study.sources import factory_for  # noqa: E402

NAME = "real_vs_simulated_errors"
STUDY_TOML = Path(__file__).resolve().parents[1] / "configs" / "esbc_replay.toml"
DISCUSSION_PATH = Path(__file__).resolve().parent / "results" / NAME / "discussion.md"
WORLDS = ("real", "simulated")
#: Elevation bins [deg] of the residual diagnostic.
ELEV_EDGES_DEG = (10, 15, 20, 30, 45, 60, 90)
#: Arcs shorter than this [epochs] are left out of the residual diagnostic (an arc mean over a
#: few epochs removes most of the error it should measure). 20 epochs = 10 min at 30 s.
MIN_ARC_EPOCHS = 20
#: The per-epoch fits of the carrier residual need this many satellites.
MIN_SATS = 4
#: Tight-filter row kinds (``EpochOutput.used_by_kind``).
KINDS = ("code", "phase", "Doppler", "iono")


def _study(quick: bool) -> config.StudyConfig:
    base = config.load(STUDY_TOML)
    study = {
        "name": NAME,
        "modes": ["df_code", "float_ppp"] if quick else ["df_code", "float_ppp", "ic_ppp"],
        # one system: with RISS16 too the full run took > 12 min on 2 cores
        "systems": ["ins15"],
        "durations_s": [60] if quick else [60, 300],
        "satellites_kept": [0, 3, "all"] if quick else [0, 2, 3, "all"],
        "policies": ["highest"],
        "realizations": 1 if quick else 2,
        "seed": 0,
        "recovery_s": 120 if quick else 300,
        "chunk_size": 64,
        "max_traces": 4,
    }
    scenario = dict(base.scenario_dict)
    if quick:
        scenario["duration_s"] = 2700
    placement = {"kind": "grid", "convergence_s": 1800 if quick else 3600, "spacing_s": 600}
    return config.from_dict({"study": study, "placement": placement,
                             "metrics": {"pre_s": 30}, "scenario": scenario},
                            base_dir=STUDY_TOML.parent)


# ------------------------------------------------------------------------------------------------
# No outage: accuracy and consistency of each (mode, system)
# ------------------------------------------------------------------------------------------------
def _consistency(factory, cfg, after_s: float) -> tuple[pd.DataFrame, object]:
    """No outage, realisation 0 (seed ``cfg.seed``): horizontal RMS after ``after_s``, mean
    (error/sigma)^2 per axis, mean NIS per used row and the share of offered code / phase rows
    the gates rejected. Also returns the first dual-frequency problem (for ``_residuals``)."""
    rows, problem = [], None
    for mode in cfg.modes:
        for system in cfg.systems:
            prob = factory.build(cfg, mode, system, cfg.seed)
            if problem is None:
                problem = prob
            run = single_run(prob, factory.ops_for(mode, system), epoch_dt_s=30.0)
            late = run.time_s >= after_s
            e, s = run.error_enu_m[late], run.sigma_enu_m[late]
            z2 = np.mean((e / s) ** 2, axis=0)
            out = run.output
            nis, dof = np.asarray(out.nis)[late], np.asarray(out.dof)[late]
            used = np.asarray(out.used_by_kind)[late].sum(axis=0)
            gated = np.asarray(out.gated_by_kind)[late].sum(axis=0)
            offered = np.maximum(used + gated, 1)
            rows.append(dict(mode=mode, system=system,
                             rms_2d_m=float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
                             z2_e=z2[0], z2_n=z2[1], z2_u=z2[2],
                             nis_per_row=float(nis.sum() / max(dof.sum(), 1)),
                             gated_code=float(gated[0] / offered[0]),
                             gated_phase=float(gated[1] / offered[1])))
    return pd.DataFrame(rows), problem


# ------------------------------------------------------------------------------------------------
# The error sources on the observations themselves
# ------------------------------------------------------------------------------------------------
def _arc_labels(ok: np.ndarray, slip: np.ndarray) -> np.ndarray:
    """[T, S] arc index (-1 where not used): a new arc at a slot's first used epoch after a gap
    and at every slip flag; arcs shorter than ``MIN_ARC_EPOCHS`` get -1."""
    T, S = ok.shape
    prev = np.vstack([np.zeros((1, S), bool), ok[:-1]])
    start = ok & (~prev | slip)
    counter = np.cumsum(start, axis=0) + (T + 1) * np.arange(S)[None, :]
    labels = np.where(ok, counter, -1)
    _, inverse, counts = np.unique(labels[ok], return_inverse=True, return_counts=True)
    out = np.full((T, S), -1)
    out[ok] = np.where(counts[inverse] >= MIN_ARC_EPOCHS, inverse, -1)
    return out


def _remove_arc_means(x: np.ndarray, arc: np.ndarray) -> np.ndarray:
    m = (arc >= 0) & np.isfinite(x)
    size = int(arc.max()) + 1 if m.any() else 0
    n = np.bincount(arc[m], minlength=size)
    mean = np.bincount(arc[m], weights=x[m], minlength=size) / np.maximum(n, 1)
    out = np.full_like(x, np.nan)
    out[m] = x[m] - mean[arc[m]]
    return out


def _fit_residual(x: np.ndarray, arc: np.ndarray, m_w: np.ndarray,
                  zwd: str | None) -> tuple[np.ndarray, float]:
    """x [T, S] minus its least-squares fit on a clock per epoch, an ambiguity per arc and, for
    ``zwd`` = "constant" / "epoch", a zenith wet delay (one for the window / one per epoch)
    mapped by m_w; returns the residual (NaN where unused) and the constant ZWD [m] (NaN
    otherwise). The clock / ambiguity datum defect is left to the minimum-norm solution."""
    use = arc >= 0
    t_idx, s_idx = np.nonzero(use)
    epochs, t_col = np.unique(t_idx, return_inverse=True)
    cols = [np.eye(epochs.size)[t_col]]
    cols.append(np.eye(int(arc[use].max()) + 1)[arc[use]])
    if zwd == "constant":
        cols.append(m_w[use][:, None])
    elif zwd == "epoch":
        cols.append(np.eye(epochs.size)[t_col] * m_w[use][:, None])
    A = np.hstack(cols)
    y = x[use]
    beta, *_ = np.linalg.lstsq(A, y - np.mean(y), rcond=None)
    out = np.full(x.shape, np.nan)
    out[t_idx, s_idx] = y - np.mean(y) - A @ beta
    return out, float(beta[-1]) if zwd == "constant" else np.nan


def _residuals(factory, prob) -> pd.DataFrame:
    """Per elevation bin: RMS of the IF code minus carrier (arc means removed) and of the IF
    carrier residual after the clock + arc fit and after the clock + ZWD + arc fit, at the true
    antenna, for the observations of ``prob`` (``factory.geo``'s epochs 1..T)."""
    obs = prob.inputs.obs
    pos = factory.geo.ant_pos_ecef[1:]
    vel = factory.geo.ant_vel_ecef[1:]
    comb = jax.vmap(combos, in_axes=(None, 0))(prob.tf.slots, obs)
    geo = jax.vmap(models.geometry)(pos, vel, obs.sat)
    rho = np.asarray(geo.range_m)
    rate = np.asarray(obs.range_rate_m_s) - np.asarray(geo.range_rate_m_s) + np.asarray(
        obs.sat.clock_rate_m_s)
    llh = np.asarray(jax.vmap(geodesy.ecef_to_llh)(pos))
    el = np.asarray(prob.elevation)
    lat, h = llh[:, :1], llh[:, 2:3]
    doy = np.asarray(prob.inputs.day_of_year).reshape(-1, 1)
    m_h, m_w = (np.asarray(a) for a in corrections.niell_mapping(np.maximum(el, 0.05), lat, h,
                                                                  doy))
    trop = m_h * np.asarray(corrections.saastamoinen_zhd_m(lat, h)) + m_w * np.asarray(
        corrections.saastamoinen_zwd_m(h))
    code_if, phase_if = np.asarray(comb.code_if_m), np.asarray(comb.phase_if_m)
    ok = (np.asarray(obs.available) & (el >= np.radians(ELEV_EDGES_DEG[0]))
          & np.isfinite(code_if) & np.isfinite(phase_if))
    arc = _arc_labels(ok, np.asarray(obs.slip))
    # enough satellites per epoch for the per-epoch fits
    few = (arc >= 0).sum(axis=1) < MIN_SATS
    arc[few] = -1
    # subtract the large constants (receiver clock ~ km, ambiguities ~ 1e4 km) per arc first
    phase = phase_if - rho + np.asarray(obs.sat.clock_m) - trop
    cmc = _remove_arc_means(code_if - phase_if, arc)
    phase = _remove_arc_means(phase, arc)
    clock_arc, _ = _fit_residual(phase, arc, m_w, None)
    clock_zwd0_arc, zwd0 = _fit_residual(phase, arc, m_w, "constant")
    clock_zwd_arc, _ = _fit_residual(phase, arc, m_w, "epoch")
    # Doppler: range-rate residual minus the per-epoch mean (the receiver clock drift)
    rate = np.where((arc >= 0) & np.asarray(obs.doppler_ok) & np.isfinite(rate), rate, np.nan)
    rate = rate - np.nanmean(rate, axis=1, keepdims=True)
    el_deg = np.degrees(el)
    rows = []
    for lo, hi in zip(ELEV_EDGES_DEG[:-1], ELEV_EDGES_DEG[1:], strict=True):
        b = (arc >= 0) & (el_deg >= lo) & (el_deg < hi)

        def rms(x, b=b):
            return float(np.sqrt(np.nanmean(x[b] ** 2))) if b.any() else np.nan

        rows.append(dict(elev=f"{lo}-{hi}", n=int(b.sum()), cmc_m=rms(cmc),
                         doppler_m_s=rms(rate), carrier_m=rms(clock_arc),
                         carrier_zwd0_m=rms(clock_zwd0_arc), carrier_zwd_m=rms(clock_zwd_arc)))
    b = arc >= 0

    def rms_all(x):
        return float(np.sqrt(np.nanmean(x[b] ** 2)))

    rows.append(dict(elev="all", n=int(b.sum()), cmc_m=rms_all(cmc),
                     doppler_m_s=rms_all(rate), carrier_m=rms_all(clock_arc),
                     carrier_zwd0_m=rms_all(clock_zwd0_arc), carrier_zwd_m=rms_all(clock_zwd_arc)))
    df = pd.DataFrame(rows)
    df.attrs["zwd_offset_m"] = zwd0
    # per-arc code bias: IF code minus truth, clock removed per epoch (median), mean per arc
    code = np.where(arc >= 0, code_if - rho + np.asarray(obs.sat.clock_m) - trop, np.nan)
    code = code - np.nanmedian(code, axis=1, keepdims=True)
    ids = np.unique(arc[b])
    means = np.array([np.nanmean(code[arc == a]) for a in ids])
    lens = np.array([int((arc == a).sum()) for a in ids])
    df.attrs["code_arc_bias_m"] = float(np.sqrt(np.sum(lens * means**2) / lens.sum()))
    df.attrs["satellites_per_epoch"] = float(b.sum(axis=1).mean())
    df.attrs["arcs"] = int(len(np.unique(arc[b])))
    return df


# ------------------------------------------------------------------------------------------------
# The twin calibrated on the replay, one error source after another
# ------------------------------------------------------------------------------------------------
def _variant(twin: SimulatedTwin, params) -> SimulatedTwin:
    """A copy of ``twin`` whose simulator draws with ``params`` (same drive, slots, geometry and
    keys: the same normalised noise, scaled)."""
    v = SimulatedTwin(twin.replay)
    v.cfg = dataclasses.replace(twin.cfg, obs_params=params)
    v.__dict__["geo"] = twin.geo
    return v


def _calibration_steps(replay, twin, resid: dict) -> tuple[list, dict]:
    """Variants of the twin: (label, factory, cumulative?) and the factors used. Cumulative,
    each error source set to the size the diagnostic measured on the replay: code (white +
    multipath of every code) scaled by the CMC RMS ratio real / sim; Doppler noise scaled by the
    Doppler residual ratio; the simulated wet delay raised (``rel_humidity``, the simulator's
    wet a-priori) by the difference of the fitted constant ZWD offsets. Then two single
    changes of the defaults, the slow errors the diagnostic cannot size (an arc's ambiguity
    absorbs them): code multipath correlation time 600 s, precise orbit and clock errors x 2."""
    real, sim = resid["real"].iloc[-1], resid["simulated"].iloc[-1]
    p = twin.cfg.obs_params
    # Python floats: a NumPy scalar in the (static) ScenarioConfig makes equinox warn
    r_code = float(real.cmc_m / sim.cmc_m)
    r_dop = float(real.doppler_m_s / sim.doppler_m_s)
    h = float(geodesy.ecef_to_llh(jax.numpy.asarray(replay.station_ecef))[2])
    zwd0 = float(corrections.saastamoinen_zwd_m(h, p.rel_humidity))
    d_zwd = float(resid["real"].attrs["zwd_offset_m"] - resid["simulated"].attrs["zwd_offset_m"])
    rh = float(p.rel_humidity * (1.0 + d_zwd / zwd0))
    p1 = p._replace(code_sigma0_m=tuple(r_code * c for c in p.code_sigma0_m),
                    multipath_code_sigma0_m=r_code * p.multipath_code_sigma0_m)
    p2 = p1._replace(doppler_sigma0_m_s=r_dop * p.doppler_sigma0_m_s)
    p3 = p2._replace(rel_humidity=rh)
    steps = [
        ("twin (simulator defaults)", twin),
        (f"+ code x {r_code:.2f}", _variant(twin, p1)),
        (f"+ Doppler x {r_dop:.3f}", _variant(twin, p2)),
        (f"+ ZWD {100 * d_zwd:+.1f} cm (rel_humidity {rh:.2f})", _variant(twin, p3)),
        ("defaults, code multipath tau 600 s (alone)",
         _variant(twin, p._replace(multipath_tau_s=600.0))),
        ("defaults, orbit and clock errors x 2 (alone)",
         _variant(twin, p._replace(orbit_sigma_m=2 * p.orbit_sigma_m,
                                   sat_clock_sigma_m=2 * p.sat_clock_sigma_m))),
    ]
    return steps, dict(r_code=r_code, r_doppler=r_dop, d_zwd_m=d_zwd, rel_humidity=rh)


def _calibration_runs(steps, cfg, system: str, after_s: float) -> pd.DataFrame:
    """No-outage runs (realisation 0) of the DF code and float PPP modes on each variant, and
    the variant's own residual diagnostic (does the knob give the replay's size?)."""
    rows = []
    modes = [m for m in ("df_code", "float_ppp") if m in cfg.modes]
    for label, f in steps:
        row = dict(step=label)
        prob = None
        for mode in modes:
            prob = f.build(cfg, mode, system, cfg.seed)
            run = single_run(prob, f.ops_for(mode, system), epoch_dt_s=30.0)
            late = run.time_s >= after_s
            e, s = run.error_enu_m[late], run.sigma_enu_m[late]
            row[f"rms_{mode}"] = float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1))))
            row[f"z2_{mode}"] = "{:.2f} / {:.2f} / {:.2f}".format(
                *np.mean((e / s) ** 2, axis=0))
        d = _residuals(f, prob)
        row.update(cmc_m=d.iloc[-1].cmc_m, doppler_m_s=d.iloc[-1].doppler_m_s,
                   zwd_offset_m=d.attrs["zwd_offset_m"],
                   code_arc_bias_m=d.attrs["code_arc_bias_m"])
        rows.append(row)
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------------------------
# Tables and figure
# ------------------------------------------------------------------------------------------------
def _kept(k) -> str:
    return "all" if int(k) == sweep.ALL else str(int(k))


def _outage_tables(both: pd.DataFrame, modes, kept_levels) -> tuple[str, str]:
    """(one row per system, outage and kept with 'real / sim' per mode; the geometric mean of
    sim / real per mode and kept over the systems and outage lengths)."""
    rows = []
    for (system, dur, k), g in both.groupby(["system", "duration_s", "satellites_kept"],
                                           sort=False):
        cells = []
        for mode in modes:
            r = g[g["mode"] == mode]
            cells.append(f"{r.mean_real.iloc[0]:.2f} / {r.mean_sim.iloc[0]:.2f}"
                         if len(r) else "-")
        rows.append((system, f"{dur:g}", _kept(k), f"{int(g.n.iloc[0])}", *cells))
    detail = common.markdown_table(["system", "outage s", "kept", "outages", *modes], rows)
    geo = []
    for k in kept_levels:
        cells = []
        for mode in modes:
            r = both[(both.satellites_kept == k) & (both["mode"] == mode)]
            cells.append(float(np.exp(np.mean(np.log(r.sim_over_real)))) if len(r) else None)
        geo.append((_kept(k), *cells))
    return detail, common.markdown_table(["kept", *modes], geo)


def _figure(both: pd.DataFrame, res_both: pd.DataFrame, path: Path) -> None:
    """Outages (top left), then the diagnostic per elevation bin: Doppler, code minus carrier,
    carrier residual."""
    fig, axes = plt.subplots(2, 2, figsize=(14, 10))
    ax = axes[0][0]
    sub = both[both.satellites_kept != sweep.ALL]
    several = sub.system.nunique() > 1
    x = np.arange(len(sub))
    ax.bar(x - 0.2, sub.mean_real, 0.4, label="real errors (replay)")
    ax.bar(x + 0.2, sub.mean_sim, 0.4, label="simulated errors (twin)")
    ax.set_xticks(x, [f"{r.system + ' ' if several else ''}{r.mode} {r.duration_s:g}s "
                      f"k{_kept(r.satellites_kept)}" for r in sub.itertuples()],
                  fontsize=8, rotation=90)
    ax.set_yscale("log")
    ax.set_ylabel("mean maximum 2D error [m]")
    ax.set_title(f"{', '.join(sub.system.unique())}: outages (k = satellites kept)")
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=9)
    mid = [0.5 * (a + b) for a, b in zip(ELEV_EDGES_DEG[:-1], ELEV_EDGES_DEG[1:], strict=True)]
    bins = res_both[res_both.elev != "all"]
    style = {"real": dict(color="C0", marker="o"), "sim": dict(color="C1", marker="s")}
    names = {"real": "real", "sim": "simulated"}
    panels = [
        (axes[0][1], "doppler_m_s", 100.0, "RMS [cm/s]",
         "f1 Doppler minus true range rate, clock drift removed"),
        (axes[1][0], "cmc_m", 1.0, "RMS [m]",
         "IF code minus carrier (code multipath + noise), arc means removed"),
    ]
    for ax, col, scale, ylabel, title in panels:
        for w in style:
            ax.plot(mid, scale * bins[f"{col}_{w}"], label=names[w], **style[w])
        ax.set_yscale("log")
        ax.set_xlabel("elevation [deg]")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=9)
    ax = axes[1][1]
    for w in style:
        ax.plot(mid, 100 * bins[f"carrier_m_{w}"], label=f"{names[w]}: clock + arc fitted",
                **style[w])
        ax.plot(mid, 100 * bins[f"carrier_zwd0_m_{w}"], ls="--",
                label=f"{names[w]}: clock + constant ZWD + arc fitted", **style[w])
    ax.set_xlabel("elevation [deg]")
    ax.set_ylabel("RMS [cm]")
    ax.set_title("IF carrier minus true range, clock, a-priori troposphere")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------
# The run (compute -> CSV + summary.json) and the report (from those files)
# ------------------------------------------------------------------------------------------------
def compute(out: Path, quick: bool) -> None:
    """Run the sweeps, the no-outage runs, the diagnostic and the calibrated twins; write
    ``outages.csv``, ``no_outage.csv``, ``residuals.csv``, ``calibration.csv`` and
    ``summary.json`` to ``out``."""
    cfg = _study(quick)
    replay = factory_for(cfg.scenario_dict, STUDY_TOML.parent)
    twin = SimulatedTwin(replay)
    timings, stats, tables, checks, resid = {}, {}, {}, {}, {}
    for label, factory in zip(WORLDS, (replay, twin), strict=True):
        t = time.time()
        sweep_dir = out / (f"sweep-quick-{label}" if quick else f"sweep-{label}")
        res = sweep.run_sweep(cfg, factory, sweep_dir, resume=True, progress=False)
        timings[f"sweep {label}"] = time.time() - t
        stats[label] = res.stats
        tables[label] = report.table_by_satellites(res.dataset)
        t = time.time()
        checks[label], prob = _consistency(factory, cfg, cfg.placement.convergence_s)
        timings[f"no-outage runs {label}"] = time.time() - t
        t = time.time()
        resid[label] = _residuals(factory, prob)
        timings[f"residual diagnostic {label}"] = time.time() - t

    keys = ["system", "duration_s", "satellites_kept", "mode"]
    both = tables["real"][keys + ["n", "mean"]].merge(
        tables["simulated"][keys + ["mean"]], on=keys, suffixes=("_real", "_sim"))
    both["sim_over_real"] = both["mean_sim"] / both["mean_real"]
    both.to_csv(out / "outages.csv", index=False)
    cons = checks["real"].merge(checks["simulated"], on=["mode", "system"],
                                suffixes=("_real", "_sim"))
    cons.to_csv(out / "no_outage.csv", index=False)
    res_both = resid["real"].merge(resid["simulated"], on="elev", suffixes=("_real", "_sim"))
    res_both.to_csv(out / "residuals.csv", index=False)

    t = time.time()
    system = "ins15" if "ins15" in cfg.systems else cfg.systems[0]
    steps, factors = _calibration_steps(replay, twin, resid)
    calib = _calibration_runs(steps, cfg, system, cfg.placement.convergence_s)
    real_row = dict(step="replay (real errors)", cmc_m=resid["real"].iloc[-1].cmc_m,
                    doppler_m_s=resid["real"].iloc[-1].doppler_m_s,
                    zwd_offset_m=resid["real"].attrs["zwd_offset_m"],
                    code_arc_bias_m=resid["real"].attrs["code_arc_bias_m"])
    for mode in ("df_code", "float_ppp"):
        r = cons[(cons["mode"] == mode) & (cons.system == system)]
        if len(r):
            r = r.iloc[0]
            real_row[f"rms_{mode}"] = r.rms_2d_m_real
            real_row[f"z2_{mode}"] = f"{r.z2_e_real:.2f} / {r.z2_n_real:.2f} / {r.z2_u_real:.2f}"
    calib = pd.concat([calib, pd.DataFrame([real_row])], ignore_index=True)
    calib.to_csv(out / "calibration.csv", index=False)
    timings["calibrated twins"] = time.time() - t

    summary = dict(
        quick=quick, start=cfg.scenario_dict["start"], duration_s=cfg.scenario_dict["duration_s"],
        modes=list(cfg.modes), systems=list(cfg.systems),
        durations_s=[float(d) for d in cfg.durations_s],
        satellites_kept=[int(k) for k in cfg.satellites_kept],
        realizations=cfg.realizations, spacing_s=cfg.placement.spacing_s,
        convergence_s=cfg.placement.convergence_s, calibration_system=system,
        zwd_residual_sigma_m=twin.cfg.obs_params.zwd_residual_sigma_m,
        resid_attrs={w: resid[w].attrs for w in WORLDS}, factors=factors,
        timings=timings, stats=stats, jaxnav_source=sweep.source_hash())
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))


def render(out: Path, quick: bool) -> Path:
    """``report.md`` and ``real_vs_simulated.png`` from the files ``compute`` wrote."""
    s = json.loads((out / "summary.json").read_text())
    if s["quick"] != quick:
        raise SystemExit(f"{out / 'summary.json'} is of a {'quick' if s['quick'] else 'full'} "
                         "run; run the script without --report-only first")
    both = pd.read_csv(out / "outages.csv")
    cons = pd.read_csv(out / "no_outage.csv")
    res_both = pd.read_csv(out / "residuals.csv")
    calib = pd.read_csv(out / "calibration.csv")
    modes, systems, conv = s["modes"], s["systems"], s["convergence_s"]
    attrs = s["resid_attrs"]

    detail, geo = _outage_tables(both, modes, s["satellites_kept"])
    cons_rows = [(r.mode, r.system, r.rms_2d_m_real, r.rms_2d_m_sim,
                  r.rms_2d_m_sim / r.rms_2d_m_real,
                  f"{r.z2_e_real:.2f} / {r.z2_n_real:.2f} / {r.z2_u_real:.2f}",
                  f"{r.z2_e_sim:.2f} / {r.z2_n_sim:.2f} / {r.z2_u_sim:.2f}",
                  f"{r.nis_per_row_real:.2f} / {r.nis_per_row_sim:.2f}",
                  f"{100 * r.gated_code_real:.1f} / {100 * r.gated_code_sim:.1f}",
                  f"{100 * r.gated_phase_real:.1f} / {100 * r.gated_phase_sim:.1f}")
                 for r in cons.itertuples()]
    res_rows = [(r.elev, f"{r.n_real} / {r.n_sim}", r.cmc_m_real, r.cmc_m_sim,
                 r.cmc_m_sim / r.cmc_m_real, 100 * r.doppler_m_s_real, 100 * r.doppler_m_s_sim,
                 100 * r.carrier_m_real, 100 * r.carrier_m_sim,
                 100 * r.carrier_zwd0_m_real, 100 * r.carrier_zwd0_m_sim,
                 100 * r.carrier_zwd_m_real, 100 * r.carrier_zwd_m_sim)
                for r in res_both.itertuples()]
    calib_modes = [m for m in ("df_code", "float_ppp") if f"rms_{m}" in calib]
    calib_rows = [(r["step"], *[x for m in calib_modes for x in (r[f"rms_{m}"], r[f"z2_{m}"])],
                   r["cmc_m"], r["code_arc_bias_m"], 100 * r["doppler_m_s"],
                   100 * r["zwd_offset_m"]) for _, r in calib.iterrows()]
    calib_head = ["simulated errors", *[x for m in calib_modes
                                        for x in (f"{m} RMS 2D [m]", f"{m} (e/s)^2 E/N/U")],
                  "CMC [m]", "code arc bias [m]", "Doppler [cm/s]", "ZWD offset [cm]"]
    _figure(both, res_both, out / "real_vs_simulated.png")

    sat_line = ", ".join(f"{w} {attrs[w]['satellites_per_epoch']:.1f} satellites per epoch in "
                         f"{attrs[w]['arcs']} arcs" for w in WORLDS)
    sections = [
        ("What was run", (
            f"One study on two sources: the replay of `configs/esbc_replay.toml` "
            f"({s['start']} GPST + {s['duration_s']:g} s) and its simulated twin. Modes "
            f"{', '.join(modes)}; systems {', '.join(systems)}; outages "
            f"{[int(d) for d in s['durations_s']]} s; satellites kept "
            f"{[_kept(k) for k in s['satellites_kept']]} (policy highest); outages on a "
            f"{s['spacing_s']:g}-s grid after {conv:g} s; {s['realizations']} realisation(s) "
            "of the IMU noise (the same in both). Both use the same filters (recorded-data "
            "stochastic model, 1-s covariance steps); only the GNSS errors differ. The twin's "
            "GNSS errors are one draw per realisation seed; the replay's are the day's.")),
        ("No outage: accuracy and consistency after convergence", (
            f"Realisation 0, epochs after {conv:g} s. (e/s)^2 is the mean over the epochs of "
            "(error / filter sigma)^2 per axis E / N / U (1 = consistent); NIS/row is the "
            "innovations' sum(nu^T S^-1 nu) over the used rows; gated is the share of offered "
            "code / phase rows the gates rejected.\n\n" + common.markdown_table(
                ["mode", "system", "RMS 2D real [m]", "RMS 2D sim [m]", "sim / real",
                 "(e/s)^2 E/N/U real", "(e/s)^2 E/N/U sim", "NIS/row real / sim",
                 "gated code % real / sim", "gated phase % real / sim"], cons_rows))),
        ("Outages: mean maximum 2D error [m], real / simulated", (
            "Every outage of the grid (placements x realisations) in each cell.\n\n" + detail
            + "\n\nGeometric mean of sim / real over the systems and outage lengths "
            "(< 1: the simulator is optimistic):\n\n" + geo)),
        ("The error sources on the observations (no filter)", (
            "At the true antenna, the observations of realisation 0, elevation mask "
            f"{ELEV_EDGES_DEG[0]} deg, arcs of at least {MIN_ARC_EPOCHS} epochs ({sat_line}). "
            "CMC: ionosphere-free code minus carrier, each arc's mean removed (code multipath "
            "+ noise; the IF carrier's own error is 1-2 orders smaller). Doppler: f1 range "
            "rate minus the true range rate and the product satellite clock rate, the mean "
            "over the satellites (receiver clock drift) removed per epoch. Carrier: IF carrier "
            "minus true range + product satellite clock - a-priori troposphere (Saastamoinen "
            "+ Niell, as the filters), residual after a least-squares fit of a clock per epoch "
            "and an ambiguity per arc; +ZWD adds one zenith wet delay for the window, "
            "+ZWD(t) one per epoch. The fits absorb part of any error (the same parameters in "
            "both worlds).\n\n" + common.markdown_table(
                ["elevation deg", "obs real / sim", "CMC real [m]", "CMC sim [m]", "sim / real",
                 "Doppler real [cm/s]", "Doppler sim [cm/s]", "carrier real [cm]",
                 "carrier sim [cm]", "+ZWD real [cm]", "+ZWD sim [cm]",
                 "+ZWD(t) real [cm]", "+ZWD(t) sim [cm]"], res_rows)
            + "\n\nPer-arc code bias (IF code minus truth, clock removed per epoch, mean over "
            "each arc; RMS over the arcs weighted by length: multipath that repeats with the "
            "geometry, code phase-centre variations, satellite-receiver code biases): real "
            f"{attrs['real']['code_arc_bias_m']:.2f} m, simulated "
            f"{attrs['simulated']['code_arc_bias_m']:.2f} m. "
            "The constant zenith wet delay fitted (observed minus the filters' a-priori "
            f"Saastamoinen wet delay): real {100 * attrs['real']['zwd_offset_m']:+.1f} cm, "
            f"simulated {100 * attrs['simulated']['zwd_offset_m']:+.1f} cm (the simulator "
            "draws its ZWD residual from a Gauss-Markov process of sigma "
            f"{100 * s['zwd_residual_sigma_m']:g} cm).")),
        (f"The twin calibrated on the replay ({s['calibration_system']}, no outage)", (
            "Rows 2-4 are cumulative: each changes one more error source of the simulator to "
            "the size the diagnostic measured on the replay; the two '(alone)' rows change one "
            "slow error of the defaults that the diagnostic cannot size. Same drive, IMU noise "
            "and normalised GNSS noise draws; realisation 0; epochs after "
            f"{conv:g} s. The last four columns are each variant's own diagnostic ('all' "
            "rows): they show each knob hit its target.\n\n"
            + common.markdown_table(calib_head, calib_rows))),
        ("Figure", "![real vs simulated](real_vs_simulated.png)"),
        ("What differs and why", common.hand_written_discussion(DISCUSSION_PATH, quick)),
        ("Run time", "\n".join(common.run_time_lines(s["timings"], s["stats"])
                               + [f"- jaxnav source hash {s['jaxnav_source']}"])),
    ]
    return common.write_report(out, "Real versus simulated GNSS errors (replay vs twin)",
                               sections, quick)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    report_only = "--report-only" in argv
    if report_only:
        argv.remove("--report-only")
    args = common.parse_args(NAME, __doc__.splitlines()[0], argv)
    if not report_only:
        compute(args.out, args.quick)
    path = render(args.out, args.quick)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
