"""``jaxnav lc --sweep``: the recorded drive as a scenario factory of the sweep engine (one
pseudo-satellite slot = the GNSS fix), per constraint mode."""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav.apps.car_config import SWEEP_MODES, CarConfig, lever_arms_b
from jaxnav.apps.lc_drive import Drive
from jaxnav.apps.lc_filter import (
    antenna_track,
    build_filter,
    epoch_inputs,
    initial_carry,
    reference_track,
)
from jaxnav.filter import loose
from jaxnav.study import metrics as mt


# ----------------------------------------------------------------------------------------------
# The sweep on the real drive (jaxnav.study.sweep engine)
# ----------------------------------------------------------------------------------------------
@functools.cache
def lc_ops(lever_b: tuple[float, float, float]):
    """``sweep.FilterOps`` of the loose filter: one pseudo-satellite slot = the GNSS fix, the
    estimate read out at the antenna (the RTK reference is the antenna track)."""
    from jaxnav.study.sweep import FilterOps

    lever = jnp.asarray(lever_b)

    def readout(out):
        # No covariance: the sweep's NEES is a batched LU (jnp.linalg.solve) over chunk x epochs
        # matrices, and jaxlib's parallel batched LU kernel deadlocked (0 % CPU, all threads
        # parked, the caller in jax::ParallelBatchMap) on this 2-core machine from chunks of
        # ~108 scenarios (at 256 even with single-threaded Eigen and synchronous dispatch).
        # NEES is therefore NaN in the sweep.
        llh = antenna_track(lever, out)
        return mt.track(llh, out.vel_enu, out.euler), None

    def with_keep(inp, keep):
        k = keep[..., 0]
        g = inp.gnss._replace(pos_valid=inp.gnss.pos_valid & k, vel_valid=inp.gnss.vel_valid & k)
        # a withheld fix cannot veto ZUPT/ZARU (epoch_inputs)
        return inp._replace(gnss=g, zupt_allowed=inp.zupt_allowed | ~k)

    return FilterOps(
        run=loose.run, readout=readout,
        get_keep=lambda inp: inp.gnss.pos_valid[..., None], with_keep=with_keep,
        smooth=loose.run_smoother,
    )


class DriveFactory:
    """Scenario factory of ``jaxnav.study.sweep.run_sweep`` for one recorded drive.

    Modes are the constraint sets of ``SWEEP_MODES``; the system label is the error-state
    layout of the configuration; realizations are meaningless on recorded data (use 1).
    """

    def __init__(self, cfg: CarConfig, drive: Drive, fingerprint: str):
        self.cfg, self.drive, self._fp = cfg, drive, fingerprint
        self.modes = tuple(SWEEP_MODES)
        self.systems = (cfg.imu_errors_states,)
        lever_ant, _ = lever_arms_b(cfg)
        self.ops = lc_ops(tuple(float(x) for x in lever_ant))

    def fingerprint(self) -> str:
        return self._fp

    def timeline(self, study):
        from jaxnav.study.sweep import Timeline

        return Timeline(self.drive.n_epochs, self.drive.epoch_dt_s,
                        t0_gps_s=float(self.drive.time_gps_s[0]))

    def build(self, study, mode: str, system: str, seed: int):
        from jaxnav.study.sweep import Problem

        nhc, zupt = SWEEP_MODES[mode]
        lf = build_filter(self.cfg, self.drive, nhc=nhc, zupt=zupt)
        carry0 = initial_carry(self.cfg, lf, self.drive)
        inputs = epoch_inputs(self.cfg, self.drive)
        T = self.drive.n_epochs
        return Problem(
            tf=lf, carry0=carry0, inputs=inputs, truth=reference_track(self.drive),
            elevation=jnp.full((T, 1), 0.5 * math.pi), available=inputs.gnss.pos_valid[:, None],
        )


def study_config(cfg: CarConfig, drive: Drive):
    """The ``StudyConfig`` of the [sweep] section: complete outages (0 of 1 slot kept) on a
    grid; the grid origin is the first filter epoch (t_imu0 + ``drive.time_rel_s[0]``)."""
    from jaxnav.study.config import PlacementConfig, StudyConfig, validate

    return validate(StudyConfig(
        name="lc_real_drive", modes=cfg.sweep_modes, systems=(cfg.imu_errors_states,),
        durations_s=cfg.sweep_durations_s, satellites_kept=(0,), recovery_s=cfg.sweep_recovery_s,
        chunk_size=cfg.sweep_chunk_size, max_traces=8, smooth=cfg.sweep_smooth,
        placement=PlacementConfig(kind="grid", convergence_s=cfg.sweep_convergence_s,
                                  spacing_s=cfg.sweep_spacing_s),
    ))


def run_drive_sweep(cfg: CarConfig, drive: Drive, out_dir, fingerprint: str, *,
                    overwrite: bool = False, progress: bool = True):
    """Run the outage sweep of the [sweep] section into ``out_dir`` (results.nc + report)."""
    from jaxnav.study import report
    from jaxnav.study.sweep import run_sweep

    study = study_config(cfg, drive)
    factory = DriveFactory(cfg, drive, fingerprint)
    res = run_sweep(study, factory, out_dir, resume=not overwrite, overwrite=overwrite,
                    progress=progress)
    report.write_report(res.dataset, out_dir)
    return res


def duration_table(ds) -> str:
    """Markdown: max 2D error per duration (rows) and mode (columns): mean / median / p90; one
    table per solution of a smoothed sweep."""
    if "solution" in ds.dims:
        return "\n\n".join(f"{s}:\n" + duration_table(ds.sel(solution=s))
                             for s in ds["solution"].values)
    lines = ["| duration | outages | " + " | ".join(
        f"{m}: mean / median / p90 [m]" for m in ds["mode"].values) + " |"]
    lines.append("|---|---|" + "---|" * ds.sizes["mode"])
    sys_label = ds["system"].values[0]
    for d in ds["duration"].values:
        cells, n = [], 0
        for m in ds["mode"].values:
            x = ds["max_2d_m"].sel(mode=m, system=sys_label, duration=d).values.ravel()
            x = x[np.isfinite(x)]
            n = x.size
            cells.append(f"{x.mean():.2f} / {np.median(x):.2f} / {np.percentile(x, 90):.2f}")
        lines.append(f"| {d:g} s | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
