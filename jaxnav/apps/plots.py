"""Pictures of a recorded-data run, next to its ``.pos``: what RTKPLOT users look at.

``write_run_plots(pos_path, sol, ...)`` writes, for ``OUT.pos``:

- ``OUT.track.png``: the solution's east / north track (metres from the reference origin), the
  reference track beside it when there is one, the outage epochs in red;
- ``OUT.error.png`` (with a reference): east, north and up error against time with the filter's
  1 / 2 / 3-sigma envelope (the ``.pos`` sigmas), outages shaded;
- ``OUT.outages.png`` (with outages and a reference): the maximum 2D error of each outage;
- ``OUT.nsat.png``: satellites used per epoch, outages shaded;
- ``OUT.summary.md``: the figures behind them (RMS and maximum error, the share of epochs
  inside the 1 / 2 / 3-sigma bounds against the 68.3 / 95.4 / 99.7 % of a Gaussian, the mean
  (error / sigma)^2 per axis, each outage's maximum error) and the list of files.

Times are seconds since ``t0_gps_s`` (the first IMU sample for ``jaxnav lc`` / ``ins``, whose
outage start times count from it; the first epoch for ``jaxnav ppp``). Matplotlib's Agg
canvas: no display needed.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxnav import geodesy
from jaxnav.io.pos import PosSolution

#: Face colours of the outage shading and of the strip over it (a pixel test looks for it),
#: and the strip's height as a fraction of the axes.
OUTAGE_RGB = (1.0, 0.8, 0.8)
OUTAGE_STRIP_RGB = (0.85, 0.1, 0.1)
STRIP = 0.04
#: Gaussian probability inside 1, 2, 3 sigma (one axis).
GAUSS_INSIDE = (0.6827, 0.9545, 0.9973)


class Outage(NamedTuple):
    """One outage of a run: id, start and end [s since t0], its maximum 2D error [m] (NaN when
    there is no reference)."""

    id: str
    start_s: float
    end_s: float
    max_2d_m: float = float("nan")


def enu_of(llh: np.ndarray, origin_llh: np.ndarray) -> np.ndarray:
    """[N, 3] east, north, up [m] of ``llh`` [N, 3] (rad, rad, m) from ``origin_llh``: the
    geodetic difference scaled by the origin's metres per radian (metre-accurate over a
    few km, as RTKPLOT's ENU view)."""
    import jax.numpy as jnp

    m_n, m_e, _ = np.asarray(geodesy.metres_per_radian(jnp.asarray(origin_llh, float)))
    d = np.asarray(llh, float) - np.asarray(origin_llh, float)
    return np.stack([d[:, 1] * m_e, d[:, 0] * m_n, d[:, 2]], axis=1)


def reference_moved(ref_llh: np.ndarray, offset_enu_m) -> np.ndarray:
    """[N, 3] ``ref_llh`` moved by an east / north / up offset [m] (the inverse of
    ``enu_of`` at each epoch), e.g. ``tc_recorded.reference_offset``."""
    import jax
    import jax.numpy as jnp

    ref = np.asarray(ref_llh, float)
    m = np.asarray(jax.vmap(geodesy.metres_per_radian)(jnp.asarray(ref)))  # N, E, U per rad
    e, n, u = np.asarray(offset_enu_m, float)
    return ref + np.stack([n / m[:, 0], e / m[:, 1], np.full(len(ref), u)], axis=1)


def _figure(nrows: int, size=(9.0, 2.4)):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0], size[1] * nrows), layout="constrained")
    return fig, np.atleast_1d(fig.subplots(nrows, 1, sharex=True, squeeze=False)).ravel()


def _shade(ax, outages: Sequence[Outage]):
    """A light background span per outage and, drawn over everything, a strip along the top
    of the axes in ``OUTAGE_STRIP_RGB`` (still visible where sigma envelopes cover the span)."""
    for i, o in enumerate(outages):
        ax.axvspan(o.start_s, o.end_s, facecolor=OUTAGE_RGB, edgecolor="none", zorder=0,
                   label="outage" if i == 0 else None)
        ax.axvspan(o.start_s, o.end_s, ymin=1.0 - STRIP, ymax=1.0, facecolor=OUTAGE_STRIP_RGB,
                   edgecolor="none", zorder=5)


def error_figure(t_s, err_enu, sd_enu, outages: Sequence[Outage] = ()):
    """(figure, axes) of the east / north / up error with the 1 / 2 / 3-sigma envelope."""
    fig, axes = _figure(3)
    for j, (ax, name) in enumerate(zip(axes, ("east", "north", "up"), strict=True)):
        _shade(ax, outages)
        for k, alpha in ((3, 0.12), (2, 0.2), (1, 0.3)):
            ax.fill_between(t_s, -k * sd_enu[:, j], k * sd_enu[:, j], color="C0", alpha=alpha,
                            lw=0, zorder=1, label=f"{k} sigma" if j == 0 else None)
        ax.plot(t_s, err_enu[:, j], color="k", lw=0.8, zorder=2,
                label="error" if j == 0 else None)
        # the error's range, not the start-up sigmas, sets the scale (as RTKPLOT's)
        lim = 1.3 * max(np.nanpercentile(np.abs(err_enu[:, j]), 99.5),
                        np.nanmedian(3 * sd_enu[:, j]), 1e-3)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{name} error [m]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, ncol=5, loc="upper left")
    axes[-1].set_xlabel("time [s]")
    return fig, axes


def _stats(err_enu, sd_enu, mask):
    e, s = err_enu[mask], sd_enu[mask]
    rms = np.sqrt(np.mean(e**2, axis=0))
    h = np.hypot(e[:, 0], e[:, 1])
    inside = [np.mean(np.abs(e) <= k * s, axis=0) for k in (1, 2, 3)]
    z2 = np.mean((e / s) ** 2, axis=0)
    return rms, float(np.sqrt(np.mean(h**2))), float(h.max()), inside, z2


def write_run_plots(
    pos_path: str | Path,
    sol: PosSolution,
    *,
    t0_gps_s: float,
    ref_llh: np.ndarray | None = None,
    outages: Sequence[Outage] = (),
    title: str = "",
    ref_name: str = "reference",
    outages_in_solution: bool = True,
) -> dict[str, Path]:
    """Write the PNGs and the Markdown summary of the module docstring next to ``pos_path``;
    ``ref_llh``: [N, 3] a reference track at the solution epochs (NaN where absent) or [3] a
    fixed point; ``outages_in_solution`` False when each outage was a separate run and ``sol``
    has none (``jaxnav ins`` tight): no shading, the bars and the table only. Returns
    {name: path}."""
    pos_path = Path(pos_path)

    def beside(suffix):  # OUT.pos -> OUT.<suffix>, keeping dots inside the name
        return pos_path.parent / f"{pos_path.stem}.{suffix}"

    t = np.asarray(sol.time_gps_s, float) - t0_gps_s
    llh = np.asarray(sol.llh, float)
    ref = None if ref_llh is None else np.broadcast_to(np.asarray(ref_llh, float), llh.shape)
    has_ref = ref is not None and bool(np.isfinite(ref).all(axis=1).any())
    origin = ref[np.flatnonzero(np.isfinite(ref).all(axis=1))[0]] if has_ref else llh[0]
    enu = enu_of(llh, origin)
    shaded = tuple(outages) if outages_in_solution else ()
    in_outage = np.zeros(t.size, bool)
    for o in shaded:
        in_outage |= (t >= o.start_s) & (t < o.end_s)
    paths: dict[str, Path] = {}

    fig, (ax,) = _figure(1, size=(6.5, 6.0))
    if has_ref:
        r = enu_of(ref, origin)
        ax.plot(r[:, 0], r[:, 1], color="0.6", lw=2.5, label=ref_name)
    ax.plot(enu[:, 0], enu[:, 1], color="C0", lw=1.0, label="solution")
    if in_outage.any():
        ax.plot(np.where(in_outage, enu[:, 0], np.nan), np.where(in_outage, enu[:, 1], np.nan),
                color="red", lw=1.6, label="in an outage")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_title(title or pos_path.name, fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    paths["track"] = beside("track.png")
    fig.savefig(paths["track"], dpi=100)

    sd_enu = np.asarray(sol.sd_neu_m, float)[:, [1, 0, 2]]
    lines = [f"# {title or pos_path.name}", "", f"Solution `{pos_path.name}`: {t.size} epochs, "
             f"{t[0]:.2f} to {t[-1]:.2f} s (time 0 = GPS second {t0_gps_s:.3f})."]
    if has_ref:
        err = enu_of(llh, origin) - enu_of(ref, origin)
        ok = np.isfinite(err).all(axis=1) & (sd_enu > 0).all(axis=1)
        fig, axes = error_figure(t, err, sd_enu, shaded)
        axes[0].set_title(f"error against the {ref_name}; 1 / 2 / 3-sigma envelope of the "
                          "solution's own sigmas", fontsize=9)
        paths["error"] = beside("error.png")
        fig.savefig(paths["error"], dpi=100)
        lines += ["", f"Against the {ref_name} (error = solution - reference):", "",
                  "| epochs | RMS E / N / U [m] | 2D RMS [m] | 2D max [m] | inside 1 / 2 / 3 "
                  "sigma (mean of E, N, U) | mean (error/sigma)^2 E / N / U |",
                  "|---|---|---|---|---|---|"]
        rows = [("all", ok)] + ([("outside outages", ok & ~in_outage),
                                  ("in outages", ok & in_outage)] if in_outage.any() else [])
        for name, m in rows:
            if not m.any():
                continue
            rms, h_rms, h_max, inside, z2 = _stats(err, sd_enu, m)
            share = " / ".join(f"{100 * np.mean(x):.0f} %" for x in inside)
            lines.append(f"| {name} ({int(m.sum())}) | {rms[0]:.3f} / {rms[1]:.3f} / "
                         f"{rms[2]:.3f} | {h_rms:.3f} | {h_max:.3f} | {share} | "
                         f"{z2[0]:.2f} / {z2[1]:.2f} / {z2[2]:.2f} |")
        lines += ["", "A Gaussian error with true sigmas is inside 1 / 2 / 3 sigma "
                  f"{' / '.join(f'{100 * p:.1f} %' for p in GAUSS_INSIDE)} of the time, and its "
                  "mean (error/sigma)^2 is 1."]
    if outages:
        lines += [""] + ([] if outages_in_solution else [
            "The outages below were separate runs; the solution above has none."])
        lines += ["", "| outage | start [s] | end [s] | max 2D error [m] |", "|---|---|---|---|"]
        lines += [f"| {o.id} | {o.start_s:.2f} | {o.end_s:.2f} | {o.max_2d_m:.3f} |"
                  for o in outages]
        if has_ref and np.isfinite([o.max_2d_m for o in outages]).any():
            fig, (ax,) = _figure(1, size=(max(4.0, 0.5 * len(outages) + 2.0), 3.2))
            ax.bar(np.arange(len(outages)), [o.max_2d_m for o in outages], color="C3")
            ax.set_xticks(np.arange(len(outages)), [o.id for o in outages], rotation=60,
                          fontsize=7)
            ax.set_ylabel("max 2D error [m]")
            ax.set_title(f"maximum 2D error per outage (mean "
                         f"{np.nanmean([o.max_2d_m for o in outages]):.2f} m)", fontsize=9)
            ax.grid(True, axis="y", alpha=0.3)
            paths["outages"] = beside("outages.png")
            fig.savefig(paths["outages"], dpi=100)
    fig, (ax,) = _figure(1)
    _shade(ax, shaded)
    ax.step(t, np.asarray(sol.ns), where="post", color="C2", lw=1.0)
    ax.set_ylabel("satellites used")
    ax.set_xlabel("time [s]")
    ax.grid(True, alpha=0.3)
    paths["nsat"] = beside("nsat.png")
    fig.savefig(paths["nsat"], dpi=100)
    paths["summary"] = beside("summary.md")
    lines += ["", "Files: " + ", ".join(f"`{p.name}`" for p in paths.values()), ""]
    paths["summary"].write_text("\n".join(lines))
    return paths
