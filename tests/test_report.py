"""Tables and plots of a sweep Dataset (jaxnav.study.report), on hand-built Datasets with the
engine's layout, so every cell can be recomputed independently."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from jaxnav.study import report as rp
from jaxnav.study import sweep as sw

MODES = ["sf_code", "df_code", "float_ppp"]
KEPT = [0, 1, 2, 3, sw.ALL]
DURATIONS = [10.0, 30.0, 60.0]


def synthetic(durations=DURATIONS, kept=KEPT, lengths=None, traces=True, seed=0):
    """A Dataset shaped like the engine's, max_2d_m drawn from a known generator."""
    rng = np.random.default_rng(seed)
    shape = (len(MODES), 2, 3, len(durations), len(kept), 5, 1, 2)
    max_2d = rng.lognormal(0.0, 1.0, shape)
    max_2d[0, 0, 0, 0, 0, 0, 0, 0] = np.nan  # e.g. a % of distance during a stop
    coords = {
        "mode": MODES, "system": ["riss", "ins"], "realization": [0, 1, 2],
        "duration": np.asarray(durations, float), "satellites_kept": kept,
        "placement": np.arange(5), "policy": ["highest"], "ramp": [0.0, 2.0],
    }
    if lengths is None:
        lengths = np.broadcast_to(np.asarray(durations, float)[:, None], (len(durations), 5))
    ds = xr.Dataset(
        {"max_2d_m": (sw.DIMS, max_2d), "end_enu_m": (sw.DIMS + ("enu",), np.zeros(shape + (3,)))},
        coords | {"length_s": (("duration", "placement"), lengths)},
    )
    ds.attrs.update(title="synthetic", jaxnav_version="0.0", config_hash="abc123")
    if traces:
        t = np.arange(-5.0, 40.0)
        err = np.zeros((4, t.size, 3))
        for i in range(4):
            err[i, :, 0] = np.where((t >= 0) & (t < 30), 0.1 + 0.01 * (3 - i) * t**2, 0.1)
        ds["trace_err_enu_m"] = (("trace", "trace_epoch", "enu"), err)
        ds = ds.assign_coords(
            trace_time_s=(("trace", "trace_epoch"), np.broadcast_to(t, (4, t.size))),
            trace_mode=("trace", ["sf_code"] * 4), trace_system=("trace", ["riss"] * 4),
            trace_satellites_kept=("trace", [0, 1, 2, sw.ALL]),
            trace_outage_s=("trace", [30.0] * 4), trace_ramp_s=("trace", [0.0] * 4),
        )
    return ds


def _cell(ds, system, duration, kept, mode):
    """Independent reference: every other axis pooled, NaN dropped."""
    v = ds.max_2d_m.sel(system=system, duration=duration, satellites_kept=kept, mode=mode)
    v = v.values.ravel()
    v = v[~np.isnan(v)]
    return v.size, v.mean(), np.median(v), np.percentile(v, 90), v.max()


def test_table_by_satellites_pools_every_other_axis():
    ds = synthetic()
    df = rp.table_by_satellites(ds)
    assert len(df) == 2 * len(DURATIONS) * len(KEPT) * len(MODES)
    # the seed's order: modes as configured, satellites kept ascending with "all" last
    first = df[(df.system == "riss") & (df.duration_s == 10.0)]
    assert list(pd.unique(first.satellites_kept)) == [0, 1, 2, 3, sw.ALL]
    assert list(first["mode"][:3]) == MODES
    for _, row in df.iterrows():
        n, mean, med, p90, mx = _cell(ds, row.system, row.duration_s, row.satellites_kept,
                                      row["mode"])
        assert row.n == n
        np.testing.assert_allclose([row["mean"], row["median"], row.p90, row["max"]],
                                   [mean, med, p90, mx], rtol=1e-12)
    nan_cell = df[(df.system == "riss") & (df.duration_s == 10.0) & (df.satellites_kept == 0)
                  & (df["mode"] == "sf_code")]
    assert int(nan_cell.n.iloc[0]) == 3 * 5 * 2 - 1  # the NaN is dropped, not propagated


def test_table_by_duration_uses_complete_outages_and_length():
    ds = synthetic()
    df = rp.table_by_duration(ds)
    assert set(df.satellites_kept) == {0} and len(df) == 2 * len(DURATIONS) * len(MODES)
    for _, row in df.iterrows():
        n, mean, *_ = _cell(ds, row.system, row.duration_s, 0, row["mode"])
        assert row.n == n
        np.testing.assert_allclose(row["mean"], mean, rtol=1e-12)
    # no complete outage in the study: the lowest level kept is used
    df1 = rp.table_by_duration(ds.sel(satellites_kept=[2, 3, sw.ALL]))
    assert set(df1.satellites_kept) == {2}
    # schedule files: one duration entry (-1), lengths per placement
    lengths = np.array([[10.0, 10.0, 20.0, 20.0, 45.0]])
    sched = synthetic(durations=[-1.0], lengths=lengths)
    ds_s = rp.table_by_duration(sched)
    assert sorted(pd.unique(ds_s.duration_s)) == [10.0, 20.0, 45.0]
    row = ds_s[(ds_s.system == "ins") & (ds_s.duration_s == 20.0) & (ds_s["mode"] == "df_code")]
    ref = sched.max_2d_m.sel(system="ins", satellites_kept=0, mode="df_code").isel(
        placement=[2, 3]).values
    np.testing.assert_allclose(row["mean"].iloc[0], np.nanmean(ref), rtol=1e-12)
    by_sat = rp.table_by_satellites(sched)
    assert sorted(pd.unique(by_sat.duration_s)) == [10.0, 20.0, 45.0]


def test_markdown_and_csv(tmp_path):
    ds = synthetic()
    paths = rp.write_tables(ds, tmp_path)
    md = paths["markdown"].read_text()
    df = rp.table_by_satellites(ds)
    r = df[(df.system == "ins") & (df.duration_s == 60.0) & (df.satellites_kept == 3)]
    cells = [f"{rp._fmt(x.mean)} ({rp._fmt(x.median)} / {rp._fmt(x.p90)})"
             for x in r.itertuples()]
    assert "| 3 | " + " | ".join(cells) + " |" in md
    assert "| satellites kept | sf_code | df_code | float_ppp |" in md
    assert "### Average maximum 2D error [m] by satellites kept x mode: ins, 60 s outages" in md
    assert "| all | " in md and "| 30 s | " in md
    assert "by outage duration x mode: riss, 0 satellites kept" in md
    back = pd.read_csv(paths["by_satellites_csv"])
    assert list(back.columns) == ["system", "duration_s", "satellites_kept", "mode", *rp.STATS]
    assert set(back.satellites_kept.astype(str)) == {"0", "1", "2", "3", "all"}
    np.testing.assert_allclose(back["mean"], df["mean"], rtol=1e-5)  # 6 significant digits
    back_d = pd.read_csv(paths["by_duration_csv"])
    assert len(back_d) == 2 * len(DURATIONS) * len(MODES)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        rp.write_tables(ds, tmp_path, overwrite=False)
    with pytest.raises(ValueError, match="enu"):
        rp.table_by_satellites(ds, "end_enu_m")


def _is_png(path):
    data = path.read_bytes()
    return data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_plots_are_written(tmp_path):
    ds = synthetic()
    paths = rp.write_report(ds, tmp_path)
    for key in ("error_growth", "by_satellites", "by_duration", "markdown"):
        assert paths[key].exists()
    for key in ("error_growth", "by_satellites", "by_duration"):
        assert _is_png(paths[key]), key
    assert rp.plot_error_growth(synthetic(traces=False), tmp_path / "none.png") is None
    assert not (tmp_path / "none.png").exists()


def _with_traces(ds, n_runs=7, seed=1):
    """Replace the traces by n_runs runs per level of sf_code / riss with known errors:
    run i's 2D error at level k is (k + 1) * (i + 1) metres at every epoch."""
    ds = ds.drop_vars([v for v in ds.variables if str(v).startswith("trace")])
    t = np.arange(-5.0, 40.0)
    levels = [0, 1, sw.ALL]
    kept = np.repeat(levels, n_runs)
    run = np.tile(np.arange(n_runs), len(levels))
    scale = np.where(kept == sw.ALL, 0.1, kept + 1.0) * (run + 1.0)
    err = np.zeros((kept.size, t.size, 3))
    err[:, :, 0] = scale[:, None] * 0.6
    err[:, :, 1] = scale[:, None] * 0.8  # |(0.6, 0.8)| = 1
    n = kept.size
    ds["trace_err_enu_m"] = (("trace", "trace_epoch", "enu"), err)
    return ds.assign_coords(
        trace_time_s=(("trace", "trace_epoch"), np.broadcast_to(t, (n, t.size))),
        trace_mode=("trace", ["sf_code"] * n), trace_system=("trace", ["riss"] * n),
        trace_satellites_kept=("trace", kept), trace_outage_s=("trace", [30.0] * n),
        trace_ramp_s=("trace", [0.0] * n),
    )


def test_error_growth_is_the_median_and_band_over_the_traced_runs(tmp_path):
    """Each curve is the median of its level's runs with the 10th / 90th percentiles (not one
    run), and the panel's title says how many runs a curve holds."""
    ds = _with_traces(synthetic(traces=False), n_runs=7)
    longest, ramp, curves = rp.error_growth_curves(ds, "riss", "sf_code")
    assert (longest, ramp) == (30.0, 0.0) and list(curves) == [0, 1, sw.ALL]
    runs = np.arange(1.0, 8.0)
    for k, (t, med, lo, hi, n) in curves.items():
        scale = (0.1 if k == sw.ALL else k + 1.0) * runs
        assert n == 7 and t[0] == -5.0
        np.testing.assert_allclose(med, np.median(scale), rtol=1e-12)
        np.testing.assert_allclose(lo, np.percentile(scale, 10), rtol=1e-12)
        np.testing.assert_allclose(hi, np.percentile(scale, 90), rtol=1e-12)
    path = rp.plot_error_growth(ds, tmp_path / "g.png")
    assert _is_png(path)


def test_pooled_cells_and_the_summary_table(tmp_path):
    """table.md says what a cell pools, and its summary table holds % of distance, the
    re-convergence median and the NEES verdict: chi2(3) draws are consistent, ten times them
    over-confident (bold), a tenth under-confident (chi2(3 R) / R band over the R
    realizations, whose outages are not independent)."""
    from scipy.stats import chi2

    ds = synthetic()
    rng = np.random.default_rng(5)
    shape = ds.max_2d_m.shape
    nees = rng.chisquare(3, shape)
    nees[0] *= 10.0  # sf_code over-confident
    nees[2] *= 0.1  # float_ppp under-confident
    reconv = rng.uniform(0, 20, shape)
    ok = rng.uniform(size=shape) > 0.3
    ds = ds.assign(nees_pos=(sw.DIMS, nees), pct_of_distance=(sw.DIMS, ds.max_2d_m.values * 2),
                   reconv_s=(sw.DIMS, np.where(ok, reconv, np.nan)),
                   reconverged=(sw.DIMS, ok))
    assert rp.pooled_text(ds) == "5 placements x 3 realizations x 2 ramps"
    df = rp.table_summary(ds)
    assert len(df) == 2 * len(DURATIONS) * len(KEPT) * len(MODES)
    r = df[(df.system == "ins") & (df.duration_s == 30.0) & (df.satellites_kept == 1)]
    sel = dict(system="ins", duration=30.0, satellites_kept=1)
    for mode, verdict in (("sf_code", rp.OVER), ("df_code", rp.CONSISTENT),
                          ("float_ppp", rp.UNDER)):
        row = r[r["mode"] == mode].iloc[0]
        v = ds.nees_pos.sel(mode=mode, **sel)  # one chi2(3) draw per realization's mean
        per_real = v.mean([d for d in v.dims if d != "realization"]).values
        n_real = per_real.size
        assert row.nees_pos_mean == pytest.approx(per_real.mean(), rel=1e-12)
        assert row.nees_hi == pytest.approx(chi2.ppf(0.975, 3 * n_real) / n_real, rel=1e-12)
        assert row.consistency == verdict, (mode, row.nees_pos_mean, row.nees_lo, row.nees_hi)
        rc = ds.reconv_s.sel(mode=mode, **sel).values.ravel()
        assert row.reconv_median_s == pytest.approx(np.nanmedian(rc), rel=1e-12)
        assert row.reconverged_frac == pytest.approx(np.isfinite(rc).mean(), rel=1e-12)
        pct = ds.pct_of_distance.sel(mode=mode, **sel).values.ravel()
        assert row.pct_of_distance_mean == pytest.approx(np.nanmean(pct), rel=1e-12)
    md = rp.write_tables(ds, tmp_path)["markdown"].read_text()
    assert "of 30 outages per cell = 5 placements x 3 realizations x 2 ramps" in md
    assert "### Re-convergence, error per distance and consistency: ins, 30 s outages" in md
    assert "| sf_code |" in md and "**over-confident**" in md and "| under-confident |" in md


def test_one_duration_draws_no_duration_distribution(tmp_path):
    paths = rp.write_report(synthetic(durations=[30.0]), tmp_path)
    assert "by_duration" not in paths and not (tmp_path / "dist_by_duration.png").exists()
    assert _is_png(paths["by_satellites"])


# ----------------------------------------------------------------------------------------------
# End to end with the real tight filter: simulated drive -> sweep -> Dataset -> report
# ----------------------------------------------------------------------------------------------
class SimFactory:
    """Scenario factory over jaxnav.sim.scenario: RISS + tightly coupled PPP (a template for the
    command line's factory). Realization = the PRNG seed of every sensor and GNSS error."""

    modes = ("sf_code", "df_code", "sdf_code", "float_ppp", "ic_ppp")
    systems = ("riss",)

    def __init__(self, duration_s: float):
        import jax.numpy as jnp

        from jaxnav.sim import constellation, scenario

        self.scfg = scenario.ScenarioConfig(duration_s=duration_s)
        self.geo = geo = scenario.build_geometry(self.scfg)
        el, az = constellation.elevations(geo.orbits, geo.truth_ep.time_s, geo.ant_pos_ecef)
        idx = np.asarray(geo.slot_table.sat_index)
        occ = np.asarray(geo.slot_table.occupied)
        # epoch 0 initialises the filter: the study's epochs are 1 .. T - 1
        self.elevation = jnp.where(occ, jnp.asarray(el)[:, idx], -jnp.pi / 2)[1:]
        self.azimuth = jnp.asarray(az)[:, idx][1:]
        self.ops = sw.tight_ops()
        self._cache = {}

    def fingerprint(self):
        return repr(self.scfg)

    def timeline(self, cfg):
        t = self.geo.truth_ep
        return sw.Timeline(int(t.time_s.shape[0]) - 1, self.scfg.epoch_interval_s,
                           np.asarray(t.event[1:]))

    def build(self, cfg, mode, system, seed):
        import jax

        from jaxnav.filter import systems, tight
        from jaxnav.gnss import ppp
        from jaxnav.sim import scenario, sensors
        from jaxnav.study import metrics as mt

        key = (mode, system, seed)
        if key in self._cache:
            return self._cache[key]
        scfg, geo = self.scfg, self.geo
        real = jax.jit(lambda k: scenario.realize(k, geo, scfg, mode == "sf_code"))(
            jax.random.PRNGKey(seed)
        )
        pcfg = ppp.PppConfig(mode=mode, n_slots=int(geo.slots.system.shape[0]),
                             estimate_zwd=mode in ("float_ppp", "ic_ppp"))
        dt = 1.0 / scfg.riss_rate_hz
        riss = systems.RissSystem.for_sensors(
            sensors.imu_grade(scfg.imu_grade), sensors.odometer(scfg.odometer),
            scfg.lever_b_m, dt,
        )
        tf = tight.TightFilter(riss, pcfg, geo.slots, dt, scfg.epoch_interval_s)
        nav0 = scenario.initial_riss_state(geo)
        inputs = real.riss_inputs
        standstill = jax.tree.map(lambda x: x[:30].reshape(-1, *x.shape[2:]), inputs.samples)
        carry0 = tight.initial_carry(tf, nav0, real.obs0,
                                     sensors0=riss.calibrate_static(nav0, standstill, dt))
        t = geo.truth_ep
        prob = sw.Problem(
            tf, carry0, inputs, mt.track(t.llh[1:], t.vel_enu[1:], t.euler[1:]),
            self.elevation, inputs.obs.available, self.azimuth, pcfg.elevation_mask_rad,
        )
        self._cache[key] = prob
        return prob


@pytest.mark.slow
def test_end_to_end_with_the_tight_filter(tmp_path):
    """A 200-s simulated drive, DF-code PPP / RISS, 18 scenarios: exact against brute-force
    runs of the whole drive, physically sensible, and reported."""
    from jaxnav.study import config as sc
    from jaxnav.study import outages as ot

    factory = SimFactory(200.0)
    cfg = sc.from_dict(
        {"study": {"name": "e2e", "modes": ["df_code"], "systems": ["riss"],
                   "durations_s": [10, 20], "satellites_kept": [0, 2, "all"],
                   "recovery_s": 20, "chunk_size": 8, "max_traces": 3},
         "placement": {"kind": "grid", "convergence_s": 60, "spacing_s": 50}},
        modes=factory.modes, systems=factory.systems,
    )
    res = sw.run_sweep(cfg, factory, tmp_path / "out", progress=False)
    ds = res.dataset.sel(mode="df_code", system="riss", realization=0, policy="highest",
                         ramp=0.0)
    plan = sw.make_plan(cfg, factory.timeline(cfg))
    assert plan.n_per_group == 18 and list(plan.starts[0]) == [60, 110, 160]
    print("stats", {k: round(v, 2) if isinstance(v, float) else v
                    for k, v in res.stats.items()})

    prob = factory.build(cfg, "df_code", "riss", 0)
    f = plan.scenarios(np.arange(plan.n_per_group))
    worst = 0.0
    for i in (0, 7, 11, 15):  # brute force: the whole drive with the outage mask
        o = ot.Outage(*(int(f[k][i]) for k in ("start", "length", "n_keep", "ramp")))
        m, _ = sw.brute_force(prob, factory.ops, o, epoch_dt_s=1.0,
                              recovery_epochs=plan.recovery, mcfg=plan.mcfg)
        r, d, k, p, *_ = np.unravel_index(i, plan.shape)
        eng = ds.isel(duration=d, satellites_kept=k, placement=p)
        for name in ("max_2d_m", "rms_2d_m", "end_2d_m", "max_3d_m"):
            worst = max(worst, abs(float(getattr(m, name)) - float(eng[name])))
    print(f"tight filter: engine vs brute force, max |diff| {worst:.1e} m")
    assert worst < 1e-7  # different XLA programs (checkpoint restart): rounding only

    # distance = the truth's path length over the outage (speed x time)
    t = factory.geo.truth_ep
    speed = np.linalg.norm(np.asarray(t.vel_enu[1:]), axis=1)
    for d, L in enumerate((10, 20)):
        for p, s in enumerate(plan.starts[d]):
            path = np.sum(0.5 * (speed[s - 1:s + L - 1] + speed[s:s + L]))
            np.testing.assert_allclose(ds.distance_m.isel(duration=d, placement=p)
                                       .sel(satellites_kept=0), path, rtol=0.01, atol=0.05)
    # withholding every satellite cannot help: complete outages are worse on average
    assert float(ds.max_2d_m.sel(satellites_kept=0, duration=20.0).mean()) > float(
        ds.max_2d_m.sel(satellites_kept=sw.ALL, duration=20.0).mean())
    paths = rp.write_report(res.dataset, tmp_path / "report")
    assert "| 0 |" in paths["markdown"].read_text() and _is_png(paths["error_growth"])
