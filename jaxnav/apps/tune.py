"""``jaxnav tune``: noise parameters of a car configuration fitted to a recorded drive.

    jaxnav tune --config CAR.toml --imu IMU.csv [--imu-tag TAG] --gnss GNSS.pos
                --params KEY[,KEY...] --out TUNED.toml [--duration S] [--starts 1,0.5,2]
                [--max-steps N] [--outage-grid START:STEP:LENGTH] [--overwrite]

Fits the chosen ``[section] key`` values of a ``jaxnav lc`` configuration by maximum likelihood
of the loose filter's innovations over the drive with every GNSS fix used
(``jaxnav.filter.tune``: L-BFGS in log space through the whole scan, several starts, the
uncertainty from the Hessian, parameters the data cannot identify named as such). Epochs before
the in-motion alignment are left out of the likelihood (their heading is unknown: the
linearisation, not the noise, dominates their innovations).

``--outage-grid`` withholds the GNSS of outages START, START + STEP, ... (``jaxnav lc``'s grid)
inside the fitting span: the innovations of the first fixes after each outage are then the
filter's prediction errors over the outage, with their predicted covariance, and the fit also
asks the process noise to explain drift over that horizon, not only over one epoch (chosen for
outage studies, whose sigmas are read during outages).

Writes TUNED.toml: the input configuration, every comment kept, with the fitted values in place
and a comment on each naming its start value and 1-sigma factor; ``jaxnav lc --config
TUNED.toml`` runs it as it is. Vector keys (the vibration densities, one value per body axis)
are fitted per component.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxnav
from jaxnav.apps import existing_file, run_command
from jaxnav.apps.car_config import CarConfig, CarConfigError, load_config
from jaxnav.apps.lc_drive import Drive, load_drive
from jaxnav.apps.lc_filter import (
    build_filter,
    epoch_inputs,
    grid_schedule,
    initial_state,
    parse_grid,
    plan_outages,
)
from jaxnav.filter import loose
from jaxnav.filter import tune as tn

PROG = "jaxnav tune"

#: The keys ``jaxnav tune`` can fit: every positive noise figure of the loose filter's model
#: (the rest of the configuration is geometry, switches and detector settings).
TUNABLE = (
    "imu_errors.gyro_noise_deg_s_sqrt_hz", "imu_errors.accel_noise_ug_sqrt_hz",
    "imu_errors.gyro_vibration_deg_s_sqrt_hz", "imu_errors.accel_vibration_ug_sqrt_hz",
    "imu_errors.gyro_bias_turn_on_deg_s", "imu_errors.gyro_bias_gm_sigma_deg_h",
    "imu_errors.gyro_bias_gm_tau_s", "imu_errors.accel_bias_turn_on_mg",
    "imu_errors.accel_bias_gm_sigma_mg", "imu_errors.accel_bias_gm_tau_s",
    "imu_errors.gyro_scale_ppm", "imu_errors.accel_scale_ppm",
    "gnss.pos_sigma_floor_m", "gnss.vel_sigma_floor_m_s",
    "constraints.nhc_sigma_m_s", "constraints.zupt_sigma_m_s",
)  # fmt: skip


def _field(key: str) -> str:
    return key.replace(".", "_", 1)


def parse_params(text: str, cfg: CarConfig) -> tuple[str, ...]:
    """The ``--params`` list, checked: known tunable keys, each once, each > 0 in ``cfg``."""
    keys = tuple(k.strip() for k in text.split(",") if k.strip())
    if not keys:
        raise ValueError("--params: give at least one key, e.g. gnss.pos_sigma_floor_m")
    for k in keys:
        if k not in TUNABLE:
            raise ValueError(f"--params: {k!r} cannot be tuned; allowed: {', '.join(TUNABLE)}")
        if np.any(np.asarray(getattr(cfg, _field(k))) <= 0):
            raise ValueError(f"--params: {k} is {getattr(cfg, _field(k))} in the configuration; "
                             "a fit in log space needs a positive start value")
    if len(set(keys)) != len(keys):
        raise ValueError(f"--params: a key is given twice in {text!r}")
    return keys


def _layout(keys, cfg: CarConfig):
    """Flat parameter names and the (key, component or None) of each."""
    names, slots = [], []
    for k in keys:
        v = getattr(cfg, _field(k))
        if isinstance(v, tuple):
            for i in range(len(v)):
                names.append(f"{k}[{i}]")
                slots.append((k, i))
        else:
            names.append(k)
            slots.append((k, None))
    return tuple(names), tuple(slots)


def _values(cfg: CarConfig, slots) -> np.ndarray:
    return np.array([getattr(cfg, _field(k)) if i is None else getattr(cfg, _field(k))[i]
                     for k, i in slots], np.float64)


def _with_values(cfg: CarConfig, slots, theta):
    """``cfg`` with the parameters ``theta`` (JAX values: the configuration is traced)."""
    changes: dict = {}
    for j, (k, i) in enumerate(slots):
        f = _field(k)
        if i is None:
            changes[f] = theta[j]
        else:
            cur = list(changes.get(f, getattr(cfg, f)))
            cur[i] = theta[j]
            changes[f] = tuple(cur)
    return dataclasses.replace(cfg, **changes)


def drive_nll(cfg0: CarConfig, drive: Drive, slots, withheld=None):
    """NLL(theta) of the loose filter on the drive, aligned epochs only; ``withheld`` [E] bool:
    epochs whose fix is withheld (outages), else every fix is used."""
    base = epoch_inputs(cfg0, drive, withheld)
    nav0, sig, moving = initial_state(cfg0, build_filter(cfg0, drive), drive)
    eye = jnp.eye(3)

    def nll(theta):
        cfg = _with_values(cfg0, slots, theta)
        lf = build_filter(cfg, drive)
        # the initial covariance's sensor blocks depend on theta (turn-on biases, scales)
        carry = loose.initial_carry(lf, nav0, sig)._replace(aligned=jnp.asarray(moving))
        # the fixes' covariances hold the configuration's floors (lc_drive); swap in the traced
        fix = base.gnss
        fix = fix._replace(
            cov_pos_enu=fix.cov_pos_enu + (cfg.gnss_pos_sigma_floor_m**2
                                           - cfg0.gnss_pos_sigma_floor_m**2) * eye,
            cov_vel_enu=fix.cov_vel_enu + (cfg.gnss_vel_sigma_floor_m_s**2
                                           - cfg0.gnss_vel_sigma_floor_m_s**2) * eye,
        )
        _, out = loose.run(lf, carry, base._replace(gnss=fix))
        on = out.aligned
        return tn.innovation_nll(jnp.where(on, out.nis, 0.0), jnp.where(on, out.logdet, 0.0),
                                 jnp.where(on, out.dof, 0))

    return nll


def _format(v: float) -> str:
    return f"{v:.6g}"


def _toml_value(v) -> str:
    """A fitted value as TOML: a number, or a list for a vector key."""
    if isinstance(v, tuple):
        return "[" + ", ".join(_format(float(x)) for x in v) + "]"
    return _format(float(v))


def tuned_toml(text: str, cfg: CarConfig, res: tn.FitResult, slots, source: str) -> str:
    """The configuration ``text`` with the fitted values in place (comments kept)."""
    fitted = _with_values(cfg, slots, res.value.tolist())
    by_key: dict[str, list[int]] = {}
    for j, (k, _) in enumerate(slots):
        by_key.setdefault(k, []).append(j)
    lines = text.splitlines()
    section, done = None, set()
    for n, line in enumerate(lines):
        m = re.match(r"\s*\[([A-Za-z_]+)\]", line)
        if m:
            section = m.group(1)
            continue
        m = re.match(r"(\s*)([A-Za-z_]+)(\s*=\s*)", line)
        key = f"{section}.{m.group(2)}" if m else None
        if key in by_key:
            val = _toml_value(getattr(fitted, _field(key)))
            starts = ", ".join(_format(float(res.start[j])) for j in by_key[key])
            facs = ", ".join(f"{res.factor()[j]:.2f}" for j in by_key[key])
            lines[n] = (f"{m.group(1)}{m.group(2)}{m.group(3)}{val}  # jaxnav tune: was "
                        f"{starts}; 1-sigma x/ {facs}")
            done.add(key)
    missing = [k for k in by_key if k not in done]
    for key in missing:  # a key the file left at its default: add it under its section
        sec, name = key.split(".")
        val = _toml_value(getattr(fitted, _field(key)))
        idx = next((i for i, ln in enumerate(lines) if re.match(rf"\s*\[{sec}\]", ln)), None)
        entry = f"{name} = {val}  # jaxnav tune (was the default)"
        if idx is None:
            lines += ["", f"[{sec}]", entry]
        else:
            lines.insert(idx + 1, entry)
    head = [f"# Tuned by jaxnav {jaxnav.__version__} tune from {source}: maximum likelihood of "
            f"the innovations (NLL {res.nll_start:.1f} -> {res.nll:.1f}).",
            "# Lines marked 'jaxnav tune' hold fitted values; the other comments are the input's "
            "and describe its own values.",
            "# Not identified by the data (left as fitted, weakly determined): "
            + (", ".join(n for n, ok in zip(res.names, res.identified, strict=True) if not ok)
               or "none")]
    return "\n".join(head + lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True, type=existing_file,
                   help="car configuration TOML (jaxnav lc)")
    p.add_argument("--imu", required=True, type=existing_file, help="IMU CSV log")
    p.add_argument("--imu-tag", type=existing_file,
                   help="RTKLIB time-tag file of the IMU log (default IMU.tag)")
    p.add_argument("--gnss", required=True, type=existing_file, help="RTKLIB .pos track (aiding)")
    p.add_argument("--params", required=True,
                   help=f"comma-separated [section].key to fit, of: {', '.join(TUNABLE)}")
    p.add_argument("--out", required=True, help="tuned configuration TOML to write")
    p.add_argument("--duration", type=float,
                   help="fit on the first DURATION s of the log only (default: all of it)")
    p.add_argument("--starts", default="1,0.5,2",
                   help="comma-separated start factors, each multiplying every parameter's "
                        "configured value: one fit per factor (default 1,0.5,2)")
    p.add_argument("--max-steps", type=int, default=40,
                   help="L-BFGS iterations per start (default 40)")
    p.add_argument("--outage-grid", type=parse_grid, metavar="START:STEP:LENGTH",
                   help="withhold the GNSS at START, START+STEP, ... [s] for LENGTH s in the "
                        "fit (default: none withheld; module docstring)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    return p


def _starts(text: str) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in text.split(","))
    except ValueError:
        out = ()
    if not out or not all(x > 0 and math.isfinite(x) for x in out):
        raise ValueError(f"--starts {text!r}: expected positive factors like 1,0.5,2")
    return out


def _main(args) -> int:
    t0 = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise FileExistsError(f"--out {out} exists; pass --overwrite to replace it")
    if args.max_steps < 1:
        raise ValueError(f"--max-steps {args.max_steps}: expected >= 1")
    starts = _starts(args.starts)
    cfg = load_config(args.config)
    keys = parse_params(args.params, cfg)
    drive = load_drive(args.imu, args.imu_tag, args.gnss, cfg, duration_s=args.duration)
    names, slots = _layout(keys, cfg)
    withheld = None
    if args.outage_grid is not None:
        plan = plan_outages(drive, grid_schedule(drive, *args.outage_grid))
        withheld = plan.withheld
    print(f"{PROG}: {drive.n_epochs} epochs of {drive.epoch_dt_s:g} s"
          + (f" ({len(plan.ids)} outages withheld)" if withheld is not None else "")
          + f", fitting {len(names)} parameters from {len(starts)} starts", flush=True)
    res = tn.fit(drive_nll(cfg, drive, slots, withheld), _values(cfg, slots), names,
                 start_factors=starts, max_steps=args.max_steps)
    print(res.table())
    print(f"NLL {res.nll_start:.1f} at the start, {res.nll:.1f} fitted ({res.steps} steps, "
          f"{'converged' if res.converged else 'NOT converged'}); per start: "
          + ", ".join(f"x{f:g}: {v:.1f}" for f, v in res.starts))
    text = tuned_toml(Path(args.config).read_text(), cfg, res, slots, Path(args.config).name)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    try:
        load_config(out)  # what jaxnav lc will read
    except CarConfigError as exc:  # pragma: no cover - a bug in tuned_toml, not user input
        raise RuntimeError(f"the tuned configuration does not load: {exc}") from exc
    print(f"wrote {out} ({time.perf_counter() - t0:.0f} s)")
    return 0


def main(argv=None) -> int:
    """Entry point of ``jaxnav tune``; returns a process exit code."""
    return run_command(PROG, build_parser(), _main, argv)


if __name__ == "__main__":
    sys.exit(main())
