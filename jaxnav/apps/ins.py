"""``jaxnav ins``: GNSS/INS on a recorded IMU log, loosely or tightly coupled, with outages.

    jaxnav ins --config RUN.toml --out OUT.pos [--outages SCHEDULE] [--smooth] [--overwrite]

The configuration (``configs/walk_gnss_imu.toml`` documents every key) is the car
configuration of ``jaxnav lc`` (``[imu]``, ``[imu_errors]``, ``[lever_arms]``, ``[gnss]``,
``[constraints]``, ``[alignment]``, ``[filter]``, ``[sweep]``) plus:

- ``[data]``: ``imu``, ``imu_tag`` (default IMU + ".tag"), ``ubx`` (raw observations, tight),
  ``gnss_pos`` (an RTKLIB track to couple, loose), ``reference`` (an RTKLIB track to measure
  the errors against); paths relative to the configuration file;
- ``[coupling] kind``: ``"loose"`` runs ``jaxnav lc``'s filter on ``data.gnss_pos`` (the same
  code path and output); ``"tight"`` runs ``apps/tc_recorded.py`` on ``data.ubx``;
- ``[tight]``: the PPP mode, constellations, mask, start sigmas, reference conventions and
  whether to run the loose cascade on the same observations for comparison;
- ``[outages]``: ``starts_s`` (after the first IMU sample), ``length_s`` and
  ``satellites_kept`` (every combination is one scenario), unless ``--outages`` gives a
  schedule file ``id,start_s,length_s[,satellites_kept]``.

The tight run writes the solution without outages to OUT.pos (at the antenna) and, beside it,
OUT.outages.csv: per outage and coupling the maximum and final 2D error against the reference.
``--smooth``: the forward filter followed by the RTS smoother (``jaxnav.filter.smoother``); the
.pos holds the smoothed solution and the outage table the smoothed errors beside the forward
ones (``tight_fwd``; for the loose kind, ``jaxnav lc --smooth``). The loose cascade run for
comparison stays a forward filter. Existing outputs are replaced only with ``--overwrite``.
Every input error exits with code 2 and one line naming the file, section and key.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
import sys
import time
import tomllib
from pathlib import Path

import jax
import numpy as np

import jaxnav
from jaxnav.apps import (
    Stages,
    add_plot_option,
    car_config,
    existing_file,
    plots,
    pos_solution_label,
    run_command,
)
from jaxnav.apps import tc_recorded as tc
from jaxnav.apps.lc_filter import antenna_track
from jaxnav.core import schema
from jaxnav.gnss import modes as ppp_modes
from jaxnav.io import pos as pos_io
from jaxnav.study import outages as ot

PROG = "jaxnav ins"
_PATH = schema.text()
#: The sections ``jaxnav ins`` adds to the car configuration.
SCHEMA = {
    "data": {"imu": _PATH, "imu_tag": _PATH, "ubx": _PATH, "gnss_pos": _PATH,
             "reference": _PATH},
    "coupling": {"kind": schema.choice(("loose", "tight"))},
    "tight": {
        # the u-blox signals are read as ionosphere-free pairs (tc_recorded.UBLOX_SIGNALS)
        "mode": schema.choice([m for m in ppp_modes.MODES
                               if not ppp_modes.get(m).single_frequency],
                              "dual-frequency PPP modes"),
        "constellations": schema.items(schema.choice(tc.LETTERS)),
        "elevation_mask_deg": schema.number(0),
        "doppler": schema.boolean(),
        "heading_sigma_deg": schema.number(0, strict=True),
        "start_sigma_m": schema.number(0, strict=True),
        "compare_loose": schema.boolean(),
        "reference_height": schema.choice(("ellipsoidal", "msl")),
        "reference_offset": schema.choice(("none", "spp_median")),
    },
    "outages": {"starts_s": schema.items(schema.number(0)),
                "length_s": schema.number(0, strict=True, unit="seconds"),
                "satellites_kept": schema.items(schema.whole(0))},
}


class InsConfig:
    """A validated ``jaxnav ins`` configuration: the car part, paths, coupling, options."""

    def __init__(self, path: Path, car: car_config.CarConfig, tables: dict):
        self.path, self.car = path, car
        base = path.parent
        data = tables.get("data", {})
        self.paths = {k: str((base / v).resolve()) for k, v in data.items()}
        self.kind = tables.get("coupling", {}).get("kind")
        self.tight = tc.TightOptions(**{
            k: tuple(v) if isinstance(v, list | tuple) else v
            for k, v in tables.get("tight", {}).items()})
        self.outages = tables.get("outages", {})


def _fail(path, key, msg):
    raise car_config.CarConfigError(f"{path}: {key}: {msg}")


def load(path: str | Path) -> InsConfig:
    """Read and validate the configuration (every file it names must exist)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise car_config.CarConfigError(f"{path}: cannot read the configuration: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise car_config.CarConfigError(f"{path}: not valid TOML: {exc}") from None
    ours = {k: data.pop(k) for k in list(data) if k in SCHEMA}
    unknown = [k for k in data if k not in car_config.SCHEMA]
    if unknown:
        raise car_config.CarConfigError(
            f"{path}: unknown section [{unknown[0]}]; allowed sections: "
            f"{', '.join([*car_config.SCHEMA, *SCHEMA])}")
    car = car_config.config_from_dict(data, str(path))
    tables = {}
    for section, rules in SCHEMA.items():
        try:
            tables[section] = schema.check_section(
                section, ours.get(section, {}), rules, error=car_config.CarConfigError,
                required=("kind",) if section == "coupling" else ())
        except car_config.CarConfigError as e:
            raise car_config.CarConfigError(f"{path}: {e}") from None
    cfg = InsConfig(path, car, tables)
    if cfg.outages and set(cfg.outages) != {"starts_s", "length_s", "satellites_kept"}:
        _fail(path, "[outages]", "expected all of starts_s, length_s and satellites_kept")
    need = ("imu", "ubx") if cfg.kind == "tight" else ("imu", "gnss_pos")
    for key in need:
        if key not in cfg.paths:
            _fail(path, f"data.{key}", f"missing (coupling.kind = {cfg.kind!r} needs it)")
    for key, p in cfg.paths.items():
        if not Path(p).is_file():
            _fail(path, f"data.{key}", f"no such file {p} (paths are relative to the "
                  "configuration file)")
    return cfg


def schedule(cfg: InsConfig, outages_file: str | None) -> ot.Schedule | None:
    """The outage scenarios: the schedule file, else the [outages] grid, else none."""
    if outages_file:
        return ot.read_schedule(outages_file)
    o = cfg.outages
    if not o:
        return None
    combos = list(itertools.product(o["starts_s"], o["satellites_kept"]))
    ids = tuple(f"t{start:g}k{kept}" for start, kept in combos)
    return ot.Schedule(ids, np.array([c[0] for c in combos]),
                       np.full(len(combos), o["length_s"]),
                       np.array([c[1] for c in combos], np.int64))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True, type=existing_file, help="run configuration TOML")
    p.add_argument("--out", required=True, help="output .pos (INS at the antenna)")
    p.add_argument("--outages", type=existing_file,
                   help="schedule id,start_s,length_s[,satellites_kept] "
                   "(start after the first IMU sample); default: the [outages] grid")
    p.add_argument("--smooth", action="store_true",
                   help="forward filter + RTS smoother (RTKPOST's combined solution)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--quiet", action="store_true",
                   help="print only errors and the summary (no progress lines)")
    add_plot_option(p)
    return p


def main(argv=None) -> int:
    """Entry point of ``jaxnav ins``; returns a process exit code."""
    return run_command(PROG, build_parser(), _main, argv)


def _outputs(args) -> tuple[Path, Path]:
    out = Path(args.out)
    table = out.with_suffix(".outages.csv")
    for p in (out, table):
        if p.exists() and not args.overwrite:
            raise FileExistsError(f"{p} exists; pass --overwrite to replace it")
    return out, table


def _main(args) -> int:
    cfg = load(args.config)
    sched = schedule(cfg, args.outages)  # before any data is read
    out_path, table_path = _outputs(args)
    if cfg.kind == "loose":
        return _loose(cfg, args, sched)
    return _tight(cfg, args, sched, out_path, table_path)


def _loose(cfg: InsConfig, args, sched) -> int:
    """``jaxnav lc``'s pipeline on ``data.gnss_pos`` (complete outages only)."""
    from jaxnav.apps import lc

    lc_args = argparse.Namespace(
        imu=cfg.paths["imu"], imu_tag=cfg.paths.get("imu_tag"), gnss=cfg.paths["gnss_pos"],
        config=str(cfg.path), outages=None, outage_grid=None, duration=None, out=args.out,
        sweep=None, overwrite=args.overwrite, quiet=args.quiet, no_plots=args.no_plots,
        solution="combined" if args.smooth else "forward")
    return lc.run(lc_args, cfg.car, sched)


def _tight(cfg: InsConfig, args, sched, out_path: Path, table_path: Path) -> int:
    t0 = time.perf_counter()
    opts = cfg.tight
    stage = Stages(args.quiet)
    with stage(f"decoding the UBX log {Path(cfg.paths['ubx']).name}, the IMU log and the "
               "broadcast ephemerides; preparing the observations"):
        rec = tc.load_recording(cfg.car, opts, cfg.paths, sched)
        plan = tc.plan_outages(rec, sched) if sched is not None else tc.plan_outages(
            rec, ot.Schedule((), np.zeros(0), np.zeros(0), np.zeros(0, np.int64)))
        keeps = tc.keep_masks(rec, plan)
    t_read = time.perf_counter()
    with stage("building the tight filter and its inputs"):
        tf, carry, inputs = tc.build_tight(cfg.car, opts, rec)
    with stage("compiling and running the tight filter"
               + (" and the smoother" if args.smooth else "")):
        if args.smooth:
            fwd, out = tc.run_tight_smoothed(tf, carry, inputs, keeps)
        else:
            out = tc.run_tight(tf, carry, inputs, keeps)
        jax.block_until_ready(out.llh)
    ant = np.asarray(antenna_track(tf.system.lever_b, out))
    runs = {"tight": (ant, out.n_sat)}
    if args.smooth:
        runs["tight_fwd"] = (np.asarray(antenna_track(tf.system.lever_b, fwd)), fwd.n_sat)
    if opts.compare_loose:
        with stage("compiling and running the loose filter (tight vs loose)"):
            cf, c_carry, c_inputs = tc.build_loose(cfg.car, opts, rec)
            lo = tc.run_loose(cf, c_carry, c_inputs, keeps)
            runs["loose"] = (np.asarray(antenna_track(cf.lc.system.lever_b, lo.lc)),
                             lo.fix.pos_valid)
    t_run = time.perf_counter()

    sol = tc.pos_solution(rec, ant[0], out.P_nav[0], out.n_sat[0],
                          np.zeros(rec.time_gps_s.size, bool))
    pos_io.write_pos(out_path, sol, comments=(
        f"jaxnav ins: tightly coupled {opts.mode} / {cfg.car.imu_errors_states} at the antenna; "
        f"config {cfg.path.name}; solution "
        f"{'combined (forward + RTS smoother)' if args.smooth else 'forward'}",
        f"first IMU sample {rec.t_imu0_gps_s:.3f} GPS s (origin of outage start times)"),
        program=f"jaxnav {jaxnav.__version__} ins",
        info=tuple(("inp file", str(cfg.paths[k])) for k in ("ubx", "imu", "imu_tag", "reference")
                   if cfg.paths.get(k)) + (
            ("pos mode", f"Tightly coupled PPP/INS ({opts.mode} / {cfg.car.imu_errors_states})"),
            ("freqs", "L1+L2"),
            ("solution", pos_solution_label(args.smooth)),
            ("elev mask", f"{opts.elevation_mask_deg:.1f} deg"),
            ("navi sys", ",".join(c.upper() if c == "gps" else c.capitalize()
                                  for c in opts.constellations))))

    t_rel = rec.time_gps_s - rec.t_imu0_gps_s
    print(f"{PROG}: tight {opts.mode} / {cfg.car.imu_errors_states}, "
          f"{rec.time_gps_s.size} epochs of {rec.epoch_dt_s:g} s from "
          f"{t_rel[0]:.2f} s after the first IMU sample; satellites {','.join(rec.prep.sv)}")
    sats = {k.split(":")[0] for k in rec.nav_report.ephemerides}
    print(f"  ubx: {rec.ubx_counts.get('RXM-RAWX', 0)} RAWX epochs, "
          f"{rec.ubx_counts['damaged']} damaged frames; ephemerides of "
          f"{sum(s[0] == 'G' for s in sats)} GPS, {sum(s[0] == 'E' for s in sats)} Galileo "
          f"satellites; slips LLI {rec.prep.slip_counts['lli']}, "
          f"GF {rec.prep.slip_counts['gf']}, MW {rec.prep.slip_counts['mw']}")
    rows = []
    if rec.ref_llh is not None:
        offset = (tc.reference_offset(rec) if opts.reference_offset == "spp_median"
                  else np.zeros(3))
        rows = _report(rec, opts, plan, runs, offset)
        _write_table(table_path, rows)
        print(f"  wrote {table_path}")
    print(f"  wrote {out_path}; read + prepare {t_read - t0:.1f} s, filters {t_run - t_read:.1f}"
          " s (incl. compilation)")
    if not args.no_plots:
        outages = [plots.Outage(str(r["id"]), float(r["start_s"]),
                                float(r["start_s"] + r["length_s"]),
                                float(r["tight_max_2d_m"])) for r in rows]
        ref = None if rec.ref_llh is None else plots.reference_moved(rec.ref_llh, offset)
        written = plots.write_run_plots(
            out_path, sol, t0_gps_s=rec.t_imu0_gps_s, ref_llh=ref, outages=outages,
            outages_in_solution=False, ref_name="reference track (data.reference)",
            title=f"jaxnav ins: tight {opts.mode} / {cfg.car.imu_errors_states}, "
                  f"{'combined' if args.smooth else 'forward'} solution")
        print("  wrote " + ", ".join(str(p) for p in written.values()))
    return 0


def _report(rec: tc.Recording, opts: tc.TightOptions, plan: tc.OutagePlan, runs: dict,
            offset: np.ndarray):
    """Print the error summary against the reference moved by ``offset`` (ENU [m]) and return
    the per-outage rows."""
    fixed = rec.ref_q == 1
    if opts.reference_offset == "spp_median":
        print(f"  reference offset removed (median SPP - reference over the run, E N U): "
              f"{offset[0]:+.2f} {offset[1]:+.2f} {offset[2]:+.2f} m")
    errs = {}
    for name, (ant, _) in runs.items():
        e2, _ = tc.horizontal_errors(rec, ant, offset)
        errs[name] = e2
        raw, _ = tc.horizontal_errors(rec, ant[:1])
        rms = math.sqrt(float(np.mean(e2[0][fixed] ** 2))) if fixed.any() else math.nan
        rms_raw = math.sqrt(float(np.mean(raw[0][fixed] ** 2))) if fixed.any() else math.nan
        print(f"  {name:5s} no outage: horizontal RMS {rms:.3f} m over the {int(fixed.sum())} "
              f"fixed reference epochs (max {float(e2[0][fixed].max()):.3f} m; against the "
              f"reference as given {rms_raw:.3f} m)")
    rows = []
    if len(plan.ids):
        print(f"  {'outage':>10} {'start_s':>8} {'len_s':>6} {'kept':>4} {'fixed':>5}  "
              + "  ".join(f"{n + ' max_2d':>12} {n + ' end_2d':>12}" for n in runs))
    for k, oid in enumerate(plan.ids):
        w = slice(int(plan.start_epoch[k]), int(plan.start_epoch[k] + plan.n_epochs[k]))
        row = {"id": oid, "start_s": plan.start_s[k], "length_s": plan.length_s[k],
               "satellites_kept": int(plan.kept[k]),
               # the share of the window where the reference is RTK-fixed (else float)
               "reference_fixed": float(np.mean(fixed[w]))}
        for name, e2 in errs.items():
            row[f"{name}_max_2d_m"] = float(e2[k + 1][w].max())
            row[f"{name}_end_2d_m"] = float(e2[k + 1][w.stop - 1])
        rows.append(row)
        print(f"  {oid:>10} {row['start_s']:8.2f} {row['length_s']:6.2f} "
              f"{row['satellites_kept']:4d} {row['reference_fixed']:5.2f}  " + "  ".join(
                  f"{row[n + '_max_2d_m']:12.3f} {row[n + '_end_2d_m']:12.3f}" for n in errs))
    return rows


def _write_table(path: Path, rows):
    with path.open("w", newline="") as f:
        if not rows:
            f.write("id,start_s,length_s,satellites_kept\n")
            return
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    sys.exit(main())
