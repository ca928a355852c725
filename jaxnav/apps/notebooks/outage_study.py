# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Tutorial: a GNSS-outage study with jaxnav
#
# You have a PPP receiver coupled with an inertial system and want to know how far the solution
# drifts when the sky disappears for 30 or 60 s, or when only one or two satellites survive,
# and how long it takes to recover. jaxnav answers that with a *study*: a grid of outages laid
# over a simulated drive, every cell run through the same filter, many thousands at once.
#
# This notebook defines a small study, runs it, reads the results and looks at one run in
# detail. `jaxnav tutorial --out DIR` copies it out of the installed package, as this script
# and (with `pip install "jaxnav[notebook]"`) as `outage_study.ipynb`. It also runs as a
# script: `python outage_study.py [--quick] [--out DIR]` writes `report.md` and the figures
# into `DIR` (default `tutorial_results/` in the current folder). `--quick` shrinks everything
# for the tests.

# %%
import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import xarray as xr

import jaxnav  # noqa: F401  (float64 and single-threaded XLA:CPU, before any computation)
from jaxnav import geodesy
from jaxnav.sim.trajectory import Event
from jaxnav.study import config, outages, report, sweep
from jaxnav.study.factory import SimFactory

IN_JUPYTER = "ipykernel" in sys.modules
if not IN_JUPYTER:
    matplotlib.use("Agg")  # a script needs no display
import matplotlib.pyplot as plt  # noqa: E402

ap = argparse.ArgumentParser(description="jaxnav outage-study tutorial")
ap.add_argument("--quick", action="store_true", help="tiny study (what the tests run)")
# (relative to the current folder: in Jupyter the notebook's own; never the project's committed
# rendering, experiments/results/tutorial_outage_study/, which is written with an explicit --out)
ap.add_argument("--out", type=Path, default=Path("tutorial_results"),
                help="folder of report.md, the figures and the sweep (default tutorial_results)")
# Inside Jupyter sys.argv holds the kernel's arguments: ignore them (and unknown ones anyway).
args, _ = ap.parse_known_args([] if IN_JUPYTER else sys.argv[1:])
OUT = args.out
OUT.mkdir(parents=True, exist_ok=True)
T_START = time.perf_counter()
REPORT = []  # (heading, markdown) sections of report.md, filled as we go


def show(fig, name):
    """Save a figure into OUT (and display it when running in Jupyter)."""
    fig.savefig(OUT / name, dpi=110)
    if IN_JUPYTER:
        plt.show()
    plt.close(fig)
    return name


# %% [markdown]
# ## 1. What a study is
#
# A study is plain data: four tables, the same ones a TOML file holds (`jaxnav sweep
# study.toml`), here a Python dict.
#
# - **study**: the grid axes. `modes` are PPP observation models: `sf_code` (L1 code with a
#   broadcast ionosphere model), `df_code` (ionosphere-free code), `sdf_code` (the same,
#   carrier-smoothed), `float_ppp` (ionosphere-free code and carrier, float ambiguities),
#   `ic_ppp` (raw dual-frequency with ionosphere states). `systems` are the navigation systems
#   (`riss` = one vertical
#   gyro, two accelerometers and the odometer, 16 states; `ins15` / `ins21` = full IMU);
#   `durations_s` the outage lengths; `satellites_kept` how many satellites stay in view during
#   an outage, with `"all"` meaning no outage at all (the reference); `realizations` the number
#   of noise draws (seeds `seed`, `seed + 1`, ...); `recovery_s` how long after the outage is
#   kept to measure re-convergence; `chunk_size` how many scenarios are run per batch (bounds
#   memory; <= 64 here); `max_traces` how many per-epoch error curves are stored for plots;
#   `policies` which satellites survive a partial outage (`highest`, `lowest`, `random`,
#   `best_geometry`, `worst_geometry`).
# - **placement**: where outages start. `grid` (every `spacing_s`), `random` (`count`),
#   `events` (centred on labelled turns / straights / stops / slopes of the drive) or
#   `schedule` (a CSV file). Nothing is placed before `convergence_s`. `min_event_s` skips
#   label runs shorter than that (a 2-s "straight" between a stop and an acceleration is not
#   worth an outage).
# - **metrics**: thresholds of the metrics (e.g. re-convergence to 20 cm).
# - **scenario**: handed to the scenario factory: the drive (`drive_style` mixed, urban,
#   suburban, highway or airborne; `drive_seed`; `duration_s`), the sensor presets
#   (`imu_grade`, `ins_grade`, `odometer` from `jaxnav.sim.sensors`), `constellations`,
#   `iono_scale`, `bssd`.
#
# Every combination (mode x system x duration x satellites kept x placement x realization) is
# one scenario.

# %%
STUDY = {
    "study": {
        "name": "tutorial",
        "modes": ["sf_code", "df_code", "float_ppp"],
        "systems": ["riss"],
        "durations_s": [30, 60],
        "satellites_kept": [0, 1, 3, "all"],
        "policies": ["highest"],  # in a partial outage the highest satellites survive
        "realizations": 4,
        "seed": 0,
        "recovery_s": 30,
        "chunk_size": 64,
        "max_traces": 8,
    },
    "placement": {"kind": "events", "convergence_s": 270, "events": ["turn", "straight", "stop"],
                  "max_per_event": 2, "min_spacing_s": 40, "min_event_s": 5},
    "metrics": {"reconv_threshold_m": 0.2},
    "scenario": {"drive_style": "mixed", "drive_seed": 0, "duration_s": 900},
}
if args.quick:  # a 7-minute drive, one mode, two levels, two realizations
    STUDY["study"].update(modes=["df_code"], durations_s=[30], satellites_kept=[0, "all"],
                          realizations=2, recovery_s=10, chunk_size=8, max_traces=2)
    STUDY["placement"].update(convergence_s=120, events=["turn", "straight"], max_per_event=1,
                              min_spacing_s=0)
    STUDY["scenario"]["duration_s"] = 420

cfg = config.from_dict(STUDY, modes=SimFactory.modes, systems=SimFactory.systems)
print("modes", cfg.modes, "| satellites kept", cfg.satellites_kept, "(-1 = all) | seeds",
      cfg.realization_seeds)
try:  # a typo is caught before anything runs, with the key, the value and what is allowed
    config.from_dict({**STUDY, "study": {**STUDY["study"], "modes": ["ppp"]}},
                     modes=SimFactory.modes, systems=SimFactory.systems)
except config.ConfigError as e:
    print("ConfigError:", e)

# %% [markdown]
# ## 2. The simulated drive
#
# `SimFactory` turns the `scenario` table into one drive (trajectory, satellites, slot table)
# shared by every scenario, and per (mode, system, seed) a filter with its noisy inputs. Each
# GNSS epoch carries a motion label; `events` placement centres outages on them.
# `sweep.make_plan` shows where the outages will go before anything is run.

# %%
factory = SimFactory(cfg.scenario_dict)
geo = factory.geo
llh = np.asarray(geo.truth_ep.llh)
enu = np.asarray(jax.vmap(lambda p: geodesy.enu_offset(geodesy.llh_to_ecef(p), llh[0]))(
    jnp.asarray(llh)))
time_s = np.asarray(geo.truth_ep.time_s)
label = np.asarray(geo.truth_ep.event)
plan = sweep.make_plan(cfg, factory.timeline(cfg))
# Filter epoch i (inputs, truth, plan.starts) is drive epoch i + 1: epoch 0 initialises.
d_long = int(np.argmax(plan.lengths[:, 0]))
windows = [(int(s) + 1, int(s + n) + 1) for s, n in zip(plan.starts[d_long],
                                                        plan.lengths[d_long], strict=True)]
print(f"{time_s[-1]:.0f} s drive, {np.sum(np.hypot(*np.diff(enu[:, :2], axis=0).T)):.0f} m; "
      f"{plan.starts.shape[1]} placements: {plan.placement_event}")
print(f"{plan.n_per_group} scenarios per (mode, system), {len(cfg.modes) * plan.n_per_group} "
      "in total")

fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained")
ax0.plot(enu[:, 0], enu[:, 1], color="0.7", lw=1)
for i, (a, b) in enumerate(windows):
    ax0.plot(enu[a:b, 0], enu[a:b, 1], color="C3", alpha=0.4, lw=6,
             label=f"{plan.lengths[d_long, 0]:g}-s outages" if i == 0 else None)
    ax0.annotate(f"{i}: {plan.placement_event[i]}", enu[a, :2], fontsize=8)
for ev in (Event.TURN, Event.STOP):
    m = label == ev
    ax0.plot(enu[m, 0], enu[m, 1], ".", ms=3, label=ev.name.lower())
ax0.plot(*enu[0, :2], "g^", label="start")
ax0.set(xlabel="east [m]", ylabel="north [m]", aspect="equal", title="Drive (truth, local ENU)")
ax0.legend(fontsize=8)
ax1.plot(time_s, np.asarray(geo.truth_ep.odo_speed_mps) * 3.6, "k", lw=1)
for i, (a, b) in enumerate(windows):
    ax1.axvspan(time_s[a], time_s[b - 1], color="C3", alpha=0.3,
                label=f"{plan.lengths[d_long, 0]:g}-s outages" if i == 0 else None)
ax1.axvspan(0, cfg.placement.convergence_s, color="0.9", label="convergence (no outages)")
ax1.set(xlabel="time [s]", ylabel="speed [km/h]", title="Speed and outage windows")
ax1.legend(fontsize=8)
FIGS = [show(fig, "drive.png")]

# %% [markdown]
# ## 3. Running the sweep
#
# `run_sweep` builds each (mode, system) filter once, runs the whole drive once per
# realization while saving filter checkpoints at the outage starts, then runs every outage
# scenario from its checkpoint in vmapped batches of `chunk_size`. Each finished chunk is
# written to `chunks/` in the sweep folder; with `resume=True` an interrupted run picks up at
# the first missing chunk, and a finished one is simply reloaded (run the cell twice: the second
# time takes a second). A folder remembers the config hash of its study and refuses results of
# another one, never overwriting them unless you pass `overwrite=True`; naming the folder after
# the hash, as below, lets you edit `STUDY` and re-run without thinking about it.

# %%
t0 = time.perf_counter()
sweep_dir = OUT / f"sweep-{cfg.hash()[:10]}"
result = sweep.run_sweep(cfg, factory, sweep_dir, resume=True, progress=IN_JUPYTER)
ds = result.dataset
st = result.stats
t_sweep = time.perf_counter() - t0
print(f"{st['scenarios']} scenarios in {t_sweep:.0f} s (compile "
      f"{st['compile_full_s'] + st['compile_eval_s']:.0f} s, chunks computed "
      f"{st['chunks_computed']}, reused {st['chunks_reused']}); saved in {result.path}")

# %% [markdown]
# ## 4. Reading the Dataset
#
# The result is an `xarray.Dataset` (also saved as `results.nc`; reload it later with
# `sweep.load_results`). Every metric has the same named dimensions, so cells are picked by
# name with `.sel` and pooled with `.mean` / `.quantile` over the axes you do not care about.
# Errors are estimate minus truth in local ENU metres. `max_2d_m` is the largest horizontal
# error inside the outage window; `satellites_kept = -1` is the "all" level, i.e. the same
# window without an outage, so it is the baseline to compare with. Other metrics: `end_2d_m`,
# `pct_of_distance`, `max_azimuth_err_rad`, `reconv_s` (time back under the re-convergence
# threshold), `nees_pos` (filter consistency). Per-epoch error curves of a few scenarios are
# kept as `trace_*` variables.

# %%
print(dict(ds["max_2d_m"].sizes))
print("metrics:", [v for v in ds.data_vars if not v.startswith("trace")])
mode = cfg.modes[-1]
cell = ds.max_2d_m.sel(mode=mode, system="riss", satellites_kept=0, policy="highest", ramp=0)
print(f"\n{mode}, complete outages: max 2D error [m], realization x placement")
print(cell.isel(duration=-1).round(2).to_pandas())
pooled = ds.max_2d_m.sel(system="riss", drop=True).squeeze(["policy", "ramp"], drop=True)
over = ["realization", "placement"]  # pool the noise draws and the outage positions
spread = xr.Dataset({"mean": pooled.mean(over), "median": pooled.median(over),
                     "p90": pooled.quantile(0.9, over).drop_vars("quantile")})
print("\nmax 2D error [m] over realizations and placements:")
print(spread.to_dataframe().round(2))
REPORT.append(("Dataset", f"Sizes: `{dict(ds['max_2d_m'].sizes)}`\n\nmax 2D error [m] over "
               "realizations and placements:\n\n```\n" + spread.to_dataframe().round(2)
               .to_string() + "\n```"))

# %% [markdown]
# pandas is a jaxnav dependency, so `to_dataframe` gives one row per scenario for your own
# groupbys and exports:

# %%
df = ds[["max_2d_m", "reconv_s", "nees_pos"]].to_dataframe().reset_index()
print(df.groupby(["mode", "duration", "satellites_kept"])[["max_2d_m", "reconv_s", "nees_pos"]]
      .median().round(2))

# %% [markdown]
# ## 5. Tables and plots
#
# `jaxnav.study.report` turns the Dataset into tables in the layout of the published outage
# studies (rows: satellites kept, columns: modes; each cell the mean, median and 90th
# percentile over realizations and placements) and standard figures: the error growth of the
# kept traces and box plots of the maximum error. `report.write_report(ds, folder)` does all of
# it in one call (plus CSV files).

# %%
table = report.table_by_satellites(ds)
table_md = report.markdown_by_satellites(table)
print(table_md)
growth = report.plot_error_growth(ds, OUT / "error_growth.png")
dists = report.plot_distributions(ds, OUT)
FIGS += [f.name for f in [growth, *dists.values()] if f is not None]
if IN_JUPYTER:
    from IPython.display import Image, display
    for name in FIGS[1:]:
        display(Image(filename=str(OUT / name)))

# %% [markdown]
# What do the numbers say? The list below is generated from the Dataset, so it stays true when
# you change the study. A position NEES far above 3 with every satellite is a known property of
# the simulated errors (time-correlated multipath, ionosphere and product errors that the
# filters treat as white; `docs/models.md`, "Known limits of consistency"): read the filter's
# sigma as optimistic.

# %%
mean_max = ds.max_2d_m.mean(["realization", "placement", "policy", "ramp"])
lines = []
for m in cfg.modes:
    for dur in ds.duration.values:
        c = mean_max.sel(mode=m, system="riss", duration=dur)
        zero, ref = float(c.sel(satellites_kept=0)), float(c.sel(satellites_kept=-1))
        lines.append(f"- {m}, {dur:g}-s outages: mean maximum 2D error {zero:.2f} m with no "
                     f"satellite vs {ref:.2f} m without an outage ({zero / ref:.1f} times).")
longest = mean_max.sel(system="riss").isel(duration=-1)
for k in [int(k) for k in ds.satellites_kept.values if 0 < k]:
    for m in cfg.modes:
        change = 100.0 * (float(longest.sel(mode=m, satellites_kept=k))
                          / float(longest.sel(mode=m, satellites_kept=0)) - 1.0)
        verdict = ("about the same (within 10 %)" if abs(change) < 10.0 else
                   "worse: the few satellites left hurt more than they help" if change > 0 else
                   "better")
        lines.append(f"- {m}, longest outage, {k} satellite(s) kept instead of none: mean "
                     f"maximum error {change:+.0f} %, {verdict}.")
if ds.sizes["duration"] > 1:
    c0 = mean_max.sel(satellites_kept=0, system="riss")
    growth_ratio = c0.isel(duration=-1) / c0.isel(duration=0)
    r = float(ds.duration[-1] / ds.duration[0])
    per_mode = ", ".join(f"{m} {float(v):.1f}x" for m, v in zip(cfg.modes, growth_ratio.values,
                                                                  strict=True))
    fast = [m for m, v in zip(cfg.modes, growth_ratio.values, strict=True) if v > r]
    lines.append(f"- a {r:g}x longer complete outage multiplies the mean maximum error by "
                 f"{per_mode}; faster than linear growth (above {r:g}x, as a heading error "
                 f"times the distance driven gives) for: {', '.join(fast) or 'none'}.")
nees = ds.nees_pos.median(["realization", "placement", "policy", "ramp", "duration"])
for m in cfg.modes:
    n0, n_all = (float(nees.sel(mode=m, system="riss", satellites_kept=k)) for k in (0, -1))
    lines.append(f"- {m}: median position NEES {n0:.1f} in complete outages, {n_all:.1f} with "
                 "every satellite (3 when the filter's covariance matches its errors; above: "
                 "over-confident, below: cautious).")
interpretation = "\n".join(lines)
print(interpretation)

# %% [markdown]
# ## 6. One run up close
#
# The sweep only keeps metrics. To look inside one scenario, build its problem with the
# factory and hand it to `sweep.single_run` with an outage: it withholds the satellites, runs
# the filter over the whole drive (a `lax.scan` over the epochs) and returns the errors and the
# filter's own 1-sigma in metres, epoch by epoch (epoch k is drive time `run.time_s[k]`; epoch 0
# of the drive only initialises the filter). The maximum error in the window should match the
# sweep's number for the same cell, although the sweep ran only the window from a checkpoint.

# %%
seed = cfg.seed
p = plan.placement_event.index("turn") if "turn" in plan.placement_event else 0
prob = factory.build(cfg, mode, "riss", seed)
outage = outages.Outage(int(plan.starts[d_long, p]), int(plan.lengths[d_long, p]), 0)
run = sweep.single_run(prob, factory.ops_for(mode, "riss"), outage,
                       epoch_dt_s=factory.cfg.epoch_interval_s)
err_2d = np.hypot(run.error_enu_m[:, 0], run.error_enu_m[:, 1])
sigma_2d = np.hypot(run.sigma_enu_m[:, 0], run.sigma_enu_m[:, 1])
t = run.time_s
a, b = outage.start, outage.start + outage.length
ours = float(err_2d[a:b].max())
theirs = float(ds.max_2d_m.sel(mode=mode, system="riss", realization=seed,
                               duration=ds.duration[d_long], satellites_kept=0, placement=p)
               .squeeze())
print(f"single run: max 2D error in the outage {ours:.3f} m; sweep cell: {theirs:.3f} m")
print(f"at the outage end: error {err_2d[b - 1]:.2f} m, filter 1-sigma {sigma_2d[b - 1]:.2f} m; "
      f"before it: error {err_2d[a - 1]:.2f} m, 1-sigma {sigma_2d[a - 1]:.2f} m")

fig, ax = plt.subplots(figsize=(9, 4), layout="constrained")
ax.axvspan(t[a], t[b - 1], color="C3", alpha=0.2, label=f"outage ({outage.length} s, 0 sats)")
ax.plot(t, err_2d, "k", lw=1, label="2D error |estimate - truth|")
ax.plot(t, sigma_2d, "C0--", lw=1, label="filter 1-sigma (2D, from P)")
ax.set(yscale="log", xlabel="time [s]", ylabel="[m]",
       title=f"{mode} / riss, seed {seed}, placement {p} ({plan.placement_event[p]})")
ax.grid(True, which="both", alpha=0.3)
ax.legend(fontsize=8)
FIGS.append(show(fig, "single_run.png"))

# %% [markdown]
# ## 7. The report
#
# The script form writes everything above into `report.md` next to the figures.

# %%
wall = time.perf_counter() - T_START
REPORT = [
    ("Study", "```json\n{\n" + ",\n".join(f'"{k}": {json.dumps(v)}' for k, v in STUDY.items())
     + "\n}\n```"),
    *REPORT,  # the Dataset summary
    ("Tables", table_md),
    ("Interpretation (computed)", interpretation),
    ("Single run", f"{mode} / riss, seed {seed}, placement {p}: maximum 2D error in the "
     f"outage {ours:.3f} m from a whole-drive `sweep.single_run`, {theirs:.3f} m from the "
     "sweep."),
    ("Figures", "\n".join(f"![{n}]({n})" for n in FIGS)),
    ("Run", f"{st['scenarios']} scenarios, sweep {t_sweep:.0f} s, notebook {wall:.0f} s"
     f"{' (--quick: tiny study, numbers not meaningful)' if args.quick else ''}."),
]
text = ("# jaxnav tutorial: an outage study\n\nRendered output of the tutorial notebook "
        "(`jaxnav tutorial --out DIR` writes it; the notebook explains each step).\n\n"
        + "\n\n".join(f"## {h}\n\n{body.strip()}" for h, body in REPORT) + "\n")
(OUT / "report.md").write_text(text)
print(f"wrote {OUT / 'report.md'} ({wall:.0f} s)")
