"""``jaxnav lc``: loosely coupled GNSS/INS on a recorded drive, with withheld-GNSS outages.

    jaxnav lc --imu IMU.csv --imu-tag IMU.csv.tag --gnss GNSS.pos --config CAR.toml
              [--outages SCHEDULE | --outage-grid START:STEP:LENGTH] [--duration S]
              --out OUT.pos [--smooth | --solution forward|combined] [--sweep DIR [--overwrite]]

The filter is ``jaxnav.filter.loose`` (full IMU, 15/21/27 error states) aided by the positions
(and, with ``gnss.use_velocity``, velocities) of an RTKLIB ``.pos`` track, with the vehicle
constraints of ``jaxnav.filter.constraints`` (non-holonomic constraint; ZUPT + ZARU on detected
standstill, allowed only where the GNSS is withheld or slow, see ``epoch_inputs``; no
odometer). The car configuration (TOML, ``configs/car_gnss_imu_drive.toml`` documents every key)
gives the IMU mounting, lever arms, time offset, noise and the constraint switches.

Data flow (documented choices where the sources are silent):

- IMU: ``jaxnav.io.read_imu_csv`` (+ the RTKLIB time tag, + ``imu.time_offset_s``), rotated to
  the body frame with ``sensor_to_body_dcm(mounting + misalignment)``, trapezoidal increments.
  They are **resampled** onto a grid of ``imu.resample_hz`` aligned with the GNSS epochs (the
  loose filter needs K equal samples per epoch): the cumulative integrals of angular rate and
  specific force are interpolated linearly at the grid times and differenced, which keeps every
  integral over the drive (it spreads each sample over at most two grid intervals).
- GNSS: the ``.pos`` epochs on a regular grid (their median interval; a missing epoch is an
  invalid fix); the fix covariance is RTKLIB's sdn/sde/sdu (+ cross terms) with a floor
  ``gnss.pos_sigma_floor_m`` added in quadrature (lever-arm survey and IMU-GNSS timing errors
  that RTKLIB's cm-level sigmas do not contain), likewise for the velocity.
- Epochs: the first filter epoch ends at the second GNSS epoch inside the IMU log (the first one
  is the initial state's time), the last is the last GNSS epoch inside the log (or before
  ``--duration``).
- Initialisation (in-motion alignment, ``loose`` module docstring): position from the first
  fix, roll and pitch by levelling the mean specific force of the first ``alignment.level_s``
  seconds (the log should start at rest), heading unknown until the first fix faster than
  ``alignment.min_speed_m_s``, where it is set to the course over ground. ZUPT/ZARU calibrate
  the gyros while standing; the detector's reference variance is measured over the same
  levelling window (``constraints.zupt_ref_sigma_m_s2 = "start"``: an idling engine shakes the
  IMU far above its white noise). A log whose first fix is faster than the alignment speed is
  aligned at once from that fix's course.
- Outages: GNSS epochs t with start <= t - t_imu0 < start + length withheld (position and
  velocity), t_imu0 the first IMU sample time; from a schedule file (``id,start_s,length_s``,
  ``jaxnav.study.outages.read_schedule``, no overlaps) or a grid START:STEP:LENGTH (starts START,
  START + STEP, ... while the window ends inside the drive; STEP > LENGTH).
- Output: the INS solution **at the antenna** (IMU position + C_b^l l^b with the estimated
  attitude; velocity with the lever-arm rotation term) at every filter epoch, RTKLIB ``.pos``;
  outage epochs get Q = 7 (``jaxnav.io.Q_OUTAGE``), aided epochs keep the fix's Q and ns; sigmas
  from the filter covariance (position block rotated to ENU metres).
- Smoothing (``--smooth`` = ``--solution combined``): the forward filter followed by the RTS
  smoother (``loose.run_smoother``, ``jaxnav.filter.smoother``), i.e. RTKPOST's "combined"
  solution, every epoch estimated from the whole drive; the ``.pos`` holds the smoothed track and
  sigmas, and the outage report gives the forward maximum beside it. There is no "backward"
  solution: an INS run backwards needs a reverse-time mechanization, which jaxnav does not have.
- Per-outage report: start [s after t_imu0], length, distance travelled (RTK track), maximum and
  final 2D error against the RTK track (``jaxnav.study.metrics.window_metrics``: the ``.pos``
  itself is the reference, cm-level when fixed).

Outage sweep (``--sweep DIR``): every start on a grid of ``sweep.spacing_s`` from
``sweep.convergence_s``, each of ``sweep.durations_s``, for each constraint mode in
``sweep.modes``, evaluated by the checkpoint-forking engine ``jaxnav.study.sweep.run_sweep``
(one full run per mode with checkpoints at the outage starts, then all outage windows as one
``vmap`` from their checkpoints, chunked): the drive is its "scenario factory" (``DriveFactory``)
with one pseudo-satellite slot whose keep mask is the GNSS fix's validity. Writes
``DIR/results.nc`` and the report's tables and plots (``jaxnav.study.report``).

Modules: ``car_config.py`` (the TOML), ``lc_drive.py`` (loading), ``lc_filter.py`` (filter,
outages, output), ``lc_sweep.py`` (the sweep); this one is the command line.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav.apps import (
    Stages,
    add_plot_option,
    add_solution_options,
    existing_file,
    plots,
    pos_solution_label,
    run_command,
)
from jaxnav.apps.car_config import (  # noqa: F401  (re-exported: the command's public names)
    SWEEP_MODES,
    UG_M_S2,
    CarConfig,
    CarConfigError,
    config_from_dict,
    imu_error_model,
    lever_arms_b,
    load_config,
)
from jaxnav.apps.lc_drive import (  # noqa: F401
    Drive,
    gnss_fixes_from_pos,
    load_drive,
    resample_increments,
    rest_noise,
)
from jaxnav.apps.lc_filter import (  # noqa: F401
    OutagePlan,
    antenna_track,
    build_filter,
    epoch_inputs,
    grid_schedule,
    initial_carry,
    outage_metrics,
    parse_grid,
    plan_outages,
    reference_track,
    run_filter,
    run_smoothed,
    solution_pos,
)
from jaxnav.apps.lc_sweep import (  # noqa: F401
    DriveFactory,
    duration_table,
    lc_ops,
    run_drive_sweep,
    study_config,
)
from jaxnav.io import pos as pos_io
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot

PROG = "jaxnav lc"


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------
def sigma_ratios(err_enu: np.ndarray, sd_neu_m: np.ndarray) -> np.ndarray:
    """(error / sigma)^2 per epoch and axis [E, 3] (E, N, U), sigmas in RTKLIB (n, e, u) order.

    Its mean over epochs is 1 when the written sigmas are true (a chi-square with 1 dof per axis).
    """
    sd_enu = sd_neu_m[:, [1, 0, 2]]
    return (err_enu / sd_enu) ** 2


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--imu", required=True, type=existing_file,
                   help="IMU CSV log (acc [g], gyro [deg/s], tick [ms]; other units: the "
                        "config's [imu] accel_unit, gyro_unit)")
    p.add_argument("--imu-tag", type=existing_file,
                   help="RTKLIB time-tag file of the IMU log (default IMU.tag)")
    p.add_argument("--gnss", required=True, type=existing_file,
                   help="RTKLIB .pos with velocities (aiding + reference)")
    p.add_argument("--config", required=True, type=existing_file, help="car configuration TOML")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--outages", type=existing_file,
                   help="schedule CSV id,start_s,length_s [s] (start after the first IMU "
                        "sample; default: no outages)")
    g.add_argument("--outage-grid", type=parse_grid, metavar="START:STEP:LENGTH",
                   help="outages at START, START+STEP, ... [s after the first IMU sample] of "
                        "LENGTH seconds each (default: no outages)")
    p.add_argument("--duration", type=float,
                   help="process only the first DURATION s of the log (default: all of it)")
    p.add_argument("--out", required=True, help="output .pos (INS at the antenna)")
    add_solution_options(p)
    p.add_argument("--sweep", metavar="DIR",
                   help="also run the outage sweep of the config's [sweep] table into DIR "
                        "(results.nc, tables)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sweep in DIR")
    p.add_argument("--quiet", action="store_true",
                   help="print only errors and the summary (no progress lines or bar)")
    add_plot_option(p)
    return p


def _fingerprint(args, cfg: CarConfig) -> str:
    h = hashlib.sha256(cfg.to_json().encode())
    for f in (args.imu, args.imu_tag or args.imu + ".tag", args.gnss):
        st_ = os.stat(f)
        h.update(f"{Path(f).name}:{st_.st_size}".encode())
    h.update(f"duration={args.duration}".encode())
    return h.hexdigest()


def main(argv=None) -> int:
    """Entry point of ``jaxnav lc``; returns a process exit code."""
    return run_command(PROG, build_parser(), _main, argv)


def _main(args) -> int:
    cfg = load_config(args.config)
    sched = ot.read_schedule(args.outages, allow_overlap=False) if args.outages else None
    return run(args, cfg, sched)


def run(args, cfg: CarConfig, sched: ot.Schedule | None) -> int:
    """The loose pipeline on ``args`` (the command line's fields) with a validated car
    configuration and outage schedule (``jaxnav ins`` with ``[coupling] kind = "loose"``)."""
    t_start = time.perf_counter()
    if sched is not None and sched.satellites_kept is not None and (
            sched.satellites_kept > 0).any():
        where = f"{args.outages}: " if args.outages else "[outages] "
        raise ValueError(f"{where}satellites_kept > 0 needs raw observations (jaxnav ins with "
                         "[coupling] kind = 'tight'); a .pos fix is withheld whole")
    if sched is not None:  # outages of one run must not overlap
        order = np.argsort(sched.start_s)
        if np.any(sched.start_s[order][1:] < (sched.start_s + sched.length_s)[order][:-1]):
            raise ValueError("the outages of one loose run must not overlap")
    stage = Stages(args.quiet)
    with stage(f"reading the IMU log {Path(args.imu).name} and the GNSS track "
               f"{Path(args.gnss).name}"):
        drive = load_drive(args.imu, args.imu_tag, args.gnss, cfg, duration_s=args.duration)
    if args.outage_grid is not None:
        sched = grid_schedule(drive, *args.outage_grid)
    plan = plan_outages(drive, sched) if sched is not None else None
    t_read = time.perf_counter()

    with stage("building the filter and its inputs"):
        lf = build_filter(cfg, drive)
        carry = initial_carry(cfg, lf, drive)
        withheld = plan.withheld if plan is not None else np.zeros(drive.n_epochs, bool)
        inputs = epoch_inputs(cfg, drive, withheld)
    smooth = getattr(args, "solution", "forward") == "combined"
    with stage("compiling and running the filter" + (" and the smoother" if smooth else "")):
        if smooth:
            out_fwd, out = run_smoothed(lf, carry, inputs)
        else:
            _, out = run_filter(lf, carry, inputs)
            out_fwd = out
        jax.block_until_ready(out)
    t_run = time.perf_counter()
    sol = solution_pos(drive, lf, out, withheld)
    pos_io.write_pos(
        args.out, sol, outage=withheld,
        comments=(
            f"jaxnav lc: loosely coupled INS ({cfg.imu_errors_states}) at the antenna; "
            f"config {Path(args.config).name}; solution "
            f"{'combined (forward + RTS smoother)' if smooth else 'forward'}",
            f"first IMU sample {drive.t_imu0_gps_s:.3f} GPS s (origin of outage start times)",
        ),
        program=f"jaxnav {jaxnav.__version__} lc",
        info=(("inp file", str(args.imu)), ("inp file", str(args.imu_tag or args.imu + ".tag")),
              ("inp file", str(args.gnss)),
              ("pos mode", f"Loosely coupled INS ({cfg.imu_errors_states}) on the --gnss fixes"),
              ("solution", pos_solution_label(smooth))),
    )

    err = np.asarray(mt.enu_errors(jnp.asarray(sol.llh), jnp.asarray(drive.ref_llh)))
    e2 = np.hypot(err[:, 0], err[:, 1])
    aligned = np.asarray(out.aligned)
    aided = ~withheld & np.asarray(drive.fixes.pos_valid)
    sel = aided & aligned
    print(f"{PROG}: {drive.n_epochs} epochs of {drive.epoch_dt_s:g} s "
          f"({drive.time_rel_s[0]:.2f}-{drive.time_rel_s[-1]:.2f} s after the first IMU sample), "
          f"{drive.samples.dv_b.shape[1]} IMU samples each; states {cfg.imu_errors_states}")
    noise = rest_noise(drive)
    if noise is not None:
        model = imu_error_model(cfg)
        gyro_model = np.degrees(np.asarray(model.gyro_arw_rad_sqrt_s))
        accel_model = np.asarray(model.accel_vrw_m_s_sqrt_s) / UG_M_S2
        print(f"IMU noise at the initial {noise[2]:.0f} s standstill (x, y, z): gyro "
              f"{np.array2string(noise[0], precision=4)} deg/s/sqrt(Hz), accel "
              f"{np.array2string(noise[1], precision=0)} ug/sqrt(Hz); filter model: gyro "
              f"{np.array2string(gyro_model, precision=4)}, accel "
              f"{np.array2string(accel_model, precision=0)}")
    if aligned.any():
        i = int(np.argmax(aligned))
        print(f"in-motion alignment at {drive.time_rel_s[i]:.2f} s "
              f"(GNSS speed {np.hypot(*drive.ref_vel_enu[i, :2]):.1f} m/s)")
    else:
        print("never aligned: the vehicle did not exceed [alignment] min_speed_m_s")
    if sel.any():
        print(f"with GNSS (aligned, {int(sel.sum())} epochs): 2D error vs the RTK track RMS "
              f"{np.sqrt(np.mean(e2[sel] ** 2)):.3f} m, max {e2[sel].max():.3f} m; "
              f"up RMS {np.sqrt(np.mean(err[sel, 2] ** 2)):.3f} m; NIS per row "
              f"{np.sum(np.asarray(out.nis)[sel]) / max(np.sum(np.asarray(out.dof)[sel]), 1):.2f}"
              f" (1 = consistent)")
    if plan is not None:
        m = outage_metrics(drive, sol.llh, out, plan)
        z2 = sigma_ratios(err, sol.sd_neu_m)
        fwd_col = f" {'fwd_max_2d_m':>12}" if smooth else ""
        if smooth:
            llh_fwd = antenna_track(lf.system.lever_b, out_fwd)
            m_fwd = outage_metrics(drive, llh_fwd, out_fwd, plan)
        print(f"{'outage':>8} {'start_s':>8} {'length_s':>8} {'dist_m':>8} {'max_2d_m':>9} "
              f"{'final_2d_m':>10} {'z2_e':>6} {'z2_n':>6}{fwd_col}")
        for k, oid in enumerate(plan.ids):
            w = slice(int(plan.start_epoch[k]), int(plan.start_epoch[k] + plan.n_epochs[k]))
            ze, zn = np.mean(z2[w, :2], axis=0)
            fwd_val = f" {float(m_fwd.max_2d_m[k]):12.3f}" if smooth else ""
            print(f"{oid:>8} {plan.start_s[k]:8.2f} {plan.length_s[k]:8.2f} "
                  f"{float(m.distance_m[k]):8.1f} {float(m.max_2d_m[k]):9.3f} "
                  f"{float(m.end_2d_m[k]):10.3f} {ze:6.2f} {zn:6.2f}{fwd_val}")
        print(f"mean max 2D error over the {len(plan.ids)} outages: "
              f"{float(np.mean(m.max_2d_m)):.3f} m"
              + (f" (forward filter {float(np.mean(m_fwd.max_2d_m)):.3f} m)" if smooth else ""))
        ze, zn, zu = np.mean(z2[withheld], axis=0)
        print(f"sigma check over the {int(withheld.sum())} outage epochs: mean (error / sigma)^2 "
              f"E {ze:.2f}, N {zn:.2f}, U {zu:.2f} (1 = sigmas true; z2_e / z2_n per outage)")
    print(f"wrote {args.out}; read {t_read - t_start:.1f} s, filter {t_run - t_read:.1f} s "
          f"(incl. compilation)")
    if not getattr(args, "no_plots", False):
        outages = []
        if plan is not None:
            outages = [plots.Outage(oid, float(plan.start_s[k]),
                                    float(plan.start_s[k] + plan.length_s[k]),
                                    float(m.max_2d_m[k])) for k, oid in enumerate(plan.ids)]
        written = plots.write_run_plots(
            args.out, sol, t0_gps_s=drive.t_imu0_gps_s, ref_llh=drive.ref_llh, outages=outages,
            ref_name="GNSS track (--gnss)", title=f"jaxnav lc: {Path(args.out).name} "
            f"({'combined' if smooth else 'forward'} solution)")
        print("wrote " + ", ".join(str(p) for p in written.values()))

    if args.sweep:
        t0 = time.perf_counter()
        res = run_drive_sweep(cfg, drive, args.sweep, _fingerprint(args, cfg),
                              overwrite=args.overwrite, progress=not args.quiet)
        print(f"sweep: {res.stats['scenarios']} outages in {time.perf_counter() - t0:.1f} s "
              f"(full runs {res.stats['full_run_s']:.1f} s, windows {res.stats['eval_s']:.1f} s, "
              f"compilation {res.stats['compile_full_s'] + res.stats['compile_eval_s']:.1f} s); "
              f"{res.path}")
        print("max 2D error per outage duration (all grid starts):")
        print(duration_table(res.dataset))
    return 0


if __name__ == "__main__":
    sys.exit(main())
