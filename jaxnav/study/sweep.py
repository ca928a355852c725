"""The vectorised Monte-Carlo outage sweep: checkpointed, chunked, sharded, resumable.

Exactness and cost. The filter is deterministic and causal, so an outage scenario's run is the
full-availability run up to the epoch where its mask first differs, the selection epoch
c = start - ramp. Per (mode, system, realization) the engine therefore

1. runs the full-availability filter once over the drive, keeping its carry only at the sorted
   distinct candidate epochs c (a ``lax.scan`` that writes the carry into a preallocated
   [n_ckpt + 1] buffer at every epoch, at index ``slot[t]``; epochs that are no candidate write
   to the spare last row, so the buffer never grows and no copy is made);
2. evaluates every scenario as the filter run over a fixed window of
   W = max length + 2 max ramp + recovery epochs started from its checkpoint, its inputs cut out
   with ``lax.dynamic_slice`` (shapes never depend on the scenario), its availability mask the
   outage mask of ``jaxnav.study.outages.keep_mask`` on that window. Scenarios are ``vmap``-ped
   within a device and sharded over the local devices (``jax.shard_map`` on a 1-D mesh).

The metrics (``jaxnav.study.metrics.window_metrics``) see a record of the P pre-outage epochs
of the full run (P = pre-outage averaging epochs, at least 1 for the distance's first chord)
followed by the window; epochs after the recovery period (or the end of the drive) are masked
with ``n_valid``. The result equals the brute-force run of the whole drive with the outage
mask (``brute_force`` here; tests compare them).

Chunks and memory. The scenarios of one (mode, system) group are flattened in C order over
(realization, duration, satellites_kept, placement, policy, ramp) and cut into chunks of
``chunk_size`` (the last one padded by repeating its last scenario, so every chunk has one
compiled shape). A chunk holds on the devices only the realizations it touches (at most
(chunk_size - 1) // per_realization + 2), so memory is bounded by the chunk size, not by the
number of scenarios. Completed chunks are written atomically to ``OUT/chunks/`` (one .npz
each) beside ``OUT/manifest.json`` (config hash); ``resume=True`` reuses them, so a killed
sweep resumes and yields an identical dataset (chunk shapes and order are fixed by the config,
and XLA on one device count is deterministic). Nothing is silently overwritten.

Documented choices:
- Random-policy keys: fold_in(key(seed), id), id the flat index over (realization, duration,
  placement, ramp), so the random draw is the same for every mode, system and number of
  satellites kept (nested kept sets, comparable modes).
- Placements are shared by all realizations and (for grid / random) all durations; with
  ``events`` each duration's window is centred where the longest one is. Every window leaves
  ``placement.convergence_s`` (at least P + max ramp epochs) before it and max ramp + recovery
  after it (schedule files: only the first).
- Metric window ``core``: the outage proper [start, start + length); the ramps before and after
  count as recovery / pre-outage. ``with_ramp``: [start - ramp, start + length + ramp).
- Per-epoch ENU error traces are kept for at most ``max_traces`` scenarios per group (for the
  error-growth plot): realization 0, placement 0, first policy and ramp, every satellites-kept
  level at the longest duration first.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
import warnings
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as Spec
from tqdm.auto import tqdm

import jaxnav
from jaxnav import geodesy
from jaxnav.core.ops import FilterOps
from jaxnav.sim.constellation import DEFAULT_ELEVATION_MASK_RAD
from jaxnav.sim.trajectory import Event
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study.config import ALL, ConfigError, StudyConfig, validate

#: Dimensions of every per-scenario variable, in order.
DIMS = (
    "mode", "system", "realization", "duration", "satellites_kept", "placement", "policy", "ramp"
)
GROUP_DIMS = DIMS[2:]  # the flattened axes within one (mode, system) group
RESULTS_FILE = "results.nc"
MANIFEST_FILE = "manifest.json"
CHUNK_DIR = "chunks"
METRIC_FIELDS = mt.WindowMetrics._fields
_UNITS = {
    "max_2d_m": "m", "rms_2d_m": "m", "max_3d_m": "m", "end_2d_m": "m", "end_enu_m": "m",
    "distance_m": "m", "pct_of_distance": "%", "max_azimuth_err_rad": "rad",
    "pre_2d_rms_m": "m", "reconv_threshold_m": "m", "reconv_s": "s", "reconverged": "1",
    "nees_pos": "1", "nees_posvel": "1",
}


# ----------------------------------------------------------------------------------------------
# What the engine needs from a filter and a scenario builder
# ----------------------------------------------------------------------------------------------
@functools.cache
def tight_ops() -> FilterOps:
    """FilterOps of ``jaxnav.filter.tight`` (EpochInput.keep, EpochOutput llh/vel/euler/P_nav)."""
    from jaxnav.filter import tight

    return FilterOps(
        run=tight.run,
        readout=lambda out: (mt.track(out.llh, out.vel_enu, out.euler), out.P_nav),
        get_keep=lambda inp: inp.keep,
        with_keep=lambda inp, keep: inp._replace(keep=keep),
    )


class Timeline(NamedTuple):
    """The drive's epoch grid (shared by every mode, system and realization)."""

    n_epochs: int
    epoch_dt_s: float
    labels: np.ndarray | None = None  # [T] sim.trajectory.Event codes (for event placement)


class Problem(NamedTuple):
    """One (mode, system, realization): a filter, its start and the drive's stacked inputs."""

    tf: Any  # filter configuration (arrays + static fields), first argument of ops.run
    carry0: Any  # initial carry
    inputs: Any  # [T, ...] every leaf stacked over epochs; full availability in its keep
    truth: mt.Track  # [T] true llh / vel_enu / azimuth at the epochs
    elevation: Any  # [T, S] rad (for the selection policies)
    available: Any  # [T, S] bool: slot tracked
    azimuth: Any = None  # [T, S] rad (needed by the geometry policies)
    elevation_mask_rad: float = DEFAULT_ELEVATION_MASK_RAD


class SweepResult(NamedTuple):
    dataset: xr.Dataset
    path: Path  # OUT/results.nc
    stats: dict  # timings (compile separately), devices, chunks computed / reused, ...


def scenario_key(seed: int, key_id):
    """PRNG key of a scenario's random selection policy: fold_in(key(seed), key_id)."""
    return jax.random.fold_in(jax.random.key(seed), key_id)


# ----------------------------------------------------------------------------------------------
# The scenario grid (host side)
# ----------------------------------------------------------------------------------------------
class Plan(NamedTuple):
    """The study grid in epochs, the checkpoints and the window geometry."""

    cfg: StudyConfig
    timeline: Timeline
    duration_s: np.ndarray  # [D] coordinate (-1: lengths from a schedule file)
    starts: np.ndarray  # [D, Pl] outage start epochs
    lengths: np.ndarray  # [D, Pl] outage lengths [epochs]
    n_keep: np.ndarray  # [K] (ALL = -1: no outage)
    ramps: np.ndarray  # [Rm] ramp lengths [epochs]
    seeds: np.ndarray  # [R] realization seeds
    placement_event: tuple[str, ...] | None  # [Pl] event label (events placement)
    placement_id: tuple[str, ...] | None  # [Pl] schedule ids (schedule placement)
    ckpt_epochs: np.ndarray  # [n_ckpt] sorted distinct selection epochs start - ramp
    ckpt_index: np.ndarray  # [D, Pl, Rm] index into ckpt_epochs
    window: int  # W: filter epochs evaluated per scenario
    prefix: int  # P: full-run epochs before the window in the metric record
    recovery: int  # epochs kept after the outage (and its ramp)
    mcfg: mt.MetricConfig
    trace_flat: np.ndarray  # sorted flat indices (within a group) whose traces are kept

    @property
    def shape(self) -> tuple[int, ...]:
        """Group shape over GROUP_DIMS."""
        return (
            len(self.seeds), self.starts.shape[0], len(self.n_keep), self.starts.shape[1],
            len(self.cfg.policies), len(self.ramps),
        )

    @property
    def n_per_group(self) -> int:
        return int(np.prod(self.shape))

    @property
    def n_chunks(self) -> int:
        return -(-self.n_per_group // self.cfg.chunk_size)

    @property
    def per_realization(self) -> int:
        return self.n_per_group // len(self.seeds)

    @property
    def max_rows(self) -> int:
        """Realizations a chunk can touch (bounds the chunk's device memory)."""
        return min(len(self.seeds), (self.cfg.chunk_size - 1) // self.per_realization + 2)

    def scenarios(self, flat) -> dict[str, np.ndarray]:
        """Integer fields of the scenarios at the given flat indices of a group."""
        flat = np.asarray(flat, np.int64)
        r, d, k, p, pol, rm = np.unravel_index(flat, self.shape)
        start = self.starts[d, p]
        ramp = self.ramps[rm]
        R, D, _, Pl, _, Rm = self.shape
        return {
            "realization": r, "start": start, "length": self.lengths[d, p],
            "n_keep": self.n_keep[k], "ramp": ramp, "sel": start - ramp,
            "ckpt": self.ckpt_index[d, p, rm], "policy": pol,
            "key_id": np.ravel_multi_index((r, d, p, rm), (R, D, Pl, Rm)),
        }


def _epochs(key: str, seconds: float, dt: float) -> int:
    q = float(seconds) / dt
    r = round(q)
    if abs(q - r) > 1e-6:
        raise ConfigError(f"{key} = {seconds!r}: expected a whole number of {dt} s epochs")
    return int(r)


def make_plan(cfg: StudyConfig, timeline: Timeline) -> Plan:
    """Outage starts, lengths, checkpoints and window length of a study on a drive."""
    dt, T = float(timeline.epoch_dt_s), int(timeline.n_epochs)
    pl = cfg.placement
    prefix = max(_epochs("metrics.pre_s", cfg.metrics.pre_s, dt), 1)
    ramps = np.array(
        [_epochs(f"study.ramps_s[{i}]", s, dt) for i, s in enumerate(cfg.ramps_s)], np.int64
    )
    rmax = int(ramps.max())
    recovery = _epochs("study.recovery_s", cfg.recovery_s, dt)
    conv = max(_epochs("placement.convergence_s", pl.convergence_s, dt), prefix + rmax)
    event_names = ids = None
    if pl.kind == "schedule":
        try:
            sched = ot.read_schedule(pl.file)
            s0, l0 = ot.schedule_to_epochs(sched, dt, T)
        except ValueError as e:
            raise ConfigError(f"placement.file = {pl.file!r}: {e}") from None
        early = np.flatnonzero(s0 < prefix + rmax)
        if early.size:
            i = int(early[0])
            raise ConfigError(
                f"placement.file = {pl.file!r}: outage {sched.id[i]!r} starts at "
                f"{sched.start_s[i]} s; expected >= {(prefix + rmax) * dt} s (pre-outage "
                f"metric epochs + the longest ramp)"
            )
        starts, lengths = s0[None, :], l0[None, :]
        duration_s = np.array([-1.0])
        ids = tuple(sched.id)
    else:
        lens = np.array(
            [_epochs(f"study.durations_s[{i}]", s, dt) for i, s in enumerate(cfg.durations_s)],
            np.int64,
        )
        lmax = int(lens.max())
        tail = rmax + recovery
        try:
            if pl.kind == "grid":
                spacing = _epochs("placement.spacing_s", pl.spacing_s, dt)
                s0 = ot.grid_starts(T, lmax, max(spacing, 1), convergence_epochs=conv,
                                    tail_epochs=tail)
            elif pl.kind == "random":
                s0 = ot.random_starts(
                    T, lmax, pl.count, cfg.seed,
                    min_spacing=_epochs("placement.min_spacing_s", pl.min_spacing_s, dt),
                    convergence_epochs=conv, tail_epochs=tail,
                )
            else:  # events
                if timeline.labels is None:
                    raise ConfigError(
                        "placement.kind = 'events': the scenario factory gives no event labels"
                    )
                ev = ot.event_starts(
                    timeline.labels, lmax, [Event[n.upper()] for n in pl.events],
                    min_spacing=_epochs("placement.min_spacing_s", pl.min_spacing_s, dt),
                    convergence_epochs=conv, tail_epochs=tail,
                    min_event_epochs=max(_epochs("placement.min_event_s", pl.min_event_s, dt),
                                         1),
                    max_per_event=pl.max_per_event,
                )
                s0 = ev.start
                event_names = tuple(Event(int(c)).name.lower() for c in ev.event)
        except ValueError as e:
            if isinstance(e, ConfigError):
                raise
            raise ConfigError(f"placement ({pl.kind}): {e}") from None
        s0 = np.asarray(s0, np.int64)
        if pl.kind == "events":  # centre every duration where the longest window is centred
            starts = (s0 + lmax // 2)[None, :] - (lens // 2)[:, None]
        else:
            starts = np.broadcast_to(s0, (lens.size, s0.size)).copy()
        lengths = np.broadcast_to(lens[:, None], starts.shape).copy()
        duration_s = np.asarray(cfg.durations_s, float)
    if starts.shape[1] == 0:
        raise ConfigError(
            f"placement ({pl.kind}): no outage fits in the {T}-epoch ({T * dt:g} s) drive after "
            f"convergence_s = {pl.convergence_s:g} s with the longest outage, ramps and "
            f"recovery_s = {cfg.recovery_s:g} s"
        )
    sel = starts[:, :, None] - ramps[None, None, :]
    ckpt_epochs, inv = np.unique(sel, return_inverse=True)
    ckpt_index = inv.reshape(sel.shape).astype(np.int64)
    window = int(lengths.max()) + 2 * rmax + recovery
    mcfg = mt.MetricConfig(
        reconv_threshold_m=cfg.metrics.reconv_threshold_m,
        reconv_factor=cfg.metrics.reconv_factor,
        pre_epochs=prefix,
        min_distance_m=cfg.metrics.min_distance_m,
    )
    n_keep = np.asarray(cfg.satellites_kept, np.int64)
    plan = Plan(
        cfg, timeline, duration_s, starts, lengths, n_keep, ramps,
        np.asarray(cfg.realization_seeds, np.int64), event_names, ids, ckpt_epochs, ckpt_index,
        window, prefix, recovery, mcfg, np.zeros(0, np.int64),
    )
    # Traces: realization 0, placement 0, first policy / ramp; longest duration first.
    order = np.argsort(-plan.lengths[:, 0], kind="stable")
    picks = [
        np.ravel_multi_index((0, d, k, 0, 0, 0), plan.shape)
        for d in order for k in range(len(n_keep))
    ][: cfg.max_traces]
    return plan._replace(trace_flat=np.sort(np.asarray(picks, np.int64)))


# ----------------------------------------------------------------------------------------------
# Device functions
# ----------------------------------------------------------------------------------------------
class _Context(NamedTuple):
    """The realizations a chunk touches, stacked on a leading row axis [M, ...]."""

    tf_dyn: Any  # array leaves of the filter configuration
    carries: Any  # [M, n_ckpt, ...] checkpointed carries
    inputs: Any  # [M, T + W, ...] inputs, padded at the end
    track: mt.Track  # [M, T] full-availability solution
    truth: mt.Track  # [M, T + W]
    elevation: Any  # [M, T + W, S]
    available: Any
    azimuth: Any


class _Batch(NamedTuple):
    row: Any
    ckpt: Any
    sel: Any
    start: Any
    length: Any
    n_keep: Any
    ramp: Any
    policy: Any
    key_id: Any


def _window(a, row, start, n):
    """a[row, start:start + n] with traced row / start (one gather under vmap)."""
    idx = (row, start) + (0,) * (a.ndim - 2)
    return jax.lax.dynamic_slice(a, idx, (1, n) + a.shape[2:])[0]


def _keep_fn(policies, elevation_mask_rad, el, av, az, outage, key, pidx):
    fns = [
        partial(ot.keep_mask, policy=p, azimuth=az, elevation_mask_rad=elevation_mask_rad)
        for p in policies
    ]
    if len(fns) == 1:
        return fns[0](el, av, outage, key)
    return jax.lax.switch(pidx, [lambda f=f: f(el, av, outage, key) for f in fns])


class _Static(NamedTuple):
    """Everything static about a group's evaluation (closed over by the compiled functions)."""

    tf_static: Any
    ops: FilterOps
    policies: tuple[str, ...]
    seed: int
    elevation_mask_rad: float
    n_epochs: int
    window: int
    prefix: int
    recovery: int
    epoch_dt_s: float
    mcfg: mt.MetricConfig
    with_ramp: bool


def _record_metrics(st: _Static, est_rec, truth_rec, P_rec, start, length, ramp, sel):
    P = st.prefix
    if st.with_ramp:
        m_start, m_len = P, length + 2 * ramp
    else:
        m_start, m_len = P + ramp, length
    n_valid = jnp.minimum(P + 2 * ramp + length + st.recovery, P + st.n_epochs - sel)
    m = mt.window_metrics(est_rec, truth_rec, P_rec, m_start, m_len, st.epoch_dt_s, st.mcfg,
                          n_valid)
    err = mt.enu_errors(est_rec.llh, truth_rec.llh)
    err = jnp.where((jnp.arange(err.shape[0]) < n_valid)[:, None], err, jnp.nan)
    return m, err


def _one_scenario(st: _Static, ctx: _Context, s: _Batch):
    W, P = st.window, st.prefix
    tf = eqx.combine(jax.tree.map(lambda a: a[s.row], ctx.tf_dyn), st.tf_static)
    carry = jax.tree.map(lambda a: a[s.row, s.ckpt], ctx.carries)
    inp = jax.tree.map(lambda a: _window(a, s.row, s.sel, W), ctx.inputs)
    el, av, az = (_window(a, s.row, s.sel, W) for a in (ctx.elevation, ctx.available, ctx.azimuth))
    outage = ot.Outage(s.start - s.sel, s.length, s.n_keep, s.ramp)
    key = scenario_key(st.seed, s.key_id)
    mask = _keep_fn(st.policies, st.elevation_mask_rad, el, av, az, outage, key, s.policy)
    inp = st.ops.with_keep(inp, st.ops.get_keep(inp) & mask)
    _, out = st.ops.run(tf, carry, inp)
    est, P_nav = st.ops.readout(out)
    pre = jax.tree.map(lambda a: _window(a, s.row, s.sel - P, P), ctx.track)
    est_rec = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pre, est)
    truth_rec = jax.tree.map(lambda a: _window(a, s.row, s.sel - P, P + W), ctx.truth)
    P_rec = None
    if P_nav is not None:  # the prefix's covariance is never used (NEES is over the window)
        k = P_nav.shape[-1]
        P_rec = jnp.concatenate([jnp.broadcast_to(jnp.eye(k), (P, k, k)), P_nav])
    return _record_metrics(st, est_rec, truth_rec, P_rec, s.start, s.length, s.ramp, s.sel)


def _make_evaluate(st: _Static, mesh: Mesh):
    local = jax.vmap(partial(_one_scenario, st), in_axes=(None, 0))
    if mesh.devices.size == 1:
        # One device: a plain vmap. (A one-device shard_map adds nothing, and a demo run on the
        # CPU once stalled inside it with no CPU use.)
        return jax.jit(local)
    sharded = jax.shard_map(
        local, mesh=mesh, in_specs=(Spec(), Spec("batch")), out_specs=Spec("batch"),
        check_vma=False,
    )
    return jax.jit(sharded)


# Compiled functions are reused across groups and sweeps of one process when the static
# configuration, the argument shapes and the devices agree (e.g. a demo then a config sweep, or
# a resume in the same session). Small LRU: each entry holds an XLA executable.
_COMPILED: list[tuple[tuple, _Static, Any]] = []
_COMPILED_MAX = 16


def _compiled(kind: str, st: _Static, build: Callable, args: tuple, devices: tuple, stats,
              extra_key: tuple = ()):
    """The compiled ``build()`` for these argument shapes, from the cache when ``kind``, the
    static configuration, the shapes, the devices and ``extra_key`` (whatever else ``build``
    closes over) all agree."""
    leaves, treedef = jax.tree.flatten(args)
    sig = (kind, treedef, tuple((jnp.shape(a), jnp.result_type(a)) for a in leaves), devices,
           extra_key)
    for i, (k, k_st, fn) in enumerate(_COMPILED):
        if k == sig and eqx.tree_equal(k_st, st) is True:
            _COMPILED.append(_COMPILED.pop(i))
            return fn
    t0 = time.perf_counter()
    fn = build().lower(*args).compile()
    stats[f"compile_{kind}_s"] += time.perf_counter() - t0
    _COMPILED.append((sig, st, fn))
    del _COMPILED[:-_COMPILED_MAX]
    return fn


def _make_full_run(st: _Static, n_ckpt: int):
    """jit (tf_dyn, carry0, inputs [T], slot [T]) -> (carries [n_ckpt], Track [T])."""

    def full(tf_dyn, carry0, inputs, slot):
        tf = eqx.combine(tf_dyn, st.tf_static)
        carry0 = jax.tree.map(jnp.asarray, carry0)

        def body(state, xs):
            carry, buf = state
            inp, k = xs
            buf = jax.tree.map(
                lambda b, x: jax.lax.dynamic_update_index_in_dim(b, x, k, 0), buf, carry
            )
            carry, out = st.ops.run(tf, carry, jax.tree.map(lambda a: a[None], inp))
            est, _ = st.ops.readout(out)
            return (carry, buf), jax.tree.map(lambda a: a[0], est)

        buf0 = jax.tree.map(lambda x: jnp.zeros((n_ckpt + 1,) + x.shape, x.dtype), carry0)
        (_, buf), track = jax.lax.scan(body, (carry0, buf0), (inputs, slot))
        return jax.tree.map(lambda b: b[:n_ckpt], buf), track

    return jax.jit(full)


# ----------------------------------------------------------------------------------------------
# Brute force (the reference the engine is tested against)
# ----------------------------------------------------------------------------------------------
def brute_force(
    problem: Problem,
    ops: FilterOps,
    outage: ot.Outage,
    *,
    epoch_dt_s: float,
    recovery_epochs: int,
    mcfg: mt.MetricConfig = mt.MetricConfig(),  # noqa: B008 (immutable NamedTuple)
    policy: str = ot.DEFAULT_POLICY,
    key=None,
    metric_window: str = "core",
):
    """Metrics of one outage from a run of the whole drive with the outage mask applied
    (no checkpoints): the definition the engine must reproduce. Returns (WindowMetrics,
    ENU error [T, 3] with NaN after the recovery period)."""
    T = problem.elevation.shape[0]
    mask = ot.keep_mask(
        problem.elevation, problem.available, outage, key, policy=policy,
        azimuth=problem.azimuth, elevation_mask_rad=problem.elevation_mask_rad,
    )
    inputs = ops.with_keep(problem.inputs, ops.get_keep(problem.inputs) & mask)
    _, out = jax.jit(ops.run)(problem.tf, problem.carry0, inputs)
    est, P_nav = ops.readout(out)
    start, length, ramp = (jnp.asarray(outage.start), jnp.asarray(outage.length),
                           jnp.asarray(outage.ramp))
    if metric_window == "with_ramp":
        m_start, m_len = start - ramp, length + 2 * ramp
    else:
        m_start, m_len = start, length
    n_valid = jnp.minimum(start + length + ramp + recovery_epochs, T)
    m = mt.window_metrics(est, problem.truth, P_nav, m_start, m_len, epoch_dt_s, mcfg, n_valid)
    err = mt.enu_errors(est.llh, problem.truth.llh)
    err = jnp.where((jnp.arange(T) < n_valid)[:, None], err, jnp.nan)
    return m, err


class SingleRun(NamedTuple):
    """One scenario, every epoch (``single_run``). Epoch k is drive epoch k + 1 (epoch 0 only
    initialises the filter), at ``time_s``."""

    time_s: np.ndarray  # [T] s since the drive start
    keep: np.ndarray  # [T, S] bool: satellites the filter was allowed to use
    estimate: mt.Track  # [T] the filter's navigation solution
    error_enu_m: np.ndarray  # [T, 3] estimate - truth, east / north / up
    sigma_enu_m: np.ndarray  # [T, 3] the filter's 1-sigma of the same, from P
    output: Any  # the filter's raw per-epoch output (``ops.run``)


def single_run(problem: Problem, ops: FilterOps, outage: ot.Outage | None = None, *,
               epoch_dt_s: float, policy: str = ot.DEFAULT_POLICY, key=None) -> SingleRun:
    """Run one problem over the whole drive with an optional outage mask and return the errors
    and the filter's own sigmas in metres: sigma_N = sqrt(P_lat) (R_M + h),
    sigma_E = sqrt(P_lon) (R_N + h) cos(lat), sigma_U = sqrt(P_h)."""
    mask = jnp.ones_like(problem.available)
    if outage is not None:
        mask = ot.keep_mask(
            problem.elevation, problem.available, outage, key, policy=policy,
            azimuth=problem.azimuth, elevation_mask_rad=problem.elevation_mask_rad,
        )
    keep = ops.get_keep(problem.inputs) & mask
    _, out = jax.jit(ops.run)(problem.tf, problem.carry0, ops.with_keep(problem.inputs, keep))
    est, P_nav = ops.readout(out)
    err = np.asarray(mt.enu_errors(est.llh, problem.truth.llh))
    var_llh = np.asarray(jnp.diagonal(P_nav, axis1=-2, axis2=-1)[..., :3])
    scale = np.asarray(jax.vmap(geodesy.metres_per_radian)(est.llh))  # north, east, up
    sd_neu = np.sqrt(np.maximum(var_llh, 0.0)) * scale
    T = err.shape[0]
    return SingleRun(
        time_s=epoch_dt_s * np.arange(1, T + 1), keep=np.asarray(keep),
        estimate=jax.tree.map(np.asarray, est), error_enu_m=err,
        sigma_enu_m=sd_neu[:, [1, 0, 2]], output=out,
    )


# ----------------------------------------------------------------------------------------------
# Persistence
# ----------------------------------------------------------------------------------------------
class _Store:
    """OUT/manifest.json, OUT/chunks/g###_c######.npz and OUT/results.nc."""

    def __init__(self, out_dir, config_hash: str, manifest: dict):
        self.dir = Path(out_dir)
        self.hash = config_hash
        self.manifest = manifest
        self.results = self.dir / RESULTS_FILE
        self.manifest_path = self.dir / MANIFEST_FILE
        self.chunks = self.dir / CHUNK_DIR

    def chunk_path(self, g: int, j: int) -> Path:
        return self.chunks / f"g{g:03d}_c{j:06d}.npz"

    def _chunk_files(self):
        return sorted(self.chunks.glob("g*_c*.npz")) if self.chunks.is_dir() else []

    def _tmp_files(self):
        return list(self.dir.glob(".*.tmp*")) + (
            list(self.chunks.glob(".*.tmp*")) if self.chunks.is_dir() else []
        )

    def prepare(self, resume: bool, overwrite: bool) -> bool:
        """Apply the overwrite / resume rules; True when a finished result can be reused."""
        if resume and overwrite:
            raise ValueError("pass either resume=True or overwrite=True, not both")
        have_results = self.results.exists()
        have_partial = self.manifest_path.exists() or bool(self._chunk_files())
        if overwrite:
            for p in [self.results, self.manifest_path, *self._chunk_files(), *self._tmp_files()]:
                p.unlink(missing_ok=True)
        elif have_results or have_partial:
            if not resume:
                if have_results:
                    raise FileExistsError(
                        f"{self.results} exists; pass overwrite=True to replace it (or "
                        f"resume=True to reuse it if it is this study)"
                    )
                raise FileExistsError(
                    f"{self.dir} holds an unfinished sweep ({len(self._chunk_files())} chunk "
                    f"files); pass resume=True to continue it or overwrite=True to discard it"
                )
            if not self.manifest_path.exists():
                raise FileExistsError(
                    f"{self.dir} has sweep files but no {MANIFEST_FILE}; cannot tell which "
                    f"study they belong to: use another directory or overwrite=True"
                )
            old = json.loads(self.manifest_path.read_text())
            new_src = self.manifest.get("jaxnav_source")
            if old.get("config_hash") != self.hash and old.get("config") == self.manifest.get(
                "config"
            ) and old.get("jaxnav_source") != new_src:
                raise FileExistsError(
                    f"{self.dir} holds this study computed by other jaxnav code (source hash "
                    f"{str(old.get('jaxnav_source'))[:12]}, now {str(new_src)[:12]}); resuming "
                    f"would mix results of two codes: use another directory or overwrite=True"
                )
            if old.get("config_hash") != self.hash:
                raise FileExistsError(
                    f"{self.dir} holds a sweep of a different study (config hash "
                    f"{str(old.get('config_hash'))[:12]}, this one {self.hash[:12]}); use "
                    f"another directory or overwrite=True"
                )
            if old.get("n_devices") != self.manifest["n_devices"]:
                warnings.warn(
                    f"resuming a sweep started on {old.get('n_devices')} devices on "
                    f"{self.manifest['n_devices']}: chunks agree to rounding, not bit for bit",
                    stacklevel=3,
                )
            for p in self._tmp_files():  # leftovers of a killed write (never a finished chunk)
                p.unlink(missing_ok=True)
            if have_results:
                return True
        self.dir.mkdir(parents=True, exist_ok=True)
        self.chunks.mkdir(exist_ok=True)
        if not self.manifest_path.exists():
            _atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))
        return False

    def done(self) -> set[tuple[int, int]]:
        out = set()
        for p in self._chunk_files():
            g, j = p.stem.split("_")
            out.add((int(g[1:]), int(j[1:])))
        return out

    def write_chunk(self, g: int, j: int, arrays: dict):
        path = self.chunk_path(g, j)
        if path.exists():  # a finished chunk is never rewritten
            raise FileExistsError(f"{path} exists")
        tmp = self.chunks / f".{path.name}.tmp{os.getpid()}"
        with tmp.open("wb") as f:
            np.savez(f, config_hash=np.str_(self.hash), group=g, chunk=j, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)

    def read_chunk(self, g: int, j: int, n: int) -> dict:
        path = self.chunk_path(g, j)
        try:
            with np.load(path) as z:
                data = {k: z[k] for k in z.files}
        except Exception as e:  # a corrupt file must not be silently skipped
            raise OSError(f"{path}: cannot read the chunk ({e}); delete it and resume") from e
        if str(data["config_hash"]) != self.hash or int(data["group"]) != g or int(
            data["chunk"]
        ) != j or data["max_2d_m"].shape[0] != n:
            raise OSError(f"{path}: expected chunk {j} of group {g} of study {self.hash[:12]}")
        return data


def _atomic_write_text(path: Path, text: str):
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


# ----------------------------------------------------------------------------------------------
# The runner
# ----------------------------------------------------------------------------------------------
def _pad_end(a, n: int):
    a = jnp.asarray(a)
    return jnp.concatenate([a, jnp.repeat(a[-1:], n, axis=0)], axis=0)


class _Realization(NamedTuple):
    tf_dyn: Any
    carries: Any
    inputs: Any
    track: mt.Track
    truth: mt.Track
    elevation: Any
    available: Any
    azimuth: Any


class _GroupRunner:
    """Full runs (cached per realization) and chunk evaluation for one (mode, system)."""

    def __init__(self, plan: Plan, factory, ops, mode, system, mesh, stats):
        self.plan, self.factory, self.ops = plan, factory, ops
        self.mode, self.system, self.mesh, self.stats = mode, system, mesh, stats
        self.cache: dict[int, _Realization] = {}
        self.st: _Static | None = None
        self.full = self.evaluate = None
        self.ctx_rows: tuple | None = None
        self.ctx = None
        T = plan.timeline.n_epochs
        slot = np.full(T, plan.ckpt_epochs.size, np.int64)
        slot[plan.ckpt_epochs] = np.arange(plan.ckpt_epochs.size)
        self.slot = jnp.asarray(slot)

    def _check(self, prob: Problem, seed: int):
        T = self.plan.timeline.n_epochs
        where = f"scenario (mode {self.mode!r}, system {self.system!r}, seed {seed})"
        for path, leaf in jax.tree_util.tree_leaves_with_path(prob.inputs):
            if jnp.ndim(leaf) < 1 or jnp.shape(leaf)[0] != T:
                raise ValueError(
                    f"{where}: inputs{jax.tree_util.keystr(path)} has shape {jnp.shape(leaf)}; "
                    f"expected a leading epoch axis of {T}"
                )
        for name in ("elevation", "available"):
            if jnp.shape(getattr(prob, name))[0] != T:
                raise ValueError(f"{where}: {name} must be [{T}, S]")
        if jnp.shape(prob.truth.llh)[0] != T:
            raise ValueError(f"{where}: truth must have {T} epochs")
        if prob.azimuth is None and any(p.endswith("_geometry") for p in self.plan.cfg.policies):
            raise ValueError(f"{where}: the geometry policies need Problem.azimuth")

    def realization(self, r: int) -> _Realization:
        if r in self.cache:
            return self.cache[r]
        plan = self.plan
        seed = int(plan.seeds[r])
        prob = self.factory.build(plan.cfg, self.mode, self.system, seed)
        self._check(prob, seed)
        tf_dyn, tf_static = eqx.partition(prob.tf, eqx.is_array)
        if self.st is None:
            self.st = _Static(
                tf_static, self.ops, tuple(plan.cfg.policies), int(plan.cfg.seed),
                float(prob.elevation_mask_rad), int(plan.timeline.n_epochs), plan.window,
                plan.prefix, plan.recovery, float(plan.timeline.epoch_dt_s), plan.mcfg,
                plan.cfg.metric_window == "with_ramp",
            )
            # The checkpoint count is baked into the compiled scan (its buffer), not visible in
            # the argument shapes: it must be part of the cache key.
            self.full = _compiled(
                "full", self.st, lambda: _make_full_run(self.st, plan.ckpt_epochs.size),
                (tf_dyn, prob.carry0, prob.inputs, self.slot), (jax.devices()[0],), self.stats,
                extra_key=(int(plan.ckpt_epochs.size),),
            )
        elif not eqx.tree_equal(tf_static, self.st.tf_static) or (
            float(prob.elevation_mask_rad) != self.st.elevation_mask_rad
        ):
            raise ValueError(
                f"scenario (mode {self.mode!r}, system {self.system!r}, seed {seed}): the "
                f"filter's static configuration differs between realizations"
            )
        t0 = time.perf_counter()
        carries, track = self.full(tf_dyn, prob.carry0, prob.inputs, self.slot)
        jax.block_until_ready(carries)
        self.stats["full_run_s"] += time.perf_counter() - t0
        self.stats["full_runs"] += 1
        W = plan.window
        az = prob.azimuth if prob.azimuth is not None else jnp.zeros_like(prob.elevation)
        real = _Realization(
            tf_dyn, carries,
            jax.tree.map(lambda a: _pad_end(a, W), prob.inputs),
            track,
            jax.tree.map(lambda a: _pad_end(a, W), prob.truth),
            _pad_end(jnp.asarray(prob.elevation, jnp.float64), W),
            _pad_end(jnp.asarray(prob.available, bool), W),
            _pad_end(jnp.asarray(az, jnp.float64), W),
        )
        self.cache[r] = real
        return real

    def context(self, rows: tuple[int, ...]):
        if rows == self.ctx_rows:
            return self.ctx
        for r in [r for r in self.cache if r < rows[0]]:  # chunks run in order
            del self.cache[r]
        reals = [self.realization(r) for r in rows]
        self.stats["max_realizations_held"] = max(
            self.stats["max_realizations_held"], len(self.cache)
        )
        ctx = _Context(*(
            jax.tree.map(lambda *a: jnp.stack(a), *[getattr(x, f) for x in reals])
            for f in _Realization._fields
        ))
        self.ctx = jax.device_put(ctx, NamedSharding(self.mesh, Spec()))
        self.ctx_rows = rows
        return self.ctx

    def chunk(self, j: int) -> dict:
        plan = self.plan
        C = plan.cfg.chunk_size
        n_dev = self.mesh.devices.size
        flat = np.arange(j * C, min((j + 1) * C, plan.n_per_group), dtype=np.int64)
        n = flat.size
        c_pad = -(-C // n_dev) * n_dev
        flat_pad = np.concatenate([flat, np.full(c_pad - n, flat[-1])])
        f = plan.scenarios(flat_pad)
        r_lo, r_hi = int(f["realization"][0]), int(f["realization"][-1])
        rows = tuple(range(r_lo, r_hi + 1))
        rows = rows + (r_hi,) * (plan.max_rows - len(rows))
        ctx = self.context(rows)
        batch = _Batch(
            row=f["realization"] - r_lo, ckpt=f["ckpt"], sel=f["sel"], start=f["start"],
            length=f["length"], n_keep=f["n_keep"], ramp=f["ramp"], policy=f["policy"],
            key_id=f["key_id"],
        )
        batch = jax.device_put(
            jax.tree.map(jnp.asarray, batch), NamedSharding(self.mesh, Spec("batch"))
        )
        if self.evaluate is None:
            self.evaluate = _compiled(
                "eval", self.st, lambda: _make_evaluate(self.st, self.mesh), (ctx, batch),
                tuple(self.mesh.devices.flat), self.stats,
            )
        t0 = time.perf_counter()
        m, err = self.evaluate(ctx, batch)
        self.stats["shards"] = len(err.sharding.device_set)
        out = {k: np.asarray(v)[:n] for k, v in m._asdict().items()}
        self.stats["eval_s"] += time.perf_counter() - t0
        keep = np.isin(flat, plan.trace_flat)
        out["trace_flat"] = flat[keep]
        out["trace_err"] = np.asarray(err)[:n][keep]
        return out


def _devices(devices) -> list:
    return list(jax.local_devices() if devices is None else devices)


@functools.cache
def source_hash() -> str:
    """SHA-256 (16 hex digits) of jaxnav's own source files: part of a sweep's config hash, so
    a resumed sweep never mixes chunks computed by two versions of the code."""
    root = Path(jaxnav.__file__).parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def run_sweep(
    cfg: StudyConfig,
    factory,
    out_dir: str | os.PathLike,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    devices: Sequence | None = None,
    on_chunk: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Run (or resume) a sweep into ``out_dir`` and return its Dataset (module docstring).

    ``factory``: ``timeline(cfg) -> Timeline``, ``build(cfg, mode, system, seed) -> Problem``,
    optional ``ops_for(mode, system)`` (FilterOps per group) or ``ops`` (one FilterOps for
    every group; default ``tight_ops()``), ``modes`` / ``systems`` (allowed
    labels) and ``fingerprint()`` (hashed with the config so resumed chunks match the code's
    scenario). ``on_chunk(group, chunk)`` is called after each chunk is persisted.
    """
    t_wall = time.perf_counter()
    validate(cfg, modes=getattr(factory, "modes", None), systems=getattr(factory, "systems", None))
    ops = getattr(factory, "ops", None) or tight_ops()
    ops_for = getattr(factory, "ops_for", None)  # per (mode, system) when the factory varies it
    fingerprint = factory.fingerprint() if hasattr(factory, "fingerprint") else ""
    timeline = factory.timeline(cfg)
    plan = make_plan(cfg, timeline)
    devs = _devices(devices)
    mesh = Mesh(np.array(devs), ("batch",))
    config_hash = cfg.hash(f"{fingerprint}\njaxnav {jaxnav.__version__} {source_hash()}")
    groups = [(m, s) for m in cfg.modes for s in cfg.systems]
    manifest = {
        "config_hash": config_hash, "config": cfg.to_dict(), "fingerprint": fingerprint,
        "jaxnav_version": jaxnav.__version__, "jaxnav_source": source_hash(),
        "groups": groups, "chunk_size": cfg.chunk_size,
        "chunks_per_group": plan.n_chunks, "scenarios_per_group": plan.n_per_group,
        "n_devices": len(devs),
    }
    store = _Store(out_dir, config_hash, manifest)
    stats = {
        "scenarios": len(groups) * plan.n_per_group, "n_devices": len(devs), "shards": 0,
        "compile_full_s": 0.0, "compile_eval_s": 0.0, "full_run_s": 0.0, "eval_s": 0.0,
        "full_runs": 0, "chunks_computed": 0, "chunks_reused": 0, "scenarios_computed": 0,
        "max_realizations_held": 0, "window_epochs": plan.window,
        "checkpoints": int(plan.ckpt_epochs.size),
    }
    if store.prepare(resume, overwrite):
        ds = load_results(store.results)
        stats["chunks_reused"] = len(groups) * plan.n_chunks
        stats["wall_s"] = time.perf_counter() - t_wall
        return SweepResult(ds, store.results, stats)
    done = store.done()
    n_done = sum(
        min(plan.cfg.chunk_size, plan.n_per_group - j * plan.cfg.chunk_size) for _, j in done
    )
    stats["chunks_reused"] = len(done)
    bar = tqdm(
        total=stats["scenarios"], initial=n_done, unit="scen", desc=cfg.name, smoothing=0.1,
        disable=not progress, dynamic_ncols=True,
    )
    try:
        for g, (mode, system) in enumerate(groups):
            todo = [j for j in range(plan.n_chunks) if (g, j) not in done]
            if not todo:
                continue
            bar.set_postfix_str(f"{mode}/{system}")
            g_ops = ops_for(mode, system) if ops_for is not None else ops
            runner = _GroupRunner(plan, factory, g_ops, mode, system, mesh, stats)
            for j in todo:
                out = runner.chunk(j)
                store.write_chunk(g, j, out)
                n = out["max_2d_m"].shape[0]
                stats["chunks_computed"] += 1
                stats["scenarios_computed"] += n
                bar.update(n)
                if on_chunk is not None:
                    on_chunk(g, j)
            del runner
    finally:
        bar.close()
    ds = assemble(plan, store, groups, config_hash)
    tmp = store.results.with_name(f".{RESULTS_FILE}.tmp{os.getpid()}")
    ds.to_netcdf(tmp, engine=netcdf_engine())
    os.replace(tmp, store.results)
    stats["wall_s"] = time.perf_counter() - t_wall
    return SweepResult(ds, store.results, stats)


# ----------------------------------------------------------------------------------------------
# Dataset
# ----------------------------------------------------------------------------------------------
def assemble(plan: Plan, store: _Store, groups, config_hash: str) -> xr.Dataset:
    """The sweep's Dataset from its persisted chunks (named dimensions for every axis)."""
    cfg = plan.cfg
    C, N = cfg.chunk_size, plan.n_per_group
    per_group = []
    traces = []
    for g in range(len(groups)):
        parts = [store.read_chunk(g, j, min(C, N - j * C)) for j in range(plan.n_chunks)]
        per_group.append({k: np.concatenate([p[k] for p in parts]) for k in METRIC_FIELDS})
        for p in parts:
            for flat, err in zip(p["trace_flat"], p["trace_err"], strict=True):
                traces.append((g, int(flat), err))
    n_mode, n_sys = len(cfg.modes), len(cfg.systems)
    lead = (n_mode, n_sys) + plan.shape
    data_vars = {}
    for k in METRIC_FIELDS:
        a = np.stack([pg[k] for pg in per_group]).reshape(lead + per_group[0][k].shape[1:])
        dims = DIMS + (("enu",) if a.ndim > len(DIMS) else ())
        data_vars[k] = xr.Variable(dims, a, {"units": _UNITS.get(k, "1")})
    dt = float(plan.timeline.epoch_dt_s)
    coords = {
        "mode": ("mode", np.asarray(cfg.modes, dtype=object)),
        "system": ("system", np.asarray(cfg.systems, dtype=object)),
        "realization": ("realization", plan.seeds, {"long_name": "noise realization seed"}),
        "duration": ("duration", plan.duration_s,
                     {"units": "s", "long_name": "outage duration (-1: per placement, length_s)"}),
        "satellites_kept": ("satellites_kept", plan.n_keep,
                            {"long_name": "satellites kept during the outage (-1: all)"}),
        "placement": ("placement", np.arange(plan.starts.shape[1])),
        "policy": ("policy", np.asarray(cfg.policies, dtype=object)),
        "ramp": ("ramp", plan.ramps * dt, {"units": "s"}),
        "enu": ("enu", np.asarray(["east", "north", "up"], dtype=object)),
        "start_s": (("duration", "placement"), plan.starts * dt,
                    {"units": "s", "long_name": "outage start after the first epoch"}),
        "length_s": (("duration", "placement"), plan.lengths * dt, {"units": "s"}),
    }
    if plan.placement_event is not None:
        coords["placement_event"] = ("placement", np.asarray(plan.placement_event, dtype=object))
    if plan.placement_id is not None:
        coords["placement_id"] = ("placement", np.asarray(plan.placement_id, dtype=object))
    ds = xr.Dataset(data_vars, coords)
    if traces:
        g_idx = np.array([t[0] for t in traces])
        flat = np.array([t[1] for t in traces])
        f = plan.scenarios(flat)
        r, d, k, p, pol, rm = np.unravel_index(flat, plan.shape)
        L = plan.prefix + plan.window
        t_rel = (np.arange(L)[None, :] - plan.prefix - f["ramp"][:, None]) * dt
        ds["trace_err_enu_m"] = xr.Variable(
            ("trace", "trace_epoch", "enu"), np.stack([t[2] for t in traces]),
            {"units": "m", "long_name": "estimate - truth, ENU, per epoch (NaN after recovery)"},
        )
        ds = ds.assign_coords(
            trace_time_s=(("trace", "trace_epoch"), t_rel,
                          {"units": "s", "long_name": "time since the outage start"}),
            trace_mode=("trace", np.asarray([cfg.modes[i // n_sys] for i in g_idx], object)),
            trace_system=("trace", np.asarray([cfg.systems[i % n_sys] for i in g_idx], object)),
            trace_realization=("trace", plan.seeds[r]),
            trace_duration=("trace", plan.duration_s[d]),
            trace_satellites_kept=("trace", plan.n_keep[k]),
            trace_placement=("trace", p),
            trace_policy=("trace", np.asarray([cfg.policies[i] for i in pol], object)),
            trace_ramp_s=("trace", plan.ramps[rm] * dt),
            trace_outage_s=("trace", f["length"] * dt),
        )
    ds.attrs.update(
        {
            "title": f"jaxnav outage sweep {cfg.name!r}",
            "config_json": cfg.to_json(),
            "config_hash": config_hash,
            "jaxnav_version": jaxnav.__version__,
            "epoch_dt_s": dt,
            "n_epochs": int(plan.timeline.n_epochs),
            "satellites_kept_all": ALL,
            "metric_window": cfg.metric_window,
            "recovery_s": plan.recovery * dt,
            "placement_kind": cfg.placement.kind,
        }
    )
    return ds


def netcdf_engine() -> str:
    """NetCDF-4 writer: h5netcdf when its h5py backend is importable, else netCDF4 (installed
    with georinex). h5netcdf >= 1.4 no longer pulls in h5py, so a fresh install may lack it."""
    import importlib.util

    if importlib.util.find_spec("h5py") is not None:
        return "h5netcdf"
    if importlib.util.find_spec("netCDF4") is not None:
        return "netcdf4"
    raise ImportError("writing NetCDF needs h5py (for h5netcdf) or netCDF4: pip install h5py")


def load_results(path: str | os.PathLike) -> xr.Dataset:
    """Read a sweep's results.nc into memory."""
    return xr.load_dataset(path, engine=netcdf_engine())
