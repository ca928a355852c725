"""``jaxnav ppp``: post-processed precise point positioning on real RINEX data.

    jaxnav ppp --obs OBS --nav NAV [--sp3 F ...] [--clk F] [--ionex F]
               --mode static|kinematic --freq single|dual [--phase] [--systems G,R,E]
               [--start ISO --duration S] [--ref X,Y,Z]
               [--dcb P1C1.DCB | --p1c1-from-obs | --no-p1c1] --out OUT.pos

The forward filter is ``filter/tight.py``'s epoch step driven by a GNSS-only system
(``filter/ppp_only.py``): the same measurement models, slot resets, gating and outputs as the
integrated PPP/INS filters. ``--freq dual`` runs ionosphere-free code + carrier with float
ambiguities and a zenith-wet-delay state (``float_ppp``, S002 ch. 5); ``--freq single`` runs
C1 code with the broadcast Klobuchar (or ``--ionex``) ionosphere and the broadcast TGD
(``sf_code``, S000 / S002 ch. 4); ``--freq single --phase`` adds the L1 carrier phase with
a float ambiguity and a slant-ionosphere state per satellite (``sf_ppp``, S002 ch. 4; its
slips come from the receiver's loss-of-lock indicators only, as the geometry-free and
Melbourne-Wuebbena tests need two frequencies). Single frequency levels the GPS/GLONASS C/A
code to P1 with the satellites' P1-C1 biases (the clocks refer to P1/P2): one of ``--dcb``
(CODE file), ``--p1c1-from-obs`` (the file's own C1W - C1C) or ``--no-p1c1`` is required.
``--smooth`` (= ``--solution combined``) writes the forward filter followed by the RTS smoother
(``tight.run_smoother``): every epoch estimated from the whole session, as RTKPOST's "combined"
solution; the summary is the smoothed solution's, with the forward one's final error and RMS
beside it. A "backward" solution (the filter run in reverse time) is not offered.
``--mode static`` keeps the position a random
constant, ``--mode kinematic`` makes it a random walk of 100 m/sqrt(s) (S002 §5.2.3). Without
``--sp3`` the broadcast orbits and clocks are used.

Receiver clock: S002 §5.2.2 models it as white noise; here the clock keeps the bias + drift
states of the tight filter with a large bias PSD (``CLOCK_PSD_M2_S``), which re-estimates it
freely every epoch.

Printed summary: final position (ECEF, LLH), its offset from the reference (``--ref``, else the
RINEX header APPROX position is shown for information), convergence time to < 10 cm and
< 20 cm horizontal error (first epoch after which the error stays below), and RMS of the
east/north/up errors over the epochs after the first hour (``--rms-after``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxnav  # noqa: F401  (float64)
from jaxnav import geodesy
from jaxnav.apps import (
    Stages,
    add_plot_option,
    add_solution_options,
    existing_file,
    plots,
    pos_solution_label,
    prep_cache,
)
from jaxnav.core.gpstime import gps_seconds_to_datetime64
from jaxnav.filter import ppp_only, tight
from jaxnav.filter.systems import NavSigmas
from jaxnav.gnss import modes as ppp_modes
from jaxnav.gnss import ppp
from jaxnav.io import pos as pos_io
from jaxnav.io import prepare as prep_mod
from jaxnav.io.errors import InputError
from jaxnav.io.nav import read_broadcast_ephemeris
from jaxnav.io.products import read_clk, read_code_dcb, read_ionex, read_sp3
from jaxnav.io.rinex import read_rinex_obs

#: The recorded-data receiver clock and code noise (``gnss.ppp.PppConfig.for_recorded_data``).
CLOCK_PSD_M2_S = ppp.RECORDED_CLOCK_PSD_M2_S
REAL_CODE_SIGMA_M = ppp.RECORDED_CODE_SIGMA_M
#: Initial position 1-sigma [m] around the single-point solution (chosen: SPP is metre-level).
INIT_POS_SIGMA_M = 30.0


def _parse_systems(text: str) -> tuple[str, ...]:
    out = tuple(s.strip().upper() for s in text.split(",") if s.strip())
    bad = [s for s in out if s not in prep_mod.LETTER_TO_SYS]
    if bad or not out:
        raise argparse.ArgumentTypeError(f"--systems takes letters G, R, E (got {text!r})")
    return out


def _parse_xyz(text: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.replace(" ", "").split(",")])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--ref takes X,Y,Z in metres (got {text!r})") from exc
    if v.shape != (3,):
        raise argparse.ArgumentTypeError(f"--ref takes X,Y,Z in metres (got {text!r})")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="jaxnav ppp", description=__doc__.split("\n\n")[0])
    p.add_argument("--obs", required=True, type=existing_file,
                   help="RINEX 2/3 observations (.rnx/.crx, .gz)")
    p.add_argument("--nav", type=existing_file,
                   help="RINEX 3 navigation file (broadcast orbits, Klobuchar, TGD); needed "
                        "without --sp3 and for --freq single")
    p.add_argument("--sp3", nargs="+", default=[], type=existing_file,
                   help="SP3 orbit file(s), joined in time order (default: broadcast orbits "
                        "from --nav)")
    p.add_argument("--clk", type=existing_file,
                   help="RINEX clock file (precise satellite clocks; default: the SP3 clocks, "
                        "else broadcast)")
    p.add_argument("--ionex", type=existing_file,
                   help="IONEX maps for the single-frequency ionosphere (default: Klobuchar "
                        "from --nav)")
    p.add_argument("--mode", choices=("static", "kinematic"), required=True,
                   help="static: one position for the whole file; kinematic: a position per "
                        "epoch (random walk, 100 m/sqrt(s))")
    p.add_argument("--freq", choices=("single", "dual"), required=True,
                   help="single: L1 C/A code (and --phase); dual: ionosphere-free P1/P2 code "
                        "and carrier")
    p.add_argument("--phase", action="store_true",
                   help="with --freq single: add the L1 carrier phase (sf_ppp)")
    p.add_argument("--systems", type=_parse_systems, default=("G",),
                   help="constellation letters: G (GPS), R (GLONASS), E (Galileo); e.g. G or G,E "
                        "(default G)")
    p.add_argument("--start", help="first epoch, ISO GPST (e.g. 2020-06-25T00:00:00); give it "
                                 "with --duration (default, neither: the whole file)")
    p.add_argument("--duration", type=float,
                   help="seconds to process from --start; give it with --start (default, "
                        "neither: the whole file)")
    p.add_argument("--ref", type=_parse_xyz,
                   help="reference ECEF X,Y,Z [m] for the statistics (default: the final "
                        "static solution, or in kinematic mode the mean after --rms-after)")
    p.add_argument(
        "--ppp-mode",
        choices=ppp_modes.MODES,
        help="override the PPP flavour (default: float_ppp for dual, sf_code for single, "
        "sf_ppp for single with --phase)",
    )
    p.add_argument("--elevation-mask", type=float, default=10.0, help="degrees (default 10)")
    p.add_argument(
        "--rms-after",
        type=float,
        default=3600.0,
        help="RMS over epochs this many seconds [s] after the start (default 3600)",
    )
    p.add_argument("--no-windup", action="store_true",
                   help="do not correct the carrier phase wind-up (on by default)")
    p.add_argument("--no-tides", action="store_true",
                   help="do not correct the solid Earth tide (on by default)")
    p.add_argument(
        "--sp3-one-sided",
        action="store_true",
        help="use one-sided SP3 interpolation at the table ends (else no orbit there)",
    )
    p1c1 = p.add_mutually_exclusive_group()
    p1c1.add_argument("--dcb", type=existing_file,
                      help="CODE P1-C1 DCB file: levels the C/A code of --freq single "
                      "to P1, as the clocks expect")
    p1c1.add_argument("--p1c1-from-obs", action="store_true",
                      help="measure the satellites' P1-C1 from the file's own C1W - C1C")
    p1c1.add_argument("--no-p1c1", action="store_true",
                      help="use the C/A code as P1 (accepts up to ~1 m of satellite bias)")
    p.add_argument("--out", required=True, help="output RTKLIB .pos file")
    add_plot_option(p)
    p.add_argument("--no-cache", action="store_true",
                   help="read and prepare the files even if the cache of prepared observations "
                        "holds them, and renew the entry ($JAXNAV_CACHE_DIR or ~/.cache/jaxnav;"
                        " apps/prep_cache.py)")
    p.add_argument("--quiet", action="store_true", help="print only errors and the summary")
    add_solution_options(p)
    return p


def _time_window(args):
    if args.start is None and args.duration is None:
        return None
    if args.start is None or args.duration is None:
        raise InputError("--start and --duration go together", expected="both or neither")
    start = dt.datetime.fromisoformat(args.start)
    end = start + dt.timedelta(seconds=args.duration) - dt.timedelta(milliseconds=1)
    return start, end


def first_below_s(t_s, err_m, threshold_m):
    """First time at which |err| is below the threshold (NaN if never)."""
    ok = np.flatnonzero(np.abs(err_m) < threshold_m)
    return float(t_s[ok[0]]) if ok.size else math.nan


def convergence_time_s(t_s, err_m, threshold_m):
    """First time after which |err| stays below the threshold (NaN if it never does)."""
    bad = np.flatnonzero(~(np.abs(err_m) < threshold_m))
    if bad.size == 0:
        return float(t_s[0])
    if bad[-1] == t_s.size - 1:
        return math.nan
    return float(t_s[bad[-1] + 1])


def summary_stats(time_gps_s, llh, ref_ecef, rms_after_s=3600.0, used=None):
    """Errors vs a reference: ENU [N, 3], convergence times and RMS after ``rms_after_s``.

    ``used`` [N] bool (default all) selects the epochs with a GNSS update for the statistics.
    """
    ref_llh = geodesy.ecef_to_llh(jnp.asarray(ref_ecef))
    ecef = jax.vmap(geodesy.llh_to_ecef)(jnp.asarray(llh))
    enu = np.asarray(jax.vmap(lambda p: geodesy.enu_offset(p, ref_llh))(ecef))
    t = np.asarray(time_gps_s) - time_gps_s[0]
    used = np.ones(t.size, bool) if used is None else np.asarray(used, bool)
    hor = np.hypot(enu[:, 0], enu[:, 1])
    late = (t >= rms_after_s) & used
    t, hor_u = t[used], hor[used]
    rms = np.sqrt(np.mean(enu[late] ** 2, axis=0)) if late.any() else np.full(3, np.nan)
    return {
        "enu": enu,
        "horizontal": hor,
        "conv10_s": convergence_time_s(t, hor_u, 0.10),
        "conv20_s": convergence_time_s(t, hor_u, 0.20),
        "first10_s": first_below_s(t, hor_u, 0.10),
        "first20_s": first_below_s(t, hor_u, 0.20),
        "rms_enu": rms,
        "rms_h": float(np.hypot(rms[0], rms[1])),
        "rms_3d": float(np.linalg.norm(rms)),
        "n_rms": int(late.sum()),
    }


def run_ppp(
    prep: prep_mod.PreparedGnss,
    cfg: ppp.PppConfig,
    system: ppp_only.GnssOnlySystem,
    epoch_dt_s: float,
    nav0: ppp_only.GnssNav | None = None,
    init_sigma_m=INIT_POS_SIGMA_M,
):
    """Run the forward filter over the prepared epochs; returns (final carry, outputs).

    ``nav0`` defaults to the single-point solution of the first epoch where SPP succeeded (not
    the static median of ``prep.approx_pos_ecef``, which would lend the start information from
    the whole session).
    """
    return _run_filter(*_filter_start(prep, cfg, system, epoch_dt_s, nav0, init_sigma_m))


def run_ppp_smoothed(
    prep: prep_mod.PreparedGnss,
    cfg: ppp.PppConfig,
    system: ppp_only.GnssOnlySystem,
    epoch_dt_s: float,
    nav0: ppp_only.GnssNav | None = None,
    init_sigma_m=INIT_POS_SIGMA_M,
):
    """``run_ppp``'s filter followed by the RTS smoother (``tight.run_smoother``): returns
    (forward outputs, smoothed outputs), RTKPOST's "forward" and "combined" solutions."""
    return _run_smoother(*_filter_start(prep, cfg, system, epoch_dt_s, nav0, init_sigma_m))


def _filter_start(prep, cfg, system, epoch_dt_s, nav0, init_sigma_m):
    """(filter, initial carry, stacked inputs) of ``run_ppp``."""
    tf = tight.TightFilter(
        system=system, cfg=cfg, slots=prep.slots, imu_dt_s=epoch_dt_s, epoch_dt_s=epoch_dt_s
    )
    T = prep.time_gps_s.size
    inputs = prep_mod.epoch_inputs(prep, ppp_only.dummy_samples(T))
    # Initialise the clock from the first epoch with data (epoch 0 may have none, e.g. before
    # the clock file starts): tight.initial_carry takes the median code residual of obs0.
    have = np.asarray(prep.obs.available).any(axis=1)
    k0 = int(np.flatnonzero(have)[0]) if have.any() else 0
    obs0 = jax.tree.map(lambda x: x[k0], prep.obs)
    if nav0 is None:
        ok = np.flatnonzero(prep.spp_ok)
        start = prep.spp_pos_ecef[ok[0]] if ok.size else prep.approx_pos_ecef[0]
        nav0 = ppp_only.initial_nav(start)
    carry = tight.initial_carry(tf, nav0, obs0, NavSigmas(pos_m=init_sigma_m, vel_m_s=10.0))
    return tf, carry, inputs


@eqx.filter_jit
def _run_filter(tf, carry, inputs):
    """Compiled once per (configuration, shapes): arrays are traced, settings static."""
    return tight.run(tf, carry, inputs)


@eqx.filter_jit
def _run_smoother(tf, carry, inputs):
    return tight.run_smoother(tf, carry, inputs)


def _pos_solution(prep, out, q):
    llh = np.asarray(out.llh)
    P = np.asarray(out.P_nav)[:, :3, :3]
    m = np.asarray(jax.vmap(geodesy.metres_per_radian)(jnp.asarray(llh)))  # N, E, U scale
    cov = P * m[:, :, None] * m[:, None, :]
    sd = np.sqrt(np.maximum(np.stack([cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]], -1), 0.0))

    def ssqrt(x):
        return np.sign(x) * np.sqrt(np.abs(x))

    cross = np.stack([ssqrt(cov[:, 0, 1]), ssqrt(cov[:, 1, 2]), ssqrt(cov[:, 2, 0])], -1)
    n = llh.shape[0]
    ns = np.asarray(out.n_sat)
    return pos_io.PosSolution(
        time_gps_s=prep.time_gps_s,
        llh=llh,
        q=np.where(ns > 0, q, pos_io.Q_OUTAGE),  # no satellite used: a prediction only
        ns=ns,
        sd_neu_m=sd,
        sd_cross_m=cross,
        age_s=np.zeros(n),
        ratio=np.zeros(n),
        vel_enu=np.full((n, 3), np.nan),
        sd_vel_neu=np.full((n, 3), np.nan),
        sd_vel_cross=np.full((n, 3), np.nan),
    )


def _fmt_time(s):
    return "never" if not np.isfinite(s) else f"{s / 60.0:.1f} min"


def main(argv=None) -> int:
    """Entry point of ``jaxnav ppp``; returns a process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    t_start = time.time()
    try:
        return _main(args, argv, t_start)
    except (InputError, ValueError, FileNotFoundError) as exc:
        print(f"jaxnav ppp: error: {exc}", file=sys.stderr)
        return 2


#: The PPP flavour of (--freq, --phase) when --ppp-mode is not given.
DEFAULT_MODES = {("dual", False): "float_ppp", ("single", False): "sf_code",
                 ("single", True): "sf_ppp"}


def _ppp_mode(args) -> str:
    """The mode for the command line, checked against the frequencies read."""
    if args.phase and args.freq == "dual":
        raise InputError("--phase is for --freq single",
                         expected="--freq single --phase (dual frequency always uses the phase)")
    mode = args.ppp_mode or DEFAULT_MODES[(args.freq, args.phase)]
    single = ppp_modes.get(mode).single_frequency
    if single != (args.freq == "single"):
        raise InputError(f"--ppp-mode {mode} is a {'single' if single else 'dual'}-frequency mode",
                         expected=f"--freq {'single' if single else 'dual'}")
    return mode


def _main(args, argv, t_start) -> int:
    mode = _ppp_mode(args)  # before any file is read
    if not args.sp3 and args.nav is None:
        raise InputError("orbits are needed", expected="--sp3 files and/or --nav")
    if ppp_modes.get(mode).uses_iono_model and not (args.nav or args.ionex):
        raise InputError(f"{mode} needs a model ionosphere",
                         expected="--nav (Klobuchar) or --ionex")
    if args.freq == "single" and args.nav is None:
        raise InputError("--freq single needs the broadcast group delays (TGD / BGD)",
                         expected="--nav")
    single_gps = args.freq == "single" and any(s in prep_mod.P1_CODES for s in args.systems)
    if single_gps and not (args.dcb or args.p1c1_from_obs or args.no_p1c1):
        raise InputError("--freq single: the C/A code needs the satellites' P1-C1 biases",
                         expected="--dcb FILE, --p1c1-from-obs or --no-p1c1")
    if args.freq == "dual" and (args.dcb or args.p1c1_from_obs or args.no_p1c1):
        raise InputError("--dcb / --p1c1-from-obs / --no-p1c1 are for --freq single",
                         expected="no P1-C1 option with --freq dual (P1/P2 are read)")
    p1c1_m = read_code_dcb(args.dcb) if args.dcb else None
    window = _time_window(args)
    opt = prep_mod.PrepareOptions(
        freq=args.freq,
        systems=args.systems,
        iono="ionex" if args.ionex else ("klobuchar" if args.nav else "none"),
        apply_windup=not args.no_windup,
        apply_tides=not args.no_tides,
        sp3_one_sided=args.sp3_one_sided,
        p1c1_m=p1c1_m,
        ignore_p1c1=args.no_p1c1,
    )
    stage = Stages(args.quiet)

    def read_and_prepare():
        with warnings.catch_warnings(), stage(f"reading {args.obs}"):
            warnings.simplefilter("ignore", FutureWarning)
            obs = read_rinex_obs(
                args.obs,
                prep_mod.rinex_requests(args.freq, args.systems, p1_codes=args.p1c1_from_obs),
                tlim=window,
                on_missing="nan",
                indicators=True,
            )
        if args.p1c1_from_obs:
            opt.p1c1_m = prep_mod.p1c1_from_observations(obs)
        with stage(f"reading {len(inputs) - 1} product file(s)"):
            nav = (read_broadcast_ephemeris(args.nav, systems="".join(args.systems))
                   if args.nav else None)
            sp3 = read_sp3(args.sp3) if args.sp3 else None
            clk = read_clk(args.clk, systems=set(args.systems)) if args.clk else None
            ionex = read_ionex(args.ionex) if args.ionex else None
        products = prep_mod.Products(nav=nav, sp3=sp3, clk=clk, ionex=ionex)
        with stage("preparing (orbits, clocks, corrections per epoch)"):
            return obs, prep_mod.prepare_gnss(obs, products, opt,
                                              static_receiver=args.mode == "static")

    roles = [("--obs", args.obs), ("--nav", args.nav), *(("--sp3", f) for f in args.sp3),
             ("--clk", args.clk), ("--ionex", args.ionex), ("--dcb", args.dcb)]
    roles = [(r, f) for r, f in roles if f]
    inputs = [f for _, f in roles]
    options = {k: getattr(args, k) for k in (
        "freq", "systems", "no_windup", "no_tides", "sp3_one_sided", "p1c1_from_obs",
        "no_p1c1", "mode")} | {"window": window}
    if not args.quiet:
        print(f"jaxnav ppp: reading and preparing {args.obs} and {len(inputs) - 1} product "
              f"file(s)" + ("" if args.no_cache else " (or from the cache)") + " ...",
              flush=True)
    # (on a cache hit opt.p1c1_m stays unset: only the preparation reads it)
    (obs, prep), hit, cache_key = prep_cache.cached(roles, options, read_and_prepare,
                                                    read=not args.no_cache)
    if hit and not args.quiet:
        print(f"  prepared observations from the cache ({prep_cache.cache_dir()}/"
              f"{cache_key[:12]}...; --no-cache to read the files again)")
    t_read = time.time()

    sys_ids = tuple(sorted({prep_mod.LETTER_TO_SYS[s] for s in args.systems}))
    cfg = ppp.PppConfig(
        mode=mode,
        systems=sys_ids,
        n_slots=len(prep.sv),
        doppler=False,
        estimate_zwd=args.freq == "dual",
        elevation_mask_rad=math.radians(args.elevation_mask),
    ).for_recorded_data()
    model = "static" if args.mode == "static" else "random_walk"
    system = ppp_only.GnssOnlySystem(model=model)
    smooth = args.solution == "combined"
    with stage(f"compiling and running the filter over {len(prep.time_gps_s)} epochs"
               + (" and the smoother" if smooth else "")):
        if smooth:
            out_fwd, out = run_ppp_smoothed(prep, cfg, system, float(obs.interval_s))
        else:
            _, out = run_ppp(prep, cfg, system, float(obs.interval_s))
        jax.block_until_ready(out.llh)
    t_run = time.time()

    # RTKLIB's quality flag: PPP for a carrier-phase solution, "single" for code only.
    q = pos_io.Q_PPP if ppp_modes.get(mode).uses_phase else pos_io.Q_SINGLE
    sol = _pos_solution(prep, out, q)
    # RTKPOST writes no line for an epoch without a solution: a GNSS-only filter without a
    # satellite has only its own prediction (frozen position, growing sigmas), so it is left
    # out rather than written as dead reckoning (Q = 7).
    solved = np.asarray(sol.ns) > 0
    sol = pos_io.PosSolution(*(np.asarray(a)[solved] for a in sol))
    cmd = "jaxnav ppp " + " ".join(argv)
    info = [("inp file", f) for f in inputs] + [
        ("pos mode", f"PPP {args.mode.capitalize()} ({mode})"),
        ("freqs", "L1" if args.freq == "single" else "L1+L2"),
        ("solution", pos_solution_label(smooth)),
        ("elev mask", f"{args.elevation_mask:.1f} deg"),
        ("ionos opt", {"ionex": "IONEX TEC", "klobuchar": "Broadcast",
                       "none": "Off"}[opt.iono] if args.freq == "single" else "Iono-Free LC"),
        ("tropo opt", "Estimate ZTD" if cfg.estimate_zwd else "Saastamoinen"),
        ("ephemeris", "Precise" if args.sp3 else "Broadcast"),
        ("navi sys", ",".join({"G": "GPS", "E": "Galileo", "R": "GLONASS", "C": "BeiDou"}.get(
            x, x) for x in args.systems)),
        ("tidecorr", "off" if args.no_tides else "solid"),
    ]
    if args.ref is not None:
        ref_llh = np.asarray(geodesy.ecef_to_llh(jnp.asarray(args.ref, float)))
        info.append(("ref pos", f"{math.degrees(ref_llh[0]):.9f} {math.degrees(ref_llh[1]):.9f} "
                                f"{ref_llh[2]:.4f}"))
    pos_io.write_pos(
        args.out,
        sol,
        info=tuple(info),
        comments=(f"command   : {cmd}",) + ((
            f"no solution: {int((~solved).sum())} epoch(s) without a satellite used left "
            "out",) if not solved.all() else ()),
        program=f"jaxnav {jaxnav.__version__} ppp",
    )

    used = np.asarray(out.n_sat) > 0
    k_last = int(np.flatnonzero(used)[-1]) if used.any() else used.size - 1
    final_llh = np.asarray(out.llh[k_last])  # last epoch with a GNSS update
    final_ecef = np.asarray(geodesy.llh_to_ecef(jnp.asarray(final_llh)))
    t0 = gps_seconds_to_datetime64(prep.time_gps_s[0])
    t1 = gps_seconds_to_datetime64(prep.time_gps_s[-1])
    print(
        f"jaxnav ppp: {args.mode} {args.freq}-frequency ({mode}), systems "
        f"{','.join(args.systems)}, {prep.time_gps_s.size} epochs {t0} .. {t1} GPST, "
        f"{len(prep.sv)} satellites"
    )
    print(
        f"  orbits/clocks : {'SP3' if args.sp3 else 'broadcast'} / "
        f"{'CLK' if args.clk else ('SP3' if args.sp3 else 'broadcast')}; "
        f"iono {opt.iono if args.freq == 'single' else 'ionosphere-free'}; slips flagged "
        f"LLI {prep.slip_counts['lli']}, GF {prep.slip_counts['gf']}, "
        f"MW {prep.slip_counts['mw']}"
        + (f", carrier-Doppler {prep.slip_counts['doppler']}" if args.freq == "single" else "")
    )
    lost = {k: v for k, v in prep.lost_counts.items() if v and (
        k != "no_iono_model" or ppp_modes.get(mode).uses_iono_model) and k != "no_doppler"}
    if lost:
        print("  unusable slot-epochs: " + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                     for k, v in lost.items()))
    if args.freq == "single":
        src = ("CODE DCB file" if args.dcb else "measured C1W - C1C" if args.p1c1_from_obs
               else "NOT applied (--no-p1c1)")
        print(f"  C/A P1-C1 bias : {src}")
    x, y, z = final_ecef
    t_last = gps_seconds_to_datetime64(prep.time_gps_s[k_last])
    print(f"  final position (last epoch with satellites, {t_last} GPST):")
    print(f"                  X {x:.4f}  Y {y:.4f}  Z {z:.4f} m")
    print(
        f"                  lat {math.degrees(final_llh[0]):.9f}  lon "
        f"{math.degrees(final_llh[1]):.9f} deg  h {final_llh[2]:.4f} m"
    )
    header = obs.approx_pos_ecef
    if np.all(np.isfinite(header)):
        d = np.asarray(
            geodesy.enu_offset(jnp.asarray(final_ecef), geodesy.ecef_to_llh(jnp.asarray(header)))
        )
        print(f"  minus header APPROX position (E, N, U): {d[0]:+.4f} {d[1]:+.4f} {d[2]:+.4f} m")
    if args.ref is not None:
        ref, ref_name = args.ref, "--ref"
    elif args.mode == "static":
        ref, ref_name = final_ecef, "final static solution"
    else:
        late = ((prep.time_gps_s - prep.time_gps_s[0]) >= args.rms_after) & used
        mean_llh = np.asarray(out.llh)[late].mean(0) if late.any() else final_llh
        ref = np.asarray(geodesy.llh_to_ecef(jnp.asarray(mean_llh)))
        ref_name = "mean kinematic solution after --rms-after (self-reference; give --ref)"
    st = summary_stats(prep.time_gps_s, np.asarray(out.llh), ref, args.rms_after, used)
    fe = st["enu"][k_last]
    print(f"  reference     : {ref_name}: X {ref[0]:.4f} Y {ref[1]:.4f} Z {ref[2]:.4f}")
    print(f"  final - ref (E, N, U): {fe[0]:+.4f} {fe[1]:+.4f} {fe[2]:+.4f} m")
    print(
        f"  convergence   : horizontal error stays < 20 cm from {_fmt_time(st['conv20_s'])}, "
        f"< 10 cm from {_fmt_time(st['conv10_s'])} (first below: "
        f"{_fmt_time(st['first20_s'])}, {_fmt_time(st['first10_s'])})"
    )
    r = st["rms_enu"]
    print(
        f"  RMS after {args.rms_after / 60:.0f} min ({st['n_rms']} epochs): E {r[0]:.4f} "
        f"N {r[1]:.4f} U {r[2]:.4f} m, horizontal {st['rms_h']:.4f} m, 3D {st['rms_3d']:.4f} m"
    )
    if smooth:  # the forward filter of the same run, against the same reference
        sf = summary_stats(prep.time_gps_s, np.asarray(out_fwd.llh), ref, args.rms_after, used)
        ff, rf = sf["enu"][k_last], sf["rms_enu"]
        print(f"  forward filter: final - ref (E, N, U) {ff[0]:+.4f} {ff[1]:+.4f} {ff[2]:+.4f} m; "
              f"RMS after {args.rms_after / 60:.0f} min E {rf[0]:.4f} N {rf[1]:.4f} U "
              f"{rf[2]:.4f} m, horizontal {sf['rms_h']:.4f} m; < 10 cm from "
              f"{_fmt_time(sf['conv10_s'])}")
    spp_ok = prep.spp_ok
    if spp_ok.any():
        e_spp = np.asarray(
            jax.vmap(lambda p: geodesy.enu_offset(p, geodesy.ecef_to_llh(jnp.asarray(ref))))(
                jnp.asarray(prep.spp_pos_ecef[spp_ok])
            )
        )
        rs = np.sqrt(np.mean(e_spp**2, axis=0))
        print(
            f"  epoch-wise least-squares SPP RMS vs reference ({int(spp_ok.sum())} epochs): "
            f"E {rs[0]:.3f} N {rs[1]:.3f} U {rs[2]:.3f} m"
        )
    print(
        f"  wrote {args.out}  (read+prepare {t_read - t_start:.1f} s, filter "
        f"{t_run - t_read:.1f} s)"
    )
    if not args.no_plots and sol.time_gps_s.size:  # (no epoch with a satellite: no plots)
        ref_llh = np.asarray(geodesy.ecef_to_llh(jnp.asarray(ref, float)))
        written = plots.write_run_plots(
            args.out, sol, t0_gps_s=float(prep.time_gps_s[0]), ref_llh=ref_llh,
            ref_name=ref_name, title=f"jaxnav ppp: {args.mode} {args.freq}-frequency {mode}, "
            f"{'combined' if smooth else 'forward'} solution")
        print("  wrote " + ", ".join(str(p) for p in written.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
