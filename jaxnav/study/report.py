"""Tables and plots from a sweep's Dataset (``jaxnav.study.sweep``): views, never new numbers.

Tables (Markdown and CSV):

- **by satellites kept x mode** (seed 000 Table 5.2: "2D average maximum error" of 60-s
  outages with 0-3 satellites kept, one column per PPP variant), one table per system and
  outage duration;
- **by duration x mode** (seed 004: maximum error of complete 10 / 30 / 60-s outages), one table
  per system, for one satellites-kept level (default 0 = complete outage).

Each cell pools every other axis (realizations, placements, policies, ramps) and shows the mean
(the seeds' "average maximum") with the spread: median and 90th percentile, NaN ignored. The
CSV files hold the long form (n, mean, median, p90, max per cell).

A study with ``smooth = true`` has a ``solution`` axis (forward, smoothed): the tables are given
for each (``table.md`` one section per solution, the CSV files a ``solution`` column) and the
plots too (the smoothed ones with the suffix ``_smoothed``).

A third table per system and duration gives, per satellites kept and mode, the mean error as %
of the distance travelled, the median re-convergence time and the mean position NEES with its
chi-square band and a verdict (``table_summary``: over-confident cells in bold).

Plots (PNG, matplotlib's Agg canvas, no display needed): the 2D error around the outage, median
and 10-90 % band over the traced runs (outage shaded, ramps lighter); and box plots of the
maximum 2D error by satellites kept and (two or more durations) by duration, one box per mode.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

ALL = -1  # satellites_kept value of "no outage" (jaxnav.study.outages.ALL)
STATS = ("n", "mean", "median", "p90", "max")
_LABELS = {
    "max_2d_m": "maximum 2D error [m]",
    "rms_2d_m": "RMS 2D error [m]",
    "max_3d_m": "maximum 3D error [m]",
    "end_2d_m": "2D error at the outage end [m]",
    "pct_of_distance": "maximum 2D error [% of distance]",
    "max_azimuth_err_rad": "maximum azimuth error [rad]",
    "reconv_s": "re-convergence time [s]",
    "nees_pos": "mean position NEES",
}


def kept_label(k) -> str:
    """'all' for ALL (no outage), else the number of satellites kept."""
    return "all" if int(k) == ALL else str(int(k))


def _frame(ds: xr.Dataset, variables: str | Sequence[str]) -> pd.DataFrame:
    """Long form: one row per scenario, the dimension values plus length_s, and one column per
    variable (one frame for all of them: their dimensions are the scenario axes)."""
    names = [variables] if isinstance(variables, str) else list(variables)
    for var in names:
        dims = ds[var].dims
        if "solution" in dims:  # pooling forward and smoothed would mix two estimators
            raise ValueError(f"{var!r} has a 'solution' axis; take one solution_views(ds) entry")
        if "enu" in dims:
            raise ValueError(f"{var!r} has an 'enu' axis; pick one component or a scalar metric")
    dims = list(dict.fromkeys(d for var in names for d in ds[var].dims))  # the first's order
    df = ds[names].to_dataframe(dim_order=dims).reset_index()
    if "length_s" in ds.coords and "length_s" not in df:
        length = ds["length_s"].to_dataframe().reset_index()
        df = df.merge(length[["duration", "placement", "length_s"]], on=["duration", "placement"])
    return df


def _agg(df: pd.DataFrame, var: str, by: Sequence[str]) -> pd.DataFrame:
    def p90(x):
        x = x.dropna()
        return float(np.percentile(x, 90)) if len(x) else np.nan

    g = df.groupby(list(by), sort=False)[var]
    out = g.agg(n="count", mean="mean", median="median", p90=p90, max="max").reset_index()
    return out


def _ordered(df: pd.DataFrame, ds: xr.Dataset, cols: Sequence[str]) -> pd.DataFrame:
    """Sort rows in the Dataset's coordinate order (modes as configured, 'all' last)."""
    keys = []
    for c in cols:
        if c in ds.coords and ds[c].ndim == 1 and c in ds.dims:
            order = {v: i for i, v in enumerate(ds[c].values.tolist())}
            if c == "satellites_kept":
                order = {v: (np.inf if v == ALL else v) for v in order}
            keys.append(df[c].map(order))
        else:
            keys.append(df[c])
    idx = np.lexsort([
        np.asarray(k, float) if pd.api.types.is_numeric_dtype(k) else pd.factorize(k)[0]
        for k in reversed(keys)
    ])
    return df.iloc[idx].reset_index(drop=True)


def table_by_satellites(ds: xr.Dataset, var: str = "max_2d_m") -> pd.DataFrame:
    """Seed-000 Table 5.2 form, long: (system, duration_s, satellites_kept, mode) -> n, mean,
    median, p90, max of ``var`` over all other axes."""
    df = _frame(ds, var)
    df["duration_s"] = df["length_s"] if (ds["duration"] < 0).any() else df["duration"]
    out = _agg(df, var, ["system", "duration_s", "satellites_kept", "mode"])
    out = _ordered(out, ds, ["system", "duration_s", "satellites_kept", "mode"])
    return out[["system", "duration_s", "satellites_kept", "mode", *STATS]]


def table_by_duration(
    ds: xr.Dataset, var: str = "max_2d_m", satellites_kept: int | None = 0
) -> pd.DataFrame:
    """Seed-004 form, long: (system, duration_s, mode) -> statistics for one satellites-kept
    level (default 0, complete outages; the lowest level present if 0 is absent; None pools
    every level)."""
    df = _frame(ds, var)
    levels = ds["satellites_kept"].values.tolist()
    if satellites_kept is not None:
        if satellites_kept not in levels:
            outage_levels = sorted(k for k in levels if k != ALL)
            satellites_kept = outage_levels[0] if outage_levels else ALL
        df = df[df["satellites_kept"] == satellites_kept]
    df = df.assign(duration_s=df["length_s"])
    out = _agg(df, var, ["system", "duration_s", "mode"])
    out = _ordered(out, ds, ["system", "duration_s", "mode"])
    out.insert(1, "satellites_kept", ALL - 1 if satellites_kept is None else satellites_kept)
    return out[["system", "satellites_kept", "duration_s", "mode", *STATS]]


def _fmt(x) -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    return f"{x:.1f}" if abs(x) >= 100 else f"{x:.2f}"


def _cell(row) -> str:
    return f"{_fmt(row['mean'])} ({_fmt(row['median'])} / {_fmt(row['p90'])})"


def _pivot_md(df: pd.DataFrame, row_key: str, row_label: str, row_fmt, modes) -> list[str]:
    lines = [
        f"| {row_label} | " + " | ".join(modes) + " |",
        "|---|" + "---|" * len(modes),
    ]
    for r in pd.unique(df[row_key]):
        sub = df[df[row_key] == r].set_index("mode")
        cells = [_cell(sub.loc[m]) if m in sub.index else "n/a" for m in modes]
        lines.append(f"| {row_fmt(r)} | " + " | ".join(cells) + " |")
    return lines


def _n_text(df: pd.DataFrame) -> str:
    n = df["n"].to_numpy()
    return f"{n.min()}" if n.min() == n.max() else f"{n.min()}-{n.max()}"


def pooled_text(ds: xr.Dataset) -> str:
    """What one table cell pools, e.g. '7 placements x 3 realizations' (the axes other than
    system, duration, satellites kept and mode; policies and ramps when there are several)."""
    def count(dim, one, many):
        n = ds.sizes.get(dim, 1)
        return f"{n} {one if n == 1 else many}"

    parts = [count("placement", "placement", "placements"),
             count("realization", "realization", "realizations")]
    parts += [count(d, d, many) for d, many in (("policy", "policies"), ("ramp", "ramps"))
              if ds.sizes.get(d, 1) > 1]
    return " x ".join(parts)


def _cell_text(sub: pd.DataFrame, pooled: str | None) -> str:
    n = sub["n"].to_numpy()
    if pooled is None:
        return f"mean (median / 90th percentile) over {_n_text(sub)} outages per cell"
    text = f"mean (median / 90th percentile) of {n.max()} outages per cell = {pooled}"
    if n.min() != n.max():
        text += f" (down to {n.min()} where the metric is undefined)"
    return text


def markdown_by_satellites(df: pd.DataFrame, var: str = "max_2d_m",
                           pooled: str | None = None) -> str:
    """Markdown of ``table_by_satellites``: rows satellites kept, columns modes; ``pooled``
    (``pooled_text``) says what a cell holds."""
    label = _LABELS.get(var, var)
    out = []
    for (system, dur), sub in df.groupby(["system", "duration_s"], sort=False):
        modes = list(pd.unique(sub["mode"]))
        out.append(f"### Average {label} by satellites kept x mode: {system}, {dur:g} s outages")
        out.append("")
        out.append(_cell_text(sub, pooled))
        out.append("")
        out += _pivot_md(sub, "satellites_kept", "satellites kept", kept_label, modes)
        out.append("")
    return "\n".join(out)


def markdown_by_duration(df: pd.DataFrame, var: str = "max_2d_m",
                         pooled: str | None = None) -> str:
    """Markdown of ``table_by_duration``: rows outage durations, columns modes."""
    label = _LABELS.get(var, var)
    out = []
    for system, sub in df.groupby("system", sort=False):
        k = int(sub["satellites_kept"].iloc[0])
        what = "all levels" if k == ALL - 1 else f"{kept_label(k)} satellites kept"
        modes = list(pd.unique(sub["mode"]))
        out.append(f"### Average {label} by outage duration x mode: {system}, {what}")
        out.append("")
        out.append(_cell_text(sub, pooled))
        out.append("")
        out += _pivot_md(sub, "duration_s", "duration", lambda d: f"{d:g} s", modes)
        out.append("")
    return "\n".join(out)


#: Consistency verdict of a cell from its mean position NEES (``table_summary``).
CONSISTENT, OVER, UNDER = "consistent", "over-confident", "under-confident"


def table_summary(ds: xr.Dataset) -> pd.DataFrame:
    """Per (system, duration_s, satellites_kept, mode): n, mean maximum 2D error, mean error as
    % of the distance travelled, median re-convergence time of the outages that re-converged
    and their fraction, mean position NEES over the outage windows with its 95 % band and the
    verdict.

    Band: outages of one realization share its noise and drive (and their windows may
    overlap), so they are not independent; the test is over realizations. Each realization's
    mean NEES (over its outages' window means) is taken as one chi2(3) draw, and the mean over
    the R realizations is tested against chi2(3 R) / R. Averaging over epochs and outages only
    narrows the true spread of a realization's mean, so this band is wider than the true
    one: a cell outside it is over-confident (mean above) or under-confident (below) with
    at most the 5 % false-alarm rate; NaN NEES (no covariance) gives no verdict."""
    from scipy.stats import chi2

    cols = ["max_2d_m", "pct_of_distance", "reconv_s", "reconverged", "nees_pos"]
    df = _frame(ds, cols)
    df["duration_s"] = df["length_s"] if (ds["duration"] < 0).any() else df["duration"]
    rows = []
    for key, g in df.groupby(["system", "duration_s", "satellites_kept", "mode"], sort=False):
        nees = g.groupby("realization")["nees_pos"].mean().dropna()  # one per realization
        n_nees = len(nees)
        lo = hi = np.nan
        verdict = "n/a"
        if n_nees:
            lo, hi = (chi2.ppf(q, 3 * n_nees) / n_nees for q in (0.025, 0.975))
            m = nees.mean()
            verdict = OVER if m > hi else UNDER if m < lo else CONSISTENT
        reconv = g["reconv_s"][g["reconverged"].astype(bool)]
        rows.append(dict(zip(["system", "duration_s", "satellites_kept", "mode"], key,
                             strict=True),
                         n=int(g["max_2d_m"].count()), max_2d_mean=g["max_2d_m"].mean(),
                         pct_of_distance_mean=g["pct_of_distance"].mean(),
                         reconv_median_s=reconv.median() if len(reconv) else np.nan,
                         reconverged_frac=float(g["reconverged"].astype(bool).mean()),
                         nees_pos_mean=nees.mean() if n_nees else np.nan,
                         nees_lo=lo, nees_hi=hi, consistency=verdict))
    out = pd.DataFrame(rows)
    return _ordered(out, ds, ["system", "duration_s", "satellites_kept", "mode"])


def markdown_summary(df: pd.DataFrame, pooled: str | None = None) -> str:
    """Markdown of ``table_summary``: one row per (satellites kept, mode), per system and
    duration; over-confident cells in bold."""
    out = []
    for (system, dur), sub in df.groupby(["system", "duration_s"], sort=False):
        out += [f"### Re-convergence, error per distance and consistency: {system}, {dur:g} s "
                "outages", ""]
        what = f"{sub['n'].max()} outages per row" + (f" = {pooled}" if pooled else "")
        out += [f"means of {what}; re-convergence: median of the outages that re-converged "
                "within the recovery period (their share in brackets); NEES: mean position "
                "NEES over the outage windows, 3 = consistent, with the 95 % band of a mean "
                "over the realizations (report.table_summary)", ""]
        out += ["| satellites kept | mode | max 2D [m] | % of distance | re-convergence [s] | "
                "NEES pos (band) | filter |", "|---|---|---|---|---|---|---|"]
        for _, r in sub.iterrows():
            verdict = f"**{r['consistency']}**" if r["consistency"] == OVER else r["consistency"]
            out.append(
                f"| {kept_label(r['satellites_kept'])} | {r['mode']} | {_fmt(r['max_2d_mean'])} | "
                f"{_fmt(r['pct_of_distance_mean'])} | {_fmt(r['reconv_median_s'])} "
                f"({100 * r['reconverged_frac']:.0f} %) | {_fmt(r['nees_pos_mean'])} "
                f"({_fmt(r['nees_lo'])}-{_fmt(r['nees_hi'])}) | {verdict} |")
        out.append("")
    return "\n".join(out)


def solution_views(ds: xr.Dataset) -> list[tuple[str | None, xr.Dataset]]:
    """[(solution, Dataset of that solution)], or [(None, ds)] for a study without smoothing."""
    if "solution" not in ds.dims:
        return [(None, ds)]
    return [(str(s), ds.sel(solution=s)) for s in ds["solution"].values]


_SOLUTION_TITLES = {"forward": "Forward filter", "smoothed": "Smoothed (forward + RTS smoother)"}


def _check_write(path: Path, overwrite: bool):
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")


def write_tables(
    ds: xr.Dataset, out_dir: str | os.PathLike, var: str = "max_2d_m", *, overwrite: bool = True
) -> dict[str, Path]:
    """table.md (both forms), table_by_satellites.csv and table_by_duration.csv in out_dir.

    Tables are views of results.nc and are regenerated by default (``overwrite=False`` refuses
    to replace existing files)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "markdown": out_dir / "table.md",
        "by_satellites_csv": out_dir / "table_by_satellites.csv",
        "by_duration_csv": out_dir / "table_by_duration.csv",
    }
    for p in paths.values():
        _check_write(p, overwrite)
    title = ds.attrs.get("title", "jaxnav outage sweep")
    lines = [f"# {title}", "", f"jaxnav {ds.attrs.get('jaxnav_version', '?')}, config hash "
             f"{str(ds.attrs.get('config_hash', '?'))[:12]}", ""]
    long = {"by_satellites_csv": [], "by_duration_csv": []}
    for solution, view in solution_views(ds):
        by_sat = table_by_satellites(view, var)
        by_dur = table_by_duration(view, var)
        if solution is not None:
            lines += [f"## {_SOLUTION_TITLES.get(solution, solution)}", ""]
            by_sat.insert(0, "solution", solution)
            by_dur.insert(0, "solution", solution)
        pooled = pooled_text(view)
        lines += [markdown_by_satellites(by_sat, var, pooled),
                  markdown_by_duration(by_dur, var, pooled)]
        if all(v in view for v in ("pct_of_distance", "reconv_s", "reconverged", "nees_pos")):
            lines.append(markdown_summary(table_summary(view), pooled))
        long["by_satellites_csv"].append(by_sat)
        long["by_duration_csv"].append(by_dur)
    paths["markdown"].write_text("\n".join(lines))
    for key, parts in long.items():
        df = pd.concat(parts, ignore_index=True)
        df = df.assign(satellites_kept=[
            "pooled" if k == ALL - 1 else kept_label(k) for k in df["satellites_kept"]
        ])
        df.to_csv(paths[key], index=False, float_format="%.6g")
    return paths


# ----------------------------------------------------------------------------------------------
# Plots
# ----------------------------------------------------------------------------------------------
def _figure(n_panels: int, ncols: int = 4, size=(4.2, 3.2)):
    from matplotlib.figure import Figure  # Agg canvas on savefig: no display, no pyplot state

    ncols = max(1, min(ncols, n_panels))
    nrows = -(-n_panels // ncols)
    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, axes[:n_panels]


def error_growth_curves(ds: xr.Dataset, system: str, mode: str):
    """The curves of one ``plot_error_growth`` panel: (longest traced outage [s], its ramp [s],
    {satellites kept: (time since outage start [s], median, 10th, 90th percentile of the 2D
    error [m] over the traced runs, number of runs)}), levels sorted with 'all' last."""
    on = (ds["trace_system"].values == system) & (ds["trace_mode"].values == mode)
    sel = np.flatnonzero(on)
    longest = ds["trace_outage_s"].values[sel].max()
    sel = sel[ds["trace_outage_s"].values[sel] == longest]
    ramp = float(ds["trace_ramp_s"].values[sel].max())
    kept = ds["trace_satellites_kept"].values
    curves = {}
    for k in sorted(set(kept[sel].tolist()), key=lambda k: (k == ALL, k)):
        rows = sel[kept[sel] == k]
        err = ds["trace_err_enu_m"].values[rows]
        e2 = np.hypot(err[..., 0], err[..., 1])  # [runs, epochs]
        lo, med, hi = np.nanpercentile(e2, [10, 50, 90], axis=0)
        curves[k] = (ds["trace_time_s"].values[rows[0]], med, lo, hi, len(rows))
    return float(longest), ramp, curves


def plot_error_growth(
    ds: xr.Dataset, path: str | os.PathLike, *, system: str | None = None
) -> Path | None:
    """2D error vs time since the outage start, one panel per mode, one curve per
    satellites-kept level at the longest traced duration: the median over the traced runs
    (placements x realizations, ``plan`` picks them), with the 10-90 % band of the fewest
    satellites kept and of no outage (``error_growth_curves``), outage shaded; the title says
    how many runs a curve holds.
    None when the Dataset holds no traces."""
    if "trace_err_enu_m" not in ds or ds.sizes.get("trace", 0) == 0:
        return None
    system = ds["trace_system"].values[0] if system is None else system
    on = ds["trace_system"].values == system
    modes = [m for m in ds["mode"].values.tolist() if np.any(on & (ds["trace_mode"].values == m))]
    fig, axes = _figure(len(modes))
    for ax, mode in zip(axes, modes, strict=True):
        longest, ramp, curves = error_growth_curves(ds, system, mode)
        if ramp > 0:
            ax.axvspan(-ramp, longest + ramp, color="0.94", lw=0, label="degraded (ramp)")
        ax.axvspan(0.0, longest, color="0.86", lw=0, label=f"outage ({longest:g} s)")
        outage = [k for k in curves if k != ALL]  # five bands would hide each other
        banded = [min(outage)] * bool(outage) + [ALL] * (ALL in curves)
        for i, (k, (t, med, lo, hi, n_runs)) in enumerate(curves.items()):
            label = f"{kept_label(k)} satellites kept" if k != ALL else "no outage (all)"
            ax.plot(t, med, lw=1.4, color=f"C{i}", label=label)
            if n_runs >= 3 and k in banded:  # a band needs a few runs
                ax.fill_between(t, lo, hi, color=f"C{i}", alpha=0.2, lw=0)
        counts = [c[4] for c in curves.values()]
        ax.set_yscale("log")
        ax.set_xlabel("time since outage start [s]")
        ax.set_ylabel("2D error [m]")
        n = f"{min(counts)}" if min(counts) == max(counts) else f"{min(counts)}-{max(counts)}"
        what = (f"10-90 % band: {', '.join(kept_label(k) for k in banded)} kept"
                if min(counts) >= 3 else "no band below 3 runs")
        ax.set_title(f"{mode} / {system}\nmedian of {n} runs per curve; {what}", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def _boxes(ax, groups: list, modes: list, data: dict, labels: list[str]):
    width = 0.8 / max(len(modes), 1)
    for i, mode in enumerate(modes):
        pos = np.arange(len(groups)) + (i - (len(modes) - 1) / 2) * width
        vals = [np.asarray(data[(g, mode)]) for g in groups]
        vals = [v[np.isfinite(v)] if v.size else v for v in vals]
        keep = [j for j, v in enumerate(vals) if v.size]
        if not keep:
            continue
        bp = ax.boxplot([vals[j] for j in keep], positions=pos[keep], widths=width * 0.9,
                        whis=(10, 90), showfliers=False, patch_artist=True,
                        medianprops={"color": "k"})
        color = f"C{i}"
        for b in bp["boxes"]:
            b.set(facecolor=color, alpha=0.5)
        ax.plot([], [], color=color, lw=6, alpha=0.5, label=mode)
    ax.set_xticks(np.arange(len(groups)), labels)


def plot_distributions(
    ds: xr.Dataset, out_dir: str | os.PathLike, var: str = "max_2d_m", suffix: str = ""
) -> dict[str, Path]:
    """Box plots (whiskers 10th-90th percentile) of ``var`` by satellites kept and by duration
    (complete outages, as the seed-004 table), one box per mode, one panel per system; files
    ``dist_by_satellites{suffix}.png`` and, for studies of two or more durations,
    ``dist_by_duration{suffix}.png``."""
    out_dir = Path(out_dir)
    df = _frame(ds, var)
    modes = ds["mode"].values.tolist()
    systems = ds["system"].values.tolist()
    paths = {}

    kept = ds["satellites_kept"].values.tolist()
    kept_sorted = sorted(kept, key=lambda k: (k == ALL, k))
    fig, axes = _figure(len(systems), ncols=2, size=(6.0, 3.8))
    for ax, system in zip(axes, systems, strict=True):
        sub = df[df["system"] == system]
        data = {(k, m): sub[(sub["satellites_kept"] == k) & (sub["mode"] == m)][var]
                for k in kept_sorted for m in modes}
        _boxes(ax, kept_sorted, modes, data, [kept_label(k) for k in kept_sorted])
        ax.set_xlabel("satellites kept")
        ax.set_ylabel(_LABELS.get(var, var))
        ax.set_yscale("log")
        ax.set_title(system)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    paths["by_satellites"] = out_dir / f"dist_by_satellites{suffix}.png"
    fig.savefig(paths["by_satellites"], dpi=110)

    outage_levels = sorted(k for k in kept if k != ALL)
    level = 0 if 0 in kept else (outage_levels[0] if outage_levels else ALL)
    durations = sorted(pd.unique(df["length_s"]))
    if len(durations) < 2:  # one box per mode would repeat dist_by_satellites' column
        return paths
    fig, axes = _figure(len(systems), ncols=2, size=(6.0, 3.8))
    for ax, system in zip(axes, systems, strict=True):
        sub = df[(df["system"] == system) & (df["satellites_kept"] == level)]
        data = {(d, m): sub[(sub["length_s"] == d) & (sub["mode"] == m)][var]
                for d in durations for m in modes}
        _boxes(ax, durations, modes, data, [f"{d:g} s" for d in durations])
        ax.set_xlabel(f"outage duration ({kept_label(level)} satellites kept)")
        ax.set_ylabel(_LABELS.get(var, var))
        ax.set_yscale("log")
        ax.set_title(system)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    paths["by_duration"] = out_dir / f"dist_by_duration{suffix}.png"
    fig.savefig(paths["by_duration"], dpi=110)
    return paths


def write_report(
    ds: xr.Dataset, out_dir: str | os.PathLike, var: str = "max_2d_m", *, overwrite: bool = True
) -> dict[str, Path]:
    """Tables (write_tables) and plots (error growth, distributions) into out_dir."""
    out_dir = Path(out_dir)
    paths = write_tables(ds, out_dir, var, overwrite=overwrite)
    views = solution_views(ds)
    for solution, _ in views:
        sfx = "" if solution in (None, "forward") else f"_{solution}"
        for name in ("error_growth", "dist_by_satellites", "dist_by_duration"):
            _check_write(out_dir / f"{name}{sfx}.png", overwrite)
    for solution, view in views:
        sfx = "" if solution in (None, "forward") else f"_{solution}"
        growth = plot_error_growth(view, out_dir / f"error_growth{sfx}.png")
        if growth is not None:
            paths[f"error_growth{sfx}"] = growth
        for key, p in plot_distributions(view, out_dir, var, sfx).items():
            paths[f"{key}{sfx}"] = p
    return paths
