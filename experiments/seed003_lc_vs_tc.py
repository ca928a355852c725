"""Seed 003 (issue 7): loosely vs tightly coupled PPP with a Crista-class MEMS IMU; attitude
accuracy with and without non-holonomic constraints.

``python experiments/seed003_lc_vs_tc.py [--quick] [--out DIR]``

What is simulated (SEED_SPEC 3.5, 5 "S003"): a residential (``suburban``) drive of the scenario
factory, GPS dual-frequency PPP with float ambiguities (``float_ppp``: IF code + carrier +
Doppler, ZWD, clock), the Crista-class MEMS IMU (``sim.sensors.crista``: S003's 5400 deg/h
turn-on and > 1000 deg/h in-run gyro bias) at 100 Hz, full availability (S003: "more than four
satellites were available throughout"). Five solutions of the same noise realisations:

- PPP only (S003 Table 1): the cascade's GNSS-only constant-velocity PPP filter, at the antenna;
- TC (Table 2): ``ins15`` (tightly coupled 15-state INS, ``filter/tight.py``), and ``ins15_nhc``
  with the tight filter's optional NHC update (sigma 1 m/s, S003);
- LC (Table 3): ``lc_ins15`` (``filter/cascade.py``: that PPP filter's position / velocity and
  covariance feed a 15-state LC INS), and ``lc_ins15_nhc`` with NHC (sigma 1 m/s).

S003 processed its 20-min PPP backward because it was too short to converge; a filter here runs
forward only, so the drive is longer (30 min) and the statistics are over its last 20 minutes
(after a 10-min convergence, the S002 ch5 exclusion). Statistics: RMS over epochs and
Monte-Carlo realisations (pooled) of the error against the simulator's truth; latitude /
longitude errors in metres (north / east).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from common import comparison_table, fmt, markdown_table, parse_args, write_report

import jaxnav  # noqa: F401  (float64)
from jaxnav import attitude, geodesy
from jaxnav.study import metrics
from jaxnav.study.factory import SimFactory

NAME = "seed003_lc_vs_tc"
MODE = "float_ppp"
SOLUTIONS = {  # label -> factory system
    "TC": "ins15",
    "TC+NHC": "ins15_nhc",
    "LC": "lc_ins15",
    "LC+NHC": "lc_ins15_nhc",
}
COMPONENTS = ("lat_m", "lon_m", "h_m", "ve_m_s", "vn_m_s", "vu_m_s", "pitch_deg", "roll_deg",
              "az_deg")
# S003 Tables 1-3 (SEED_SPEC 3.5): RMS lat, lon, h [m], ve, vn, vu [m/s], pitch, roll, az [deg].
SEED = {
    "PPP": (0.10, 0.32, 0.47, 0.019, 0.025, 0.076, None, None, None),
    "TC": (0.08, 0.26, 0.38, 0.018, 0.023, 0.072, 0.44, 0.37, 1.41),
    "TC+NHC": (None, None, None, None, None, None, 0.42, 0.35, 0.75),
    "LC": (0.10, 0.30, 0.40, 0.019, 0.025, 0.073, 0.46, 0.43, 1.42),
    "LC+NHC": (None, None, None, None, None, None, 0.43, 0.41, 0.80),
}


def settings(quick: bool) -> dict:
    if quick:  # df_code: the cheapest filters to compile (the quick run only exercises the code)
        return {"duration_s": 200.0, "exclude_s": 90.0, "seeds": [0, 1], "mode": "df_code"}
    return {"duration_s": 1800.0, "exclude_s": 600.0, "seeds": list(range(6)), "mode": MODE}


def _errors(llh, vel, euler, t_llh, t_vel, t_euler):
    """[T, 9] errors: north, east, up [m]; vE, vN, vU [m/s]; pitch, roll, azimuth [deg]."""
    enu = metrics.enu_errors(llh, t_llh)
    dv = vel - t_vel
    d_eul = jnp.rad2deg(attitude.wrap_angle(euler - t_euler))
    return jnp.concatenate(
        [enu[:, [1, 0, 2]], dv, d_eul[:, [1, 0, 2]]], axis=-1
    )


def run_solution(factory: SimFactory, mode: str, system: str, seeds, truth):
    """Per-epoch errors [R, T, 9] of one system over the realisations (one vmapped run); for
    the LC systems also the errors of their PPP part (against the antenna truth)."""
    probs = [factory.build(None, mode, system, s) for s in seeds]
    tf = probs[0].tf
    ops = factory.ops_for(mode, system)
    carry0 = jax.tree.map(lambda *a: jnp.stack(a), *[p.carry0 for p in probs])
    inputs = jax.tree.map(lambda *a: jnp.stack(a), *[p.inputs for p in probs])
    del probs
    lc = system.startswith("lc_")

    @jax.jit
    def errs(tf, carry0, inputs):
        def one(c, i):
            _, out = ops.run(tf, c, i)
            o = out.lc if lc else out
            e = _errors(o.llh, o.vel_enu, o.euler, truth["llh"], truth["vel"], truth["euler"])
            if not lc:
                return e, jnp.zeros_like(e), jnp.ones(e.shape[0], bool)
            p = out.ppp
            e_ppp = _errors(p.llh, p.vel_enu, jnp.zeros_like(p.llh), truth["ant_llh"],
                            truth["ant_vel"], jnp.zeros_like(p.llh))
            return e, e_ppp, out.fix.pos_valid

        return jax.vmap(one)(carry0, inputs)

    t0 = time.perf_counter()
    e, e_ppp, valid = jax.block_until_ready(errs(tf, carry0, inputs))
    return np.asarray(e), np.asarray(e_ppp), np.asarray(valid), time.perf_counter() - t0


def rms(e, first: int):
    """Pooled RMS over realisations and epochs >= first, and the spread (std) of the
    per-realisation RMS; per component."""
    x = e[:, first:, :]
    per_real = np.sqrt(np.mean(x**2, axis=1))
    return np.sqrt(np.mean(x**2, axis=(0, 1))), per_real.std(axis=0, ddof=1) if len(x) > 1 else (
        np.zeros(x.shape[-1])
    )


def make_truth(factory: SimFactory):
    g = factory.geo
    t = g.truth_ep
    ant_llh = jax.vmap(geodesy.ecef_to_llh)(g.ant_pos_ecef[1:])
    ant_vel = jax.vmap(lambda v, llh: geodesy.C_l_e(llh[0], llh[1]).T @ v)(
        g.ant_vel_ecef[1:], ant_llh
    )
    return {"llh": t.llh[1:], "vel": t.vel_enu[1:], "euler": t.euler[1:], "ant_llh": ant_llh,
            "ant_vel": ant_vel}


def plot_attitude(out: Path, time_s, errs: dict, first: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    names = ("pitch", "roll", "azimuth")
    colors = {"TC": "C0", "TC+NHC": "C1", "LC": "C2", "LC+NHC": "C3"}
    for k, ax in enumerate(axes):
        for label, e in errs.items():
            ax.plot(time_s, e[0, :, 6 + k], lw=0.8, color=colors[label], label=label)
        ax.axvline(time_s[first], color="k", lw=0.6, ls=":")
        ax.set_ylabel(f"{names[k]} error [deg]")
        ax.grid(alpha=0.3)
    axes[0].legend(ncol=4, fontsize=8)
    axes[-1].set_xlabel("time [s] (dotted: start of the statistics)")
    fig.suptitle("Attitude errors, Crista-class MEMS, float PPP (realisation 0)")
    fig.tight_layout()
    path = out / "attitude_errors.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_bars(out: Path, ours: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(SOLUTIONS)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.6))
    for k, (ax, name) in enumerate(zip(axes, ("pitch", "roll", "azimuth"), strict=True)):
        x = np.arange(len(labels))
        seed = [SEED[lab][6 + k] if SEED[lab][6 + k] is not None else np.nan for lab in labels]
        ax.bar(x - 0.2, seed, 0.4, label="S003")
        ax.bar(x + 0.2, [ours[lab][0][6 + k] for lab in labels], 0.4, label="jaxnav",
               yerr=[ours[lab][1][6 + k] for lab in labels], capsize=3)
        ax.set_xticks(x, labels, fontsize=8)
        ax.set_title(f"RMS {name} error [deg]")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    path = out / "attitude_rms.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    st = settings(args.quick)
    t_start = time.perf_counter()
    scenario = {"duration_s": st["duration_s"], "drive_style": "suburban", "ins_grade": "crista",
                "drive_seed": 3}
    factory = SimFactory(scenario)
    mode = st["mode"]
    truth = make_truth(factory)
    dt = factory.cfg.epoch_interval_s
    first = int(round(st["exclude_s"] / dt))
    errs, ppp_err, timings, valid_frac = {}, None, {}, {}
    for label, system in SOLUTIONS.items():
        e, e_ppp, valid, secs = run_solution(factory, mode, system, st["seeds"], truth)
        errs[label] = e
        timings[label] = secs
        if system.startswith("lc_"):
            valid_frac[label] = float(valid.mean())
            if ppp_err is None:
                ppp_err = e_ppp
        print(f"{label:7s} ({system}): {secs:.1f} s", file=sys.stderr)
    ours = {lab: rms(e, first) for lab, e in errs.items()}
    ours["PPP"] = rms(ppp_err, first)

    # ---- tables ---------------------------------------------------------------------------
    rows = []
    for lab in ("PPP", *SOLUTIONS):
        r, s = ours[lab]
        n = 6 if lab == "PPP" else 9
        rows.append([lab] + [f"{r[k]:.3f} ± {s[k]:.3f}" for k in range(n)] + ["-"] * (9 - n))
    ours_table = markdown_table(["solution", *COMPONENTS], rows)
    seed_rows = [[lab] + [fmt(v, 3) if v is not None else "-" for v in SEED[lab]]
                 for lab in ("PPP", *SOLUTIONS)]
    seed_table = markdown_table(["solution", *COMPONENTS], seed_rows)
    cmp_rows = []
    for lab in ("PPP", *SOLUTIONS):
        for k, comp in enumerate(COMPONENTS):
            sv = SEED[lab][k]
            if sv is None or (lab == "PPP" and k >= 6):
                continue
            cmp_rows.append((f"{lab} {comp}", sv, float(ours[lab][0][k])))
    cmp_table = comparison_table(cmp_rows)

    def att(lab, k):
        return float(ours[lab][0][6 + k])

    nhc_gain = {
        c: {m: att(m, k) / att(f"{m}+NHC", k) for m in ("TC", "LC")}
        for k, c in enumerate(("pitch", "roll", "azimuth"))
    }
    seed_gain = {
        c: {m: SEED[m][6 + k] / SEED[f"{m}+NHC"][6 + k] for m in ("TC", "LC")}
        for k, c in enumerate(("pitch", "roll", "azimuth"))
    }
    gain_rows = [
        [f"{c} (TC)", seed_gain[c]["TC"], nhc_gain[c]["TC"]] for c in nhc_gain
    ] + [[f"{c} (LC)", seed_gain[c]["LC"], nhc_gain[c]["LC"]] for c in nhc_gain]
    gain_table = markdown_table(["RMS without / with NHC", "S003", "jaxnav"], gain_rows)
    lc_tc_rows = [
        [c, SEED["LC"][k] / SEED["TC"][k], float(ours["LC"][0][k] / ours["TC"][0][k])]
        for k, c in enumerate(COMPONENTS)
    ]
    lc_tc_table = markdown_table(["RMS LC / TC", "S003", "jaxnav"], lc_tc_rows)

    figs = [plot_attitude(args.out, np.arange(errs["TC"].shape[1]) * dt + dt, errs, first),
            plot_bars(args.out, ours)]
    summary = {
        "settings": st, "scenario": scenario, "mode": mode,
        "rms": {lab: dict(zip(COMPONENTS, map(float, ours[lab][0]), strict=False))
                for lab in ours},
        "spread": {lab: dict(zip(COMPONENTS, map(float, ours[lab][1]), strict=False))
                   for lab in ours},
        "nhc_gain": nhc_gain, "lc_fix_valid_fraction": valid_frac, "run_s": timings,
        "wall_s": time.perf_counter() - t_start,
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))

    n_real = len(st["seeds"])
    sections = [
        ("Set-up", f"""
Simulated {st['duration_s'] / 60:.0f}-min `suburban` drive (drive seed 3; residential-area
speeds, starting with a 60-s standstill used for the gyro-bias calibration of every INS
solution, after which the gyro-bias prior is the in-run GM sigma (+) ARW / sqrt(30 s),
`SimFactory.start`; see "Discussion"), GPS only, `{mode}` (IF code + carrier + Doppler at
1 Hz, S003 eq 1/6), IMU preset `crista` at 100 Hz, lever arm 1.5 m up. {n_real} noise
realisations (IMU errors, GNSS noise, multipath, ionosphere/troposphere residuals) shared by
all solutions. Statistics: RMS over the last
{(st['duration_s'] - st['exclude_s']) / 60:.0f} min (the first
{st['exclude_s'] / 60:.0f} min are the PPP convergence; S003 instead processed its PPP
backward), pooled over realisations; "±" is the standard deviation of the per-realisation
RMS.

Solutions: **PPP** = the GNSS-only constant-velocity PPP filter inside the LC cascade (scored at
the antenna); **TC** = `ins15` (tight 15-state INS), **TC+NHC** = `ins15_nhc` (the tight
filter's optional sequential NHC update, 1 m/s); **LC** = `lc_ins15` (`filter/cascade.py`: the
PPP filter's position/velocity and their covariance blocks feed a 15-state LC INS; fix valid when
the PPP update used >= 4 satellites: {', '.join(f'{k} {100 * v:.1f} %' for k, v in
valid_frac.items())} of epochs), **LC+NHC** = `lc_ins15_nhc` (NHC 1 m/s every epoch). S003 used
a 27-state INS (turn-on biases + drifts + scale factors); here 15 states (GM biases; the
turn-on bias is removed by the standstill calibration and the remainder lumped into the GM
state).
"""),
        ("Seed figures (S003 Tables 1-3)", seed_table),
        ("Ours (RMS ± spread over realisations)", ours_table),
        ("Seed vs ours", cmp_table),
        ("LC / TC ratio (S003: TC slightly better)", lc_tc_table),
        ("NHC gain (RMS without / with NHC)", gain_table),
        ("Figures", "\n".join(f"![{p.stem}]({p.name})" for p in figs)),
        ("Discussion", discussion(ours, nhc_gain, valid_frac)),
    ]
    path = write_report(args.out, "Seed 003: LC vs TC PPP/MEMS-INS and the NHC", sections,
                        args.quick)
    print(f"wrote {path} ({time.perf_counter() - t_start:.0f} s)", file=sys.stderr)
    return 0


def discussion(ours, gain, valid_frac) -> str:
    """Text written from the measured numbers (so it stays true when they change)."""

    def a(lab, k):
        return float(ours[lab][0][6 + k])

    lines = []
    tc_az, lc_az = a("TC", 2), a("LC", 2)
    lines.append(
        f"- **LC vs TC.** Azimuth RMS: TC {tc_az:.2f} deg, LC {lc_az:.2f} deg (S003: 1.41 / "
        f"1.42); pitch {a('TC', 0):.2f} / {a('LC', 0):.2f}, roll {a('TC', 1):.2f} / "
        f"{a('LC', 1):.2f} deg (S003: 0.44 / 0.46, 0.37 / 0.43). "
        + (f"TC and LC azimuths agree within {100 * abs(tc_az / lc_az - 1):.0f} % (S003: 1 %). "
           if abs(tc_az / lc_az - 1) < 0.1 else
           f"TC / LC azimuth ratio {tc_az / lc_az:.2f} (S003: 0.99). ")
        + f"TC is better in velocity (LC / TC east {ours['LC'][0][3] / ours['TC'][0][3]:.2f}, "
        f"north {ours['LC'][0][4] / ours['TC'][0][4]:.2f}; S003 1.06 / 1.09): the LC filter's "
        f"velocity fixes come from the constant-velocity PPP filter, whose velocity RMS is "
        f"{ours['PPP'][0][3]:.3f} / {ours['PPP'][0][4]:.3f} m/s (S003's PPP: 0.019 / 0.025)."
    )
    lines.append(
        f"- **Where we contradict S003.** Without NHC our azimuth RMS is "
        f"{tc_az / 1.41:.1f} x the seed's while pitch and roll are "
        f"{a('TC', 0) / 0.44:.2f} / {a('TC', 1) / 0.37:.2f} x (TC): the simulated Crista's "
        "in-run gyro drift (GM 1000 deg/h, tau 300 s) turns the heading at up to ~0.3 deg/s on "
        "the straights, where nothing observes it (see attitude_errors.png: the azimuth error "
        "ramps between turns and collapses in them), whereas the levelling of pitch and roll by "
        "the accelerometers and the GNSS velocity is better than on a real car (no vibration, "
        "no suspension pitch/roll, exact lever arm). S003's 1.4 deg azimuth with '> 1000 deg/h' "
        "drift implies either a slower drift or a route with more turns than our drive. With "
        "the NHC both reach ~"
        f"{a('TC+NHC', 2):.1f} deg ({a('TC+NHC', 2) / 0.75:.2f} x S003's 0.75)."
    )
    lines.append(
        f"- **NHC.** Azimuth improves by a factor {gain['azimuth']['TC']:.2f} (TC) and "
        f"{gain['azimuth']['LC']:.2f} (LC) (S003: 1.88 and 1.78); pitch "
        f"{gain['pitch']['TC']:.2f} / {gain['pitch']['LC']:.2f}, roll {gain['roll']['TC']:.2f} /"
        f" {gain['roll']['LC']:.2f} (S003: 1.05 / 1.07, 1.06 / 1.05). The simulated vehicle obeys "
        "the constraint exactly (no side slip, no IMU-to-vehicle misalignment, no suspension "
        "motion), while the 1 m/s noise of S003 was sized for a 2-3 deg misalignment: the "
        "constraint is therefore worth more here than on a real car, for the azimuth above all."
    )
    lines.append(
        "- **What drives the differences** (SEED_SPEC 'not specified by any seed'): (1) the "
        "gyro GM sigma / correlation time of the Crista (chosen: 1000 deg/h, tau 300 s; S003 "
        "gives only '> 1000 deg/h'), which sets how fast the azimuth, unobservable on "
        "straights, drifts between turns; (2) the process noise Q of velocity and attitude "
        "(here the simulator's own ARW / VRW, a filter model that matches the truth, which a "
        "real data set never gives); (3) the initial covariances and the truth initialisation "
        "plus the 60-s standstill gyro calibration (S003's turn-on bias of 5400 deg/h is "
        "estimated in the filter instead); (4) the GNSS noise (code 0.2 m and phase 2 mm white "
        "at zenith plus 0.2 m / 2 mm of 30-s multipath) and the product residuals, which set "
        "the PPP accuracy and therefore the position / velocity rows, and for LC that each PPP "
        "fix is weighted as independent although its error is correlated for minutes (the "
        "factory default; docs/models.md); (5) the drive itself "
        "(S003's route and dynamics are unknown: "
        "the azimuth observability comes from horizontal accelerations)."
    )
    lines.append(
        "- **Start-up (a finding that changed `SimFactory`, not a seed figure).** With the "
        "gyro biases calibrated on the standstill but the prior variance left at the "
        "uncalibrated turn-on + in-run sigma (1.5 deg/s for the Crista) both filters "
        "'learned' a wrong vertical gyro bias while the heading is unobservable at rest (-4.3 "
        "deg/s against the calibrated -1.9 deg/s in one realisation), and the TC filter then "
        "lost lock in one of two quick-run realisations while the LC filter, which has no "
        "gates, recovered to 12 deg azimuth RMS. `SimFactory.start` now starts every INS with "
        "the prior the calibration earns (`NavSigmas.gyro_calibration_s`)."
    )
    lines.append(
        f"- LC fixes were valid at {min(valid_frac.values()) * 100:.1f} % of the epochs or more "
        "(full availability, as in S003)."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
