"""Outage sweep engine (jaxnav.study.sweep) and study definitions (jaxnav.study.config).

The engine is tested with a stand-in filter that has the tight filter's ``run(tf, carry,
inputs)`` contract: a 2-D constant-velocity Kalman filter (jaxnav.filter.ekf) ranging to fixed
beacons, on a drive with a straight, a constant-rate turn and a straight. Subprocess tests
(kill + resume, 4 forced host devices) import this module for the same stand-in.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from functools import partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

import jaxnav
from jaxnav import geodesy
from jaxnav.filter import ekf
from jaxnav.study import config as sc
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study import sweep as sw

pytestmark = pytest.mark.heavy  # subprocesses (4 host devices, kill + resume)

HERE = Path(__file__).resolve().parent
PYTHON = sys.executable
DEG = math.pi / 180.0

# ----------------------------------------------------------------------------------------------
# Stand-in filter: 2-D constant velocity, ranges to fixed beacons
# ----------------------------------------------------------------------------------------------
LLH0 = np.array([44.2312 * DEG, -76.4860 * DEG, 90.0])
_MPR = np.asarray(geodesy.metres_per_radian(jnp.asarray(LLH0)))  # north, east, up [m/rad]
SPEED = 10.0  # m/s
TURN_RATE = 0.1  # rad/s (radius 100 m, centripetal 1 m/s^2)
TURN_START, TURN_END = 150.0, 270.0
N_BEACON = 6
BEACON_EL = np.array([15.0, 30.0, 45.0, 60.0, 75.0, 85.0]) * DEG  # for the selection policy
BEACON_AZ = np.array([0.0, 60.0, 120.0, 180.0, 240.0, 300.0]) * DEG
SIGMA_RANGE = 0.3  # m
Q_ACCEL = 1.0  # m^2/s^3 (responsive: small velocity lag in the 1 m/s^2 turn)


class ToyFilter(NamedTuple):
    beacons_en: jnp.ndarray  # [S, 2] m
    q: float
    sigma: jnp.ndarray
    dt: float


class ToyCarry(NamedTuple):
    x: jnp.ndarray  # [4] e, n, ve, vn
    P: jnp.ndarray


class ToyInput(NamedTuple):
    range_m: jnp.ndarray  # [S]
    available: jnp.ndarray  # [S]
    keep: jnp.ndarray  # [S]


class ToyOutput(NamedTuple):
    llh: jnp.ndarray
    vel_enu: jnp.ndarray
    euler: jnp.ndarray
    P_nav: jnp.ndarray


def en_to_llh(e, n):
    lat = LLH0[0] + n / _MPR[0]
    lon = LLH0[1] + e / _MPR[1]
    return jnp.stack([lat, lon, jnp.full_like(lat, LLH0[2])], axis=-1)


def _toy_transition(dt, q):
    Phi = jnp.eye(4).at[0, 2].set(dt).at[1, 3].set(dt)
    Q = q * jnp.array(
        [[dt**3 / 3, 0, dt**2 / 2, 0], [0, dt**3 / 3, 0, dt**2 / 2],
         [dt**2 / 2, 0, dt, 0], [0, dt**2 / 2, 0, dt]]
    )
    return Phi, Q


def _toy_output(x, P):
    scale = jnp.array([1 / _MPR[0], 1 / _MPR[1], 1.0, 1.0, 1.0, 1.0])  # (n, e) m -> (lat, lon)
    # P_nav in the tight filter's units: (d_lat, d_lon, d_h) rad/rad/m, vel ENU
    idx = jnp.array([1, 0, 0, 2, 3, 0])  # n, e, (h), ve, vn, (vu)
    P6 = P[idx[:, None], idx[None, :]]
    unit = jnp.array([1.0, 1.0, 0.0, 1.0, 1.0, 0.0])
    P6 = P6 * unit[:, None] * unit[None, :] + jnp.diag(1.0 - unit)
    P6 = P6 * scale[:, None] * scale[None, :]
    return ToyOutput(
        llh=en_to_llh(x[0], x[1]),
        vel_enu=jnp.array([x[2], x[3], 0.0]),
        euler=jnp.array([0.0, 0.0, jnp.arctan2(x[2], x[3])]),
        P_nav=P6,
    )


def _toy_scan(tf: ToyFilter, carry: ToyCarry, inputs: ToyInput):
    """The stand-in's KF; per epoch (prior mean, prior P, posterior mean, posterior P)."""
    Phi, Q = _toy_transition(tf.dt, tf.q)

    def step(c, inp):
        x_pr, P_pr = ekf.predict(c.x, c.P, Phi, Q)
        d = x_pr[:2] - tf.beacons_en
        r = jnp.linalg.norm(d, axis=1)
        H = jnp.zeros((N_BEACON, 4)).at[:, :2].set(d / r[:, None])
        res = ekf.masked_update(
            jnp.zeros(4), P_pr, inp.range_m - r, H, tf.sigma**2 * jnp.eye(N_BEACON),
            inp.available & inp.keep,
        )
        x = x_pr + res.x
        return ToyCarry(x, res.P), (x_pr, P_pr, x, res.P)

    return jax.lax.scan(step, carry, inputs)


def toy_run(tf: ToyFilter, carry: ToyCarry, inputs: ToyInput):
    carry, (_, _, x, P) = _toy_scan(tf, carry, inputs)
    return carry, jax.vmap(_toy_output)(x, P)


def toy_smooth(tf: ToyFilter, carry: ToyCarry, inputs: ToyInput, n_valid=None):
    """(forward, RTS-smoothed) outputs of the stand-in (jaxnav.filter.smoother.rts), smoothed
    over the first ``n_valid`` epochs."""
    from jaxnav.filter import smoother

    _, (x_pr, P_pr, x, P) = _toy_scan(tf, carry, inputs)
    Phi, _ = _toy_transition(tf.dt, tf.q)
    Phi = jnp.broadcast_to(Phi, P.shape)
    if n_valid is not None:
        Phi = smoother.cut_after(Phi, n_valid)
    xs, Ps = smoother.rts(x, P, x_pr, P_pr, Phi)
    return jax.vmap(_toy_output)(x, P), jax.vmap(_toy_output)(xs, Ps)


TOY_OPS = sw.FilterOps(
    run=toy_run,
    readout=lambda o: (mt.track(o.llh, o.vel_enu, o.euler), o.P_nav),
    get_keep=lambda i: i.keep,
    with_keep=lambda i, k: i._replace(keep=k),
    smooth=toy_smooth,
)


def toy_truth(t):
    """Straight east, a right turn at TURN_RATE (clockwise), straight: (e, n, ve, vn, azimuth)."""
    t = np.asarray(t, float)
    r = SPEED / TURN_RATE
    tau = np.clip(t - TURN_START, 0.0, TURN_END - TURN_START)
    psi = math.pi / 2 + TURN_RATE * tau
    e_turn = r * (math.cos(math.pi / 2) - np.cos(psi))
    n_turn = r * (np.sin(psi) - math.sin(math.pi / 2))
    e = SPEED * np.minimum(t, TURN_START) + e_turn
    n = n_turn.copy()
    after = np.maximum(t - TURN_END, 0.0)
    e = e + SPEED * np.sin(psi) * after
    n = n + SPEED * np.cos(psi) * after
    return e, n, SPEED * np.sin(psi), SPEED * np.cos(psi), psi


class ToyFactory:
    """Scenario factory for the stand-in: the noise realization is the range noise."""

    ops = TOY_OPS
    modes = ("toy_a", "toy_b")
    systems = ("cv",)

    def __init__(self, n_epochs=400, dt=1.0):
        self.n_epochs, self.dt = n_epochs, dt

    def fingerprint(self):
        return f"toy-cv n={self.n_epochs} dt={self.dt}"

    def timeline(self, cfg):
        t = np.arange(self.n_epochs) * self.dt
        labels = np.where((t >= TURN_START) & (t < TURN_END), 1, 0)  # Event.TURN / STRAIGHT
        return sw.Timeline(self.n_epochs, self.dt, labels)

    def build(self, cfg, mode, system, seed):
        T = self.n_epochs
        t = np.arange(1, T + 1) * self.dt  # epoch k at t_k (the state after the first dt)
        e, n, ve, vn, psi = toy_truth(t)
        beacons = 20e3 * np.stack([np.sin(BEACON_AZ), np.cos(BEACON_AZ)], axis=1)
        rng = np.random.default_rng(seed)
        pos = np.stack([e, n], axis=1)
        rng_m = np.linalg.norm(pos[:, None, :] - beacons[None], axis=2)
        rng_m = rng_m + SIGMA_RANGE * rng.standard_normal(rng_m.shape)
        avail = np.ones((T, N_BEACON), bool)
        avail[200:240, 5] = False  # the highest beacon drops out for 40 s
        # mode b: noisier ranges (a static difference between groups is not needed)
        sigma = SIGMA_RANGE * (2.0 if mode == "toy_b" else 1.0)
        # sigma as an array: both modes share one static configuration (one compilation)
        tf = ToyFilter(jnp.asarray(beacons), Q_ACCEL, jnp.asarray(sigma), self.dt)
        x0 = np.array([e[0] - SPEED * self.dt + 3.0, n[0] - 2.0, ve[0], vn[0]])
        carry0 = ToyCarry(jnp.asarray(x0), jnp.diag(jnp.array([25.0, 25.0, 4.0, 4.0])))
        inputs = ToyInput(jnp.asarray(rng_m), jnp.asarray(avail), jnp.ones((T, N_BEACON), bool))
        truth = mt.Track(
            en_to_llh(jnp.asarray(e), jnp.asarray(n)),
            jnp.stack([ve, vn, np.zeros(T)], axis=1),
            jnp.asarray(psi),
        )
        el = np.broadcast_to(BEACON_EL, (T, N_BEACON))
        az = np.broadcast_to(BEACON_AZ, (T, N_BEACON))
        return sw.Problem(tf, carry0, inputs, truth, jnp.asarray(el), jnp.asarray(avail),
                          jnp.asarray(az))


def toy_config(**study) -> sc.StudyConfig:
    base = {
        "name": "toy", "modes": ["toy_a", "toy_b"], "systems": ["cv"],
        "durations_s": [10, 30], "satellites_kept": [0, 1, 2, "all"],
        "realizations": 2, "recovery_s": 20, "chunk_size": 16, "max_traces": 5,
    }
    placement = study.pop("placement", {"kind": "grid", "convergence_s": 60, "spacing_s": 40})
    base.update(study)
    return sc.from_dict({"study": base, "placement": placement},
                        modes=ToyFactory.modes, systems=ToyFactory.systems)


def max_abs_diff(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    fin = ~np.isnan(a)
    return float(np.max(np.abs(a[fin] - b[fin]))) if fin.any() else 0.0



# ----------------------------------------------------------------------------------------------
# Brute force reference (compiled once per policy / metric window)
# ----------------------------------------------------------------------------------------------
@partial(jax.jit, static_argnames=("policy", "metric_window", "recovery", "dt", "mcfg", "seed"))
def _bf_batch(prob, start, length, n_keep, ramp, key_id, *, policy, metric_window, recovery, dt,
              mcfg, seed):
    def one(s, n, k, r, kid):
        return sw.brute_force(
            prob, TOY_OPS, ot.Outage(s, n, k, r), epoch_dt_s=dt, recovery_epochs=recovery,
            mcfg=mcfg, policy=policy, key=sw.scenario_key(seed, kid),
            metric_window=metric_window,
        )

    # Batches of 8 (lax.map) rather than one vmap over every scenario of a realization: the
    # single 256-wide vmap of whole-drive runs stalled XLA:CPU (all threads parked on futexes)
    # in several full-suite runs on 2 cores (jax 0.10.2).
    return jax.lax.map(lambda a: one(*a), (start, length, n_keep, ramp, key_id), batch_size=8)


def brute_force_group(plan, factory, mode, system="cv"):
    """{flat index: (metrics dict, ENU error [T, 3])} for every scenario of a group."""
    cfg = plan.cfg
    flat = np.arange(plan.n_per_group)
    f = plan.scenarios(flat)
    out = {}
    for r in range(len(plan.seeds)):
        prob = factory.build(cfg, mode, system, int(plan.seeds[r]))
        for pi, policy in enumerate(cfg.policies):
            idx = np.flatnonzero((f["realization"] == r) & (f["policy"] == pi))
            m, err = _bf_batch(
                prob, *(jnp.asarray(f[k][idx]) for k in ("start", "length", "n_keep", "ramp",
                                                          "key_id")),
                policy=policy, metric_window=cfg.metric_window, recovery=plan.recovery,
                dt=plan.timeline.epoch_dt_s, mcfg=plan.mcfg, seed=cfg.seed,
            )
            m = {k: np.asarray(v) for k, v in m._asdict().items()}
            err = np.asarray(err)
            for i, fl in enumerate(flat[idx]):
                out[int(fl)] = ({k: v[i] for k, v in m.items()}, err[i])
    return out


def compare_with_brute_force(ds, plan, factory):
    """Largest |engine - brute force| per metric (and for the kept error traces)."""
    worst: dict[str, float] = {}
    n = 0
    for mode in plan.cfg.modes:
        ref = brute_force_group(plan, factory, mode)
        sub = ds.sel(mode=mode, system="cv")
        for k in sw.METRIC_FIELDS:
            eng = sub[k].values.reshape((plan.n_per_group,) + sub[k].shape[len(sw.GROUP_DIMS):])
            bf = np.stack([ref[i][0][k] for i in range(plan.n_per_group)])
            if k == "reconverged":
                np.testing.assert_array_equal(eng, bf)
            else:
                worst[k] = max(worst.get(k, 0.0), max_abs_diff(eng, bf))
        n += plan.n_per_group
        for t in np.flatnonzero(ds.trace_mode.values == mode):
            d = int(np.flatnonzero(plan.duration_s == ds.trace_duration.values[t])[0])
            k = int(np.flatnonzero(plan.n_keep == ds.trace_satellites_kept.values[t])[0])
            r = int(np.flatnonzero(plan.seeds == ds.trace_realization.values[t])[0])
            p = int(ds.trace_placement.values[t])
            fl = int(np.ravel_multi_index((r, d, k, p, 0, 0), plan.shape))
            lo = int(plan.scenarios([fl])["sel"][0]) - plan.prefix
            eng = ds.trace_err_enu_m.values[t]
            bf = ref[fl][1][lo:lo + eng.shape[0]]
            worst["trace"] = max(worst.get("trace", 0.0), max_abs_diff(eng[: bf.shape[0]], bf))
    return worst, n


# ----------------------------------------------------------------------------------------------
# The main sweep (shared by several tests)
# ----------------------------------------------------------------------------------------------
MAIN_STUDY = {"ramps_s": [0, 3], "policies": ["highest", "random"], "realizations": 3}


@pytest.fixture(scope="module")
def main_run(tmp_path_factory, background):
    cfg = toy_config(**MAIN_STUDY)
    factory = ToyFactory()
    res = sw.run_sweep(cfg, factory, tmp_path_factory.mktemp("main") / "out", progress=False)
    return res, cfg, factory, sw.make_plan(cfg, factory.timeline(cfg))


def test_engine_equals_brute_force_whole_drive_runs(main_run):
    res, cfg, factory, plan = main_run
    worst, n = compare_with_brute_force(res.dataset, plan, factory)
    print(f"{n} scenarios vs brute force, max |diff|:",
          {k: f"{v:.1e}" for k, v in worst.items()})
    assert n == 1536 and plan.ckpt_epochs.size == 16  # 8 placements x 2 ramps
    for k, v in worst.items():
        assert v <= 1e-9, (k, v)  # metres, rad, s, % and NEES (all O(1..400))


def test_dataset_layout_and_netcdf_attributes(main_run):
    res, cfg, _, plan = main_run
    ds = sw.load_results(res.path)
    assert tuple(ds.max_2d_m.dims) == sw.DIMS
    assert ds.end_enu_m.dims[-1] == "enu"
    assert ds.sizes["mode"] == 2 and ds.sizes["satellites_kept"] == 4
    assert list(ds.satellites_kept.values) == [0, 1, 2, sw.ALL]
    assert ds.attrs["jaxnav_version"] == jaxnav.__version__
    assert sc.from_json(ds.attrs["config_json"]) == cfg
    assert ds.reconverged.dtype == bool
    np.testing.assert_array_equal(ds.start_s.values[0], np.arange(60, 341, 40))
    xr.testing.assert_identical(ds, res.dataset)
    assert res.stats["full_runs"] == 6  # once per (mode, realization)
    assert res.stats["chunks_computed"] == 2 * 48
    # a chunk of 16 never spans more than 2 of the 3 realizations (768 / 3 per realization)
    assert plan.max_rows == 2 and res.stats["max_realizations_held"] <= 2


def test_outage_errors_follow_the_drive_geometry(main_run):
    """0 satellites: a constant-velocity extrapolation off a circle of radius r drifts by
    r sqrt((th - sin th)^2 + (1 - cos th)^2), th = w tau; on a straight it stays put."""
    ds = main_run[0].dataset.sel(system="cv", policy="highest", ramp=0.0, mode="toy_a")
    r = SPEED / TURN_RATE
    for L in (10.0, 30.0):
        th = TURN_RATE * L  # the last outage epoch is L s after the last GNSS update
        drift = r * math.hypot(th - math.sin(th), 1 - math.cos(th))
        turn = ds.sel(duration=L, satellites_kept=0).isel(placement=3)  # [180, 180 + L)
        assert float(turn.start_s.values) == 180.0
        got = turn.end_2d_m.values
        print(f"L = {L:g} s in the turn: end error {got.round(1)} m vs CV drift {drift:.1f} m")
        np.testing.assert_allclose(got, drift, rtol=0.15)
        # distance: L one-second chords of 10 m (chord/arc - 1 = -(w dt)^2 / 24); 1e-4: the
        # stand-in maps ENU to llh with the scale at LLH0, metrics at the true latitude
        chord = 2 * r * math.sin(TURN_RATE / 2)
        np.testing.assert_allclose(turn.distance_m.values, L * chord, rtol=1e-4)
        # on the straight the model is exact: only the velocity noise drifts (<< curvature)
        straight = ds.sel(duration=L, satellites_kept=0).isel(placement=1)  # [100, 100 + L)
        assert np.all(straight.max_2d_m.values < 0.15 * drift)
    # two ranges fix a 2-D position: no drift over [180, 190); over [180, 210) the kept
    # highest beacon (slot 5) drops out at 200 s and is not replaced (outages' hold rule)
    two = ds.sel(satellites_kept=2).isel(placement=3).max_2d_m
    assert np.all(two.sel(duration=10.0) < 3.0)
    assert np.all(two.sel(duration=30.0) > 10.0)
    assert np.all(ds.sel(satellites_kept="all").max_2d_m < 2.0)


def test_traces_are_the_scenarios_errors(main_run):
    ds = main_run[0].dataset
    plan = main_run[3]
    assert ds.sizes["trace"] == 2 * 5  # max_traces per group
    for t in range(ds.sizes["trace"]):
        tr = ds.isel(trace=t)
        sc_ = ds.sel(mode=tr.trace_mode.item(), system=tr.trace_system.item(),
                     realization=tr.trace_realization.item(), duration=tr.trace_duration.item(),
                     satellites_kept=tr.trace_satellites_kept.item(), policy="highest",
                     ramp=0.0, placement=tr.trace_placement.item())
        time_s = tr.trace_time_s.values
        err = tr.trace_err_enu_m.values
        L = tr.trace_outage_s.item()
        last = np.flatnonzero(time_s == L - 1.0)[0]
        np.testing.assert_array_equal(err[last], sc_.end_enu_m.values)
        inside = (time_s >= 0) & (time_s < L)
        np.testing.assert_allclose(np.max(np.hypot(err[inside, 0], err[inside, 1])),
                                   sc_.max_2d_m.item(), rtol=1e-14)
        valid = ~np.isnan(err[:, 0])
        assert valid.sum() == plan.prefix + L + plan.recovery  # NaN after the recovery period


# ----------------------------------------------------------------------------------------------
# Devices, kill + resume, overwrite rules (subprocesses import this module for the stand-in;
# they start with the module so they overlap with the in-process tests)
# ----------------------------------------------------------------------------------------------
def _script(body: str) -> str:
    return f"import sys\nsys.path.insert(0, {str(HERE)!r})\n" + textwrap.dedent(body)


def _env(**extra):
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    env.update(extra)
    return env


KILL_AFTER = 4  # chunks persisted before the subprocess blocks (and is killed)


def _launch(name, body, tmp, **env):
    out, err = (tmp / f"{name}.out").open("w"), (tmp / f"{name}.err").open("w")
    proc = subprocess.Popen([PYTHON, "-c", _script(body)], env=_env(**env), stdout=out,
                            stderr=err)
    return proc, tmp / f"{name}.out", tmp / f"{name}.err"


@pytest.fixture(scope="module")
def background(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("background")
    sharded = tmp / "sharded"
    killed = tmp / "killed"
    procs = {
        "sharded": _launch("sharded", f"""
            import json
            import jax
            import test_sweep as ts
            from jaxnav.study import sweep as sw
            cfg = ts.toy_config(**ts.MAIN_STUDY, chunk_size=12)  # 3 scenarios per device
            res = sw.run_sweep(cfg, ts.ToyFactory(), {str(sharded)!r}, progress=True)
            print(json.dumps({{"devices": jax.device_count(), "n_devices": res.stats["n_devices"],
                              "shards": res.stats["shards"]}}))
        """, tmp, XLA_FLAGS="--xla_force_host_platform_device_count=4") + (sharded,),
        "killed": _launch("killed", f"""
            import time
            import test_sweep as ts
            from jaxnav.study import sweep as sw
            def hold(g, j):  # block after KILL_AFTER chunks, mid-sweep, until killed
                if j + 1 >= ts.KILL_AFTER:
                    time.sleep(600)
            sw.run_sweep(ts.toy_config(**ts.MAIN_STUDY), ts.ToyFactory(), {str(killed)!r},
                         progress=False, on_chunk=hold)
        """, tmp) + (killed,),
    }
    yield procs
    for proc, *_ in procs.values():
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_four_host_devices_and_other_chunking_give_the_same_dataset(main_run, background):
    proc, stdout, stderr, out = background["sharded"]
    proc.wait(timeout=300)
    assert proc.returncode == 0, stderr.read_text()[-3000:]
    info = json.loads(stdout.read_text().strip().splitlines()[-1])
    assert info == {"devices": 4, "n_devices": 4, "shards": 4}
    err = stderr.read_text()
    assert "1536/1536" in err and "scen/s" in err  # the progress bar
    ds4 = sw.load_results(out / sw.RESULTS_FILE)
    ds1 = main_run[0].dataset
    worst = {k: max_abs_diff(ds4[k].values, ds1[k].values) for k in sw.METRIC_FIELDS
             if k != "reconverged"}
    worst["trace"] = max_abs_diff(ds4.trace_err_enu_m.values, ds1.trace_err_enu_m.values)
    print("4 devices, chunks of 12 vs 1 device, chunks of 16: max |diff|",
          {k: f"{v:.1e}" for k, v in worst.items()})
    assert max(worst.values()) <= 1e-12
    np.testing.assert_array_equal(ds4.reconverged.values, ds1.reconverged.values)


def test_killed_sweep_resumes_to_an_identical_dataset(main_run, background):
    proc, _, stderr, out = background["killed"]
    deadline = time.monotonic() + 300
    while len(list((out / sw.CHUNK_DIR).glob("*.npz"))) < KILL_AFTER:
        assert proc.poll() is None, stderr.read_text()[-3000:]
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)  # mid-sweep: no chance to clean up
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    fresh, cfg, _, plan = main_run  # the same study, run uninterrupted in this process
    n_chunks = 2 * plan.n_chunks
    files = sorted((out / sw.CHUNK_DIR).glob("*.npz"))
    assert len(files) == KILL_AFTER and not (out / sw.RESULTS_FILE).exists()
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files}

    with pytest.raises(FileExistsError, match="unfinished sweep.*resume=True"):
        sw.run_sweep(cfg, ToyFactory(), out, progress=False)
    other = toy_config(modes=["toy_a"], durations_s=[10], satellites_kept=[0, "all"])
    with pytest.raises(FileExistsError, match="different study"):
        sw.run_sweep(other, ToyFactory(), out, resume=True, progress=False)

    resumed = sw.run_sweep(cfg, ToyFactory(), out, resume=True, progress=False)
    assert resumed.stats["chunks_reused"] == len(files)
    assert resumed.stats["chunks_computed"] == n_chunks - len(files)
    for p, (mtime, data) in before.items():  # finished chunks are never rewritten
        assert p.stat().st_mtime_ns == mtime and p.read_bytes() == data

    xr.testing.assert_identical(sw.load_results(resumed.path), sw.load_results(fresh.path))
    assert np.array_equal(resumed.dataset.max_2d_m.values, fresh.dataset.max_2d_m.values)

    # a finished result: never overwritten silently; resume reuses it; overwrite recomputes
    with pytest.raises(FileExistsError, match="overwrite=True"):
        sw.run_sweep(cfg, ToyFactory(), out, progress=False)
    again = sw.run_sweep(cfg, ToyFactory(), out, resume=True, progress=False)
    assert again.stats["chunks_computed"] == 0
    xr.testing.assert_identical(again.dataset, sw.load_results(fresh.path))
    with pytest.raises(sw.StoreError, match="not both"):
        sw.run_sweep(cfg, ToyFactory(), out, resume=True, overwrite=True, progress=False)
    redo = sw.run_sweep(cfg, ToyFactory(), out, overwrite=True, progress=False)
    assert redo.stats["chunks_computed"] == n_chunks
    xr.testing.assert_identical(redo.dataset, sw.load_results(fresh.path))


def test_report_views_of_a_sweep(main_run, tmp_path):
    from jaxnav.study import report as rp

    ds = main_run[0].dataset
    paths = rp.write_report(ds, tmp_path)
    df = rp.table_by_satellites(ds)
    for (mode, dur, k) in [("toy_a", 10.0, 0), ("toy_b", 30.0, sw.ALL)]:
        row = df[(df["mode"] == mode) & (df.duration_s == dur) & (df.satellites_kept == k)]
        ref = ds.max_2d_m.sel(mode=mode, system="cv", duration=dur, satellites_kept=k)
        np.testing.assert_allclose(row["mean"].item(), float(ref.mean()), rtol=1e-12)
        assert row["n"].item() == ref.size
    assert "| all |" in paths["markdown"].read_text()
    assert paths["error_growth"].stat().st_size > 10_000


# ----------------------------------------------------------------------------------------------
# Schedule files, ramps counted as outage, windows cut by the end of the drive
# ----------------------------------------------------------------------------------------------
SCHEDULE = """id,start_s,length_s
a,120,25
b,130,10
c,205,20
end,385,10
"""


def test_second_sweep_in_a_process_with_more_checkpoints(tmp_path):
    """Two sweeps in one process whose compiled shapes agree but whose checkpoint counts differ
    (a wider grid spacing, then a narrower one): the second must not reuse the first's full-run
    scan, whose checkpoint buffer is too short (regression: seed000's 'urban' drive, 13
    placements after 'suburban' 12, scored its last placement from the end-of-drive carry)."""
    factory = ToyFactory()
    grid = {"kind": "grid", "convergence_s": 60}
    few = toy_config(modes=["toy_a"], realizations=1, satellites_kept=[0, "all"],
                     placement={**grid, "spacing_s": 80})
    many = toy_config(modes=["toy_a"], realizations=1, satellites_kept=[0, "all"],
                      placement={**grid, "spacing_s": 40})
    p_few, p_many = (sw.make_plan(c, factory.timeline(c)) for c in (few, many))
    assert p_few.ckpt_epochs.size < p_many.ckpt_epochs.size and p_few.window == p_many.window
    sw.run_sweep(few, factory, tmp_path / "few", progress=False)
    ds = sw.run_sweep(many, factory, tmp_path / "many", progress=False).dataset
    worst, n = compare_with_brute_force(ds, p_many, factory)
    assert n == ds.max_2d_m.size and max(worst.values()) <= 1e-9, worst


def test_schedule_ramps_and_end_of_drive_equal_brute_force(tmp_path):
    (tmp_path / "outages.csv").write_text(SCHEDULE)
    text = textwrap.dedent("""
        [study]
        modes = ["toy_a"]
        systems = ["cv"]
        satellites_kept = [0, 2]
        policies = ["lowest"]
        ramps_s = [2]
        recovery_s = 20
        chunk_size = 8
        max_traces = 2
        metric_window = "with_ramp"
        [placement]
        kind = "schedule"
        file = "outages.csv"
        convergence_s = 60
    """)
    (tmp_path / "study.toml").write_text(text)
    cfg = sc.load(tmp_path / "study.toml", modes=ToyFactory.modes, systems=ToyFactory.systems)
    factory = ToyFactory()
    res = sw.run_sweep(cfg, factory, tmp_path / "out", progress=False)
    ds = res.dataset
    assert list(ds.placement_id.values) == ["a", "b", "c", "end"]
    np.testing.assert_array_equal(ds.length_s.values, [[25.0, 10.0, 20.0, 10.0]])
    assert list(ds.duration.values) == [-1.0]
    plan = sw.make_plan(cfg, factory.timeline(cfg))
    worst, n = compare_with_brute_force(ds, plan, factory)
    print(f"schedule, with_ramp, {n} scenarios: max |diff|",
          {k: f"{v:.1e}" for k, v in worst.items()})
    assert max(worst.values()) <= 1e-9
    # the last window's recovery is cut by the end of the drive (epoch 400): 395 + 2 + 20 > 400
    end = ds.sel(placement=3, satellites_kept=0).squeeze()
    assert np.isfinite(end.max_2d_m) and ds.sel(placement=3).distance_m.min() > 0


# ----------------------------------------------------------------------------------------------
# Study definitions (TOML) and their validation
# ----------------------------------------------------------------------------------------------
EXAMPLE = """
[study]
name = "demo"
modes = ["toy_a", "toy_b"]
systems = ["cv"]
durations_s = [10, 30]
satellites_kept = [0, 1, 2, 3, "all"]
policies = ["highest", "random"]
ramps_s = [0, 2]
realizations = 3
seed = 7
recovery_s = 20
chunk_size = 32
max_traces = 4
metric_window = "with_ramp"

[placement]
kind = "random"
convergence_s = 60
count = 5
min_spacing_s = 20

[metrics]
reconv_threshold_m = 0.5
pre_s = 5

[scenario]
drive = "loop"
speeds = [5, 10]
"""


def _load(text):
    return sc.loads(text, modes=ToyFactory.modes, systems=ToyFactory.systems)


def test_toml_study_definition(tmp_path):
    cfg = _load(EXAMPLE)
    assert cfg.satellites_kept == (0, 1, 2, 3, sw.ALL)
    assert cfg.durations_s == (10.0, 30.0) and cfg.ramps_s == (0.0, 2.0)
    assert cfg.realization_seeds == (7, 8, 9)
    assert cfg.placement.kind == "random" and cfg.placement.count == 5
    assert cfg.metrics.reconv_threshold_m == 0.5 and cfg.metrics.pre_s == 5.0
    assert cfg.metrics.reconv_factor == sc.MetricsConfig().reconv_factor
    assert cfg.scenario_dict == {"drive": "loop", "speeds": [5, 10]}
    assert sc.from_json(cfg.to_json()) == cfg
    assert cfg.hash() == _load(EXAMPLE.replace("[scenario]", "# same\n[scenario]")).hash()
    assert cfg.hash() != cfg.replace(seed=8).hash()
    assert cfg.hash() != _load(EXAMPLE.replace('"loop"', '"city"')).hash()
    plan = sw.make_plan(cfg, ToyFactory().timeline(cfg))
    assert plan.shape == (3, 2, 5, 5, 2, 2) and plan.prefix == 5
    assert plan.window == 30 + 2 * 2 + 20
    assert np.all(np.diff(plan.starts[0]) >= 20) and plan.starts.min() >= 60


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('satellites_kept = [0, 1, 2, 3, "all"]', 'satellites_kept = [0, 1, "most"]',
         r"study\.satellites_kept\[2\] = 'most': expected a whole number >= 0 or \"all\""),
        ('modes = ["toy_a", "toy_b"]', 'modes = ["toy_a", "gps_ppp"]',
         r"study\.modes\[1\] = 'gps_ppp': expected one of 'toy_a', 'toy_b'"),
        ('policies = ["highest", "random"]', 'policies = ["nearest"]',
         r"study\.policies\[0\] = 'nearest': expected one of 'highest', 'lowest'"),
        ("durations_s = [10, 30]", "duration_s = [10, 30]",
         r"unknown key study\.duration_s .*allowed keys in \[study\]: name, modes"),
        ("durations_s = [10, 30]", "durations_s = [10, -5]",
         r"study\.durations_s\[1\] = -5: expected a number of seconds > 0"),
        ("durations_s = [10, 30]", "durations_s = [10, 10]",
         r"study\.durations_s\[1\] = 10: expected distinct values"),
        ("chunk_size = 32", "chunk_size = 0", r"study\.chunk_size = 0: expected a whole"),
        ("realizations = 3", "realizations = 2.5", r"study\.realizations = 2\.5"),
        ('metric_window = "with_ramp"', 'metric_window = "full"',
         r"study\.metric_window = 'full': expected one of 'core', 'with_ramp'"),
        ('kind = "random"', 'kind = "spiral"',
         r"placement\.kind = 'spiral': expected one of 'grid', 'random', 'events'"),
        ('kind = "random"', 'kind = "grid"',
         r"placement\.count = 5: expected no value: it is used only by kind 'random'"),
        ("pre_s = 5", 'pre_s = "ten"', r"metrics\.pre_s = 'ten': expected a number of"),
        ("[scenario]", "[output]", r"unknown section or key \[output\]"),
        ('kind = "random"', 'kind = "schedule"', r"placement\.file = None: expected a sched"),
        ("[study]", "[study\n", r"not valid TOML"),
    ],
)
def test_invalid_definitions_name_the_key_value_and_what_is_allowed(old, new, message):
    assert old in EXAMPLE
    with pytest.raises(sc.ConfigError, match=message):
        _load(EXAMPLE.replace(old, new))


def test_plan_errors_and_rejection_before_any_work(tmp_path):
    factory = ToyFactory()
    with pytest.raises(sc.ConfigError, match=r"study\.durations_s\[0\] = 10\.5: expected a "
                                             r"whole number of 1\.0 s epochs"):
        sw.make_plan(toy_config(durations_s=[10.5]), factory.timeline(None))
    too_long = toy_config(placement={"kind": "grid", "convergence_s": 390})
    with pytest.raises(sc.ConfigError, match=r"no outage fits in the 400-epoch"):
        sw.make_plan(too_long, factory.timeline(None))
    with pytest.raises(sc.ConfigError, match="no event labels"):
        sw.make_plan(toy_config(placement={"kind": "events"}), sw.Timeline(400, 1.0))
    bad = sc.from_dict({"study": {"modes": ["toy_c"], "systems": ["cv"]}})  # no allowed list
    out = tmp_path / "never"
    with pytest.raises(sc.ConfigError, match=r"study\.modes\[0\] = 'toy_c'"):
        sw.run_sweep(bad, factory, out, progress=False)
    assert not out.exists()  # rejected before any work


def test_event_placement_centres_every_duration_on_the_event():
    cfg = toy_config(placement={"kind": "events", "events": ["turn", "straight"],
                                "convergence_s": 60})
    plan = sw.make_plan(cfg, ToyFactory().timeline(cfg))
    # labels: straight [0, 150), turn [150, 270), straight [270, 400)
    assert plan.placement_event == ("straight", "turn", "straight")
    centre = plan.starts + plan.lengths // 2
    np.testing.assert_array_equal(centre[0], centre[1])
    turn = plan.starts[:, 1]
    assert np.all(turn >= 150) and np.all(turn + plan.lengths[:, 1] <= 270)


def test_resume_refuses_chunks_of_other_jaxnav_code(main_run, tmp_path):
    """The config hash includes a hash of jaxnav's source files: a sweep started by other code
    is never resumed into the same dataset (the study itself unchanged)."""
    import shutil

    fresh, cfg, _, _ = main_run
    out = tmp_path / "sweep"
    shutil.copytree(Path(fresh.path).parent, out)
    manifest_path = out / sw.MANIFEST_FILE
    manifest = json.loads(manifest_path.read_text())
    assert manifest["jaxnav_source"] == sw.source_hash() and len(sw.source_hash()) == 16
    manifest["jaxnav_source"] = "0" * 16
    manifest["config_hash"] = "f" * 64
    manifest_path.write_text(json.dumps(manifest))
    with pytest.raises(FileExistsError, match="other jaxnav code"):
        sw.run_sweep(cfg, ToyFactory(), out, resume=True, progress=False)


def test_damaged_store_is_explained_before_any_work(tmp_path):
    """Issue 23: on resume every existing chunk is checked before any is computed (a zero-length
    or foreign chunk is named at once); a truncated results.nc is rebuilt from complete chunks;
    a truncated manifest.json is rewritten when every chunk is this study's, else refused."""
    import shutil

    factory = ToyFactory()
    cfg = toy_config(modes=["toy_a"], realizations=1, satellites_kept=[0, "all"])
    fresh = sw.run_sweep(cfg, factory, tmp_path / "fresh", progress=False)
    n_chunks = len(list((tmp_path / "fresh" / sw.CHUNK_DIR).glob("*.npz")))
    assert n_chunks >= 2

    def partial(name):  # a copy killed after its first chunk
        out = tmp_path / name
        shutil.copytree(tmp_path / "fresh", out)
        (out / sw.RESULTS_FILE).unlink()
        for p in sorted((out / sw.CHUNK_DIR).glob("*.npz"))[1:]:
            p.unlink()
        return out

    computed = []
    zero = partial("zero")
    first = sorted((zero / sw.CHUNK_DIR).glob("*.npz"))[0]
    first.write_bytes(b"")
    with pytest.raises(sw.StoreError, match=rf"{first.name}: cannot read the chunk.*delete it"):
        sw.run_sweep(cfg, factory, zero, resume=True, progress=False,
                     on_chunk=lambda g, j: computed.append((g, j)))
    assert computed == []  # found before any work

    other = toy_config(modes=["toy_a"], realizations=1, satellites_kept=[0, 1, "all"])
    sw.run_sweep(other, factory, tmp_path / "other", progress=False)
    foreign = partial("foreign")
    victim = sorted((foreign / sw.CHUNK_DIR).glob("*.npz"))[0]
    shutil.copy(tmp_path / "other" / sw.CHUNK_DIR / victim.name, victim)
    with pytest.raises(sw.StoreError, match=rf"{victim.name}: not chunk 0 of group 0"):
        sw.run_sweep(cfg, factory, foreign, resume=True, progress=False)

    trunc = tmp_path / "trunc"
    shutil.copytree(tmp_path / "fresh", trunc)
    nc = trunc / sw.RESULTS_FILE
    nc.write_bytes(nc.read_bytes()[:200])
    with pytest.warns(UserWarning, match="unreadable.*rebuilding it from its chunks"):
        rebuilt = sw.run_sweep(cfg, factory, trunc, resume=True, progress=False)
    assert rebuilt.stats["chunks_computed"] == 0
    xr.testing.assert_identical(sw.load_results(nc), sw.load_results(fresh.path))
    nc.write_bytes(nc.read_bytes()[:200])
    next(iter((trunc / sw.CHUNK_DIR).glob("*.npz"))).unlink()
    with pytest.raises(sw.StoreError, match="unreadable.*1 chunk\\(s\\) are missing"):
        sw.run_sweep(cfg, factory, trunc, resume=True, progress=False)

    cut = partial("cut")
    manifest = cut / sw.MANIFEST_FILE
    manifest.write_text(manifest.read_text()[:50])
    with pytest.warns(UserWarning, match="manifest.json is damaged.*written again"):
        resumed = sw.run_sweep(cfg, factory, cut, resume=True, progress=False)
    assert resumed.stats["chunks_reused"] == 1
    xr.testing.assert_identical(sw.load_results(resumed.path), sw.load_results(fresh.path))
    mixed = partial("mixed")
    shutil.copy(tmp_path / "other" / sw.CHUNK_DIR / victim.name,
                sorted((mixed / sw.CHUNK_DIR).glob("*.npz"))[0])
    (mixed / sw.MANIFEST_FILE).write_text("{")
    with pytest.raises(sw.StoreError, match="damaged.*do not all carry this study's hash"):
        sw.run_sweep(cfg, factory, mixed, resume=True, progress=False)


# ----------------------------------------------------------------------------------------------
# smooth = true (issue 21)
# ----------------------------------------------------------------------------------------------
def test_smoothed_sweep_adds_a_solution_axis(tmp_path):
    """``smooth = true``: every metric gets a ``solution`` axis. Its forward slice is the study
    without smoothing, bit for bit; the smoothed solution equals the forward one at the last
    valid epoch of each scenario (the RTS end condition: the smoother sees nothing after its
    recovery period) and bridges complete outages far better; the report writes both
    solutions' tables and plots."""
    from jaxnav.study import report as rp

    factory = ToyFactory()
    kw = dict(modes=["toy_a"], realizations=1, satellites_kept=[0, "all"])
    plain = sw.run_sweep(toy_config(**kw), factory, tmp_path / "plain", progress=False).dataset
    ds = sw.run_sweep(toy_config(smooth=True, **kw), factory, tmp_path / "smooth",
                      progress=False).dataset
    assert list(ds.solution.values) == ["forward", "smoothed"]
    assert ds.max_2d_m.dims == sw.DIMS + ("solution",)
    assert ds.end_enu_m.dims == sw.DIMS + ("solution", "enu")
    for k in sw.METRIC_FIELDS:
        np.testing.assert_array_equal(ds[k].sel(solution="forward").values, plain[k].values)
    np.testing.assert_array_equal(ds.trace_err_enu_m.sel(solution="forward").values,
                                  plain.trace_err_enu_m.values)
    tr = ds.trace_err_enu_m
    for t in range(ds.sizes["trace"]):
        fwd, smo = tr.values[t, 0], tr.values[t, 1]
        last = np.flatnonzero(np.isfinite(fwd[:, 0]))[-1]
        np.testing.assert_allclose(smo[last], fwd[last], rtol=0, atol=1e-9)
        assert np.nanmax(np.abs(smo[:last] - fwd[:last])) > 1e-3  # smoothed before it
    out = ds.max_2d_m.sel(satellites_kept=0)
    f, s = out.sel(solution="forward").values, out.sel(solution="smoothed").values
    print(f"complete outages, mean max 2D: forward {f.mean():.2f} m, smoothed {s.mean():.2f} m")
    assert s.mean() < 0.5 * f.mean()
    paths = rp.write_report(ds, tmp_path / "report")
    text = paths["markdown"].read_text()
    assert "## Forward filter" in text and "## Smoothed (forward + RTS smoother)" in text
    csv_text = paths["by_satellites_csv"].read_text()
    assert csv_text.startswith("solution,") and "\nsmoothed,cv," in csv_text
    for key in ("error_growth", "error_growth_smoothed", "by_satellites_smoothed"):
        assert paths[key].stat().st_size > 10_000, key


def test_smoothed_metrics_do_not_depend_on_the_other_durations(tmp_path):
    """A 10-s outage is smoothed with its own recovery period, whatever else the study holds:
    with 10 and 30 s durations (window sized for 30 s) its smoothed metrics equal those of the
    10-s-only study (the backward pass is cut at the scenario's last valid epoch; review
    finding: without the cut it saw 20 s more of later data)."""
    factory = ToyFactory()
    # 2 s of recovery: the stand-in's six beacons pin the position at once after an outage, so
    # only the first seconds of later data move the smoothed outage
    kw = dict(modes=["toy_a"], realizations=1, satellites_kept=[0, 2], smooth=True,
              recovery_s=2)
    both = sw.run_sweep(toy_config(durations_s=[10, 30], **kw), factory, tmp_path / "both",
                        progress=False).dataset.sel(duration=10.0)
    one = sw.run_sweep(toy_config(durations_s=[10], **kw), factory, tmp_path / "one",
                       progress=False).dataset.sel(duration=10.0)
    n = min(both.sizes["placement"], one.sizes["placement"])  # 30 s fit fewer placements
    both, one = both.isel(placement=slice(0, n)), one.isel(placement=slice(0, n))
    np.testing.assert_array_equal(both.start_s.values, one.start_s.values)
    for k in ("max_2d_m", "rms_2d_m", "end_2d_m", "nees_pos"):
        np.testing.assert_allclose(both[k].values, one[k].values, rtol=1e-9, atol=1e-12)


def test_smooth_needs_a_filter_with_a_smoother(tmp_path):
    """A group whose FilterOps has no smoother is refused before any
    work, naming the key."""

    class NoSmoother(ToyFactory):
        ops = TOY_OPS._replace(smooth=None)

    with pytest.raises(sc.ConfigError, match="study.smooth = true.*'toy_a' / 'cv'"):
        sw.run_sweep(toy_config(smooth=True, modes=["toy_a"], realizations=1), NoSmoother(),
                     tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()


def test_traces_start_with_run_0_then_span_the_runs():
    """Trace picks: run 0 (realization 0, placement 0) of every duration and level first (the
    earlier selection, so studies sized for it keep their traces), then the other runs, for
    the error-growth plot's median and band."""
    factory = ToyFactory()
    cfg = toy_config(**MAIN_STUDY)
    plan = sw.make_plan(cfg, factory.timeline(cfg))
    n_real, n_dur, n_keep, n_place, _, _ = plan.shape
    first = n_dur * n_keep
    small = sw.make_plan(cfg.replace(max_traces=first), factory.timeline(cfg))
    r, d, k, p, pol, ramp = np.unravel_index(small.trace_flat, plan.shape)
    assert small.trace_flat.size == first and not r.any() and not p.any()
    assert sorted(zip(d, k, strict=True)) == [(i, j) for i in range(n_dur) for j in range(n_keep)]
    big = sw.make_plan(cfg.replace(max_traces=10**6), factory.timeline(cfg))
    r, d, k, p, pol, ramp = np.unravel_index(big.trace_flat, plan.shape)
    assert big.trace_flat.size == n_real * n_dur * n_keep * n_place  # every run, policy / ramp 0
    assert not pol.any() and not ramp.any()
    assert len(set(zip(r, p, strict=True))) == n_real * n_place


def test_results_follow_cf_conventions(main_run):
    """results.nc (read back from disk): the Conventions attribute, long_name and units on every
    variable (CF flags on booleans), and a coordinate for every dimension, the trace ones
    included (a CF checker is not among the installed packages: the attributes it requires)."""
    from jaxnav.study import store

    res = main_run[0]
    ds = store.load_results(res.path)
    assert ds.attrs["Conventions"].startswith("CF-1.")
    assert {"title", "source", "references"} <= set(ds.attrs)
    for name, var in ds.variables.items():
        assert var.attrs.get("long_name"), name
        if var.dtype.kind in "fiu" and name not in ("reconverged",):
            assert "units" in var.attrs, name
    assert ds["reconverged"].attrs["flag_meanings"] == "false true"
    assert ds["max_2d_m"].attrs["units"] == "m"
    assert ds["pct_of_distance"].attrs["units"] == "percent"
    for dim in ds.dims:
        assert dim in ds.coords, dim
    assert ds.sizes["trace"] > 0 and list(ds.trace_epoch.values[:3]) == [0, 1, 2]
