"""Pictures of a recorded-data run (jaxnav.apps.plots), on a synthetic track with a known
outage: the files exist, the shaded outage sits where the schedule says (pixel check), and the
summary's figures are those of the arrays."""

from __future__ import annotations

import numpy as np
import pytest

from jaxnav.apps import plots
from jaxnav.io.pos import PosSolution

T0 = 1_000_000.0
OUT_START, OUT_END = 100.0, 130.0
SD_M = 0.5


def _run(n=200, seed=0):
    """A 1-Hz east-going track, its reference, errors N(0, SD_M) outside the outage and a
    quadratic drift inside it; sigmas SD_M, growing in the outage."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    lat0, lon0 = np.radians(44.23), np.radians(-76.49)
    ref = np.stack([np.full(n, lat0), lon0 + t * 1e-6, np.full(n, 90.0)], axis=1)
    inside = (t >= OUT_START) & (t < OUT_END)
    err = rng.normal(0.0, SD_M, (n, 3))
    err[inside, 0] += 0.02 * (t[inside] - OUT_START) ** 2  # east drift, up to 17 m
    sd = np.full((n, 3), SD_M)
    sd[inside] *= 1.0 + 0.1 * (t[inside, None] - OUT_START)
    llh = ref + np.stack([err[:, 1] / 6.37e6, err[:, 0] / (6.39e6 * np.cos(lat0)), err[:, 2]], 1)
    nan3 = np.full((n, 3), np.nan)
    sol = PosSolution(T0 + t, llh, np.full(n, 6), np.where(inside, 0, 8), sd[:, [1, 0, 2]],
                      np.zeros((n, 3)), np.zeros(n), np.zeros(n), nan3, nan3, nan3)
    return sol, ref, err, sd


def test_files_are_written_and_the_summary_holds_the_arrays_figures(tmp_path):
    sol, ref, _, _ = _run()
    out = tmp_path / "run.v1.pos"
    outage = plots.Outage("o1", OUT_START, OUT_END, 12.5)
    paths = plots.write_run_plots(out, sol, t0_gps_s=T0, ref_llh=ref, outages=[outage],
                                  ref_name="RTK track")
    assert set(paths) == {"track", "error", "outages", "nsat", "summary"}
    for key, p in paths.items():
        assert p.parent == tmp_path and p.name.startswith("run.v1."), p
        data = p.read_bytes()
        assert len(data) > (10_000 if p.suffix == ".png" else 200), key
        if p.suffix == ".png":
            assert data[:8] == b"\x89PNG\r\n\x1a\n", key
    text = paths["summary"].read_text()
    assert "| o1 | 100.00 | 130.00 | 12.500 |" in text
    # the 'outside outages' row: the share inside 1 sigma of each axis, from the arrays
    t = sol.time_gps_s - T0
    err = plots.enu_of(sol.llh, ref[0]) - plots.enu_of(ref, ref[0])
    m = (t < OUT_START) | (t >= OUT_END)
    share = np.mean(np.abs(err[m]) <= SD_M)  # mean over the three axes
    z2 = np.mean((err[m] / SD_M) ** 2, axis=0)
    row = next(ln for ln in text.splitlines() if ln.startswith("| outside outages"))
    assert f"| {100 * share:.0f} % / " in row and f"{z2[0]:.2f} / {z2[1]:.2f} / {z2[2]:.2f}" in row


def test_without_a_reference_only_the_track_and_satellites_are_drawn(tmp_path):
    sol, _, _, _ = _run()
    paths = plots.write_run_plots(tmp_path / "r.pos", sol, t0_gps_s=T0)
    assert set(paths) == {"track", "nsat", "summary"}


def _strip_share(img, ax, x, tol=3 / 255):
    """Share of the pixel column at data x, in the axes' top strip (``plots.STRIP``), that has
    the outage strip's colour."""
    h = img.shape[0]
    bbox = ax.get_window_extent()
    px = ax.transData.transform((x, 0.0))[0]
    top = int(round(h - bbox.y1))
    rows = slice(top + 1, top + int(plots.STRIP * bbox.height) - 1)
    col = img[rows, int(round(px)), :3] / 255.0
    return float(np.mean(np.all(np.abs(col - np.asarray(plots.OUTAGE_STRIP_RGB)) <= tol, axis=1)))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_the_shaded_outage_is_where_the_schedule_says(axis):
    """Rendered error figure: the outage strip's colour fills the top strip of every pixel
    column inside [100, 130) s and of none outside it (a second away from its edges)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    sol, ref, _, sd = _run()
    t = sol.time_gps_s - T0
    err = plots.enu_of(sol.llh, ref[0]) - plots.enu_of(ref, ref[0])
    fig, axes = plots.error_figure(t, err, sd, [plots.Outage("o1", OUT_START, OUT_END)])
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())
    ax = axes[axis]
    for x in (OUT_START + 1.0, 115.0, OUT_END - 1.0):
        assert _strip_share(img, ax, x) == 1.0, x
    for x in (20.0, OUT_START - 1.0, OUT_END + 1.0, 180.0):
        assert _strip_share(img, ax, x) == 0.0, x
