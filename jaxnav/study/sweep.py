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
- ``smooth = true``: each scenario's window is also run through the filter's RTS smoother
  (``FilterOps.smooth``: forward pass from the checkpoint, backward pass over the window) and
  every metric gets a ``solution`` axis ("forward", "smoothed"). The smoother conditions on the
  data before the window (through the checkpoint) and on the scenario's own epochs: its ramps,
  the outage and its ``recovery_s`` after it (the same for every duration and ramp of the
  study; window padding and the rest of the drive are cut off, ``smoother.cut_after``): a longer
  ``recovery_s`` lets more of the later data in. The P pre-outage epochs of the metric record
  are the forward full run's for both solutions, so the smoothed slice's ``pre_2d_rms_m`` is the
  forward one and its re-convergence threshold is set from it, and its traces start with those
  forward epochs. The forward metrics are those of a study without ``smooth``
  (tests/test_sweep.py). Memory: the forward pass keeps 3 n^2 float64 per
  window epoch and scenario (``jaxnav.filter.smoother``).
- Per-epoch ENU error traces are kept for at most ``max_traces`` scenarios per group (for the
  error-growth plot; first policy and ramp): realization 0 at placement 0 for every duration
  and satellites-kept level (longest duration first), then the other realizations and
  placements, so the plot's median and 10-90 % band per curve span the runs.

Modules: ``plan.py`` (scenario grid), ``engine.py`` (device functions), ``store.py`` (chunks,
manifest, Dataset), ``reference.py`` (brute-force and single runs); this one runs a sweep. Their
public names are importable from here.
"""

from __future__ import annotations

import functools
import hashlib
import os
import time
import warnings
from collections.abc import Callable, Sequence
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
from jaxnav.core.ops import FilterOps
from jaxnav.study import metrics as mt
from jaxnav.study.config import (  # noqa: F401  (ALL re-exported)
    ALL,
    ConfigError,
    StudyConfig,
    validate,
)
from jaxnav.study.engine import (
    _Batch,
    _compiled,
    _Context,
    _make_evaluate,
    _make_full_run,
    _Static,
)
from jaxnav.study.plan import (  # noqa: F401  (re-exported)
    DIMS,
    GROUP_DIMS,
    Plan,
    Problem,
    Timeline,
    make_plan,
    scenario_key,
)
from jaxnav.study.reference import SingleRun, brute_force, single_run  # noqa: F401
from jaxnav.study.store import (  # noqa: F401  (re-exported)
    CHUNK_DIR,
    MANIFEST_FILE,
    METRIC_FIELDS,
    RESULTS_FILE,
    StoreError,
    _Store,
    assemble,
    load_results,
    netcdf_engine,
)


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
        smooth=tight.run_smoother,
    )


def group_ops(factory, mode: str, system: str) -> FilterOps:
    """The FilterOps of a (mode, system) group: the factory's ``ops_for``, else its ``ops``,
    else ``tight_ops()``."""
    ops_for = getattr(factory, "ops_for", None)  # per group when the factory varies it
    if ops_for is not None:
        return ops_for(mode, system)
    return getattr(factory, "ops", None) or tight_ops()


class SweepResult(NamedTuple):
    dataset: xr.Dataset
    path: Path  # OUT/results.nc
    stats: dict  # timings (compile separately), devices, chunks computed / reused, ...


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
                plan.cfg.metric_window == "with_ramp", bool(plan.cfg.smooth),
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
    a resumed sweep never mixes chunks computed by two versions of the code. The tutorial
    notebooks (``apps/notebooks/``) are documents that no sweep runs: left out, so editing their
    prose does not invalidate every stored sweep and prepared-observation cache."""
    root = Path(jaxnav.__file__).parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        if f.parent == root / "apps" / "notebooks":
            continue
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def available_memory_bytes() -> int:
    """The memory this process may still take: MemAvailable (Linux), else the physical size."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _check_memory(cfg: StudyConfig, factory, *, rows: int, chunk_epochs: int, force: bool,
                  workers: int = 1):
    estimate = getattr(factory, "memory_bytes", None)
    if estimate is None or force:
        return
    need = estimate(cfg, rows=rows, chunk_epochs=chunk_epochs)
    have = available_memory_bytes()
    if need["total"] * workers <= have:
        return
    key = max(("scenario.duration_s", "drive"), ("study.chunk_size", "chunk"),
              key=lambda kv: need[kv[1]])[0]
    each = f" per worker, x {workers} workers" if workers > 1 else ""
    raise ConfigError(
        f"the study needs about {need['total'] / 1e9:.1f} GB{each} ({need['drive'] / 1e9:.1f} GB "
        f"for {rows} realisation(s) of the drive held at once, {need['chunk'] / 1e9:.1f} GB for "
        f"a chunk of {cfg.chunk_size} scenario windows) and {have / 1e9:.1f} GB are available: "
        f"lower {key}{', or --workers' if workers > 1 else ''}, or pass --force to run it anyway"
    )


def check_study(cfg: StudyConfig, factory, *, force: bool = False, workers: int = 1) -> Plan:
    """Every check a study passes before any work (``ConfigError`` naming the key): the schema,
    the memory estimate for the drive alone, the timeline and plan (seconds -> epochs, outage
    placements), the memory estimate for the plan (times the local ``workers``, each holding its
    own chunk), and satellites_kept against the scenario's slots. Returns the plan; touches no
    file (``jaxnav sweep --check``)."""
    validate(cfg, modes=getattr(factory, "modes", None), systems=getattr(factory, "systems", None))
    if cfg.smooth:
        for mode in cfg.modes:
            for system in cfg.systems:
                if group_ops(factory, mode, system).smooth is None:
                    raise ConfigError(
                        f"study.smooth = true: the {mode!r} / {system!r} filter has no RTS "
                        "smoother; expected smooth = false or filters with a smoother"
                    )
    _check_memory(cfg, factory, rows=1, chunk_epochs=0, force=force)  # the drive alone
    plan = make_plan(cfg, factory.timeline(cfg))
    _check_memory(cfg, factory, rows=plan.max_rows, chunk_epochs=cfg.chunk_size * plan.window,
                  force=force, workers=workers)
    n_slots = getattr(factory, "n_slots", None)
    over = [k for k in cfg.satellites_kept if n_slots is not None and k != ALL and k > n_slots]
    if over:
        raise ConfigError(
            f"study.satellites_kept = {over[0]}: expected at most the scenario's {n_slots} "
            "satellite slots, or 'all'"
        )
    return plan


def _persist_chunk(store, stats, bar, on_chunk, g: int, j: int, out: dict) -> None:
    """Chunk ``j`` of group ``g`` written, counted, shown, and announced to ``on_chunk``."""
    store.write_chunk(g, j, out)
    n = out["max_2d_m"].shape[0]
    stats["chunks_computed"] += 1
    stats["scenarios_computed"] += n
    bar.update(n)
    if on_chunk is not None:
        on_chunk(g, j)


def plan_and_workers(cfg: StudyConfig, factory, workers: int | str, *, force: bool = False
                     ) -> tuple[Plan, int]:
    """``check_study`` with ``workers = "auto"`` resolved (``parallel.auto_workers`` of the
    study's scenario count) and the memory checked for the count chosen."""
    plan = check_study(cfg, factory, force=force, workers=1 if workers == "auto" else workers)
    if workers == "auto":
        from jaxnav.study import parallel

        workers = parallel.auto_workers(len(cfg.modes) * len(cfg.systems) * plan.n_per_group)
        if workers > 1:
            plan = check_study(cfg, factory, force=force, workers=workers)
    return plan, workers


def _run_distributed(plan, factory, groups, done, store, bar, stats, on_chunk, config_hash,
                     client, workers):
    """The pending chunks on Dask workers (``parallel.run_chunks``), persisted as they come."""
    from jaxnav.study import parallel

    todo = [(g, j) for g in range(len(groups)) for j in range(plan.n_chunks)
            if (g, j) not in done]
    if not todo:
        return
    if isinstance(client, parallel.StartingClient):
        bar.set_postfix_str(f"starting {workers} workers")
        client = client.get()
    stats["n_workers"] = len(client.scheduler_info()["workers"])
    bar.set_postfix_str(f"{stats['n_workers']} workers: compiling")
    job = {"config_hash": config_hash, "factory": factory, "plan": plan}

    def persist(g, j, out, delta):
        for k in parallel._STAT_KEYS:
            stats[k] += delta[k]
        stats["max_realizations_held"] = max(stats["max_realizations_held"],
                                             delta["realizations_held"])
        bar.set_postfix_str(f"{stats['n_workers']} workers")
        _persist_chunk(store, stats, bar, on_chunk, g, j, out)

    parallel.run_chunks(client, job, todo, groups, persist)


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
    force: bool = False,
    workers: int | str = 1,
    client=None,
) -> SweepResult:
    """Run (or resume) a sweep into ``out_dir`` and return its Dataset (module docstring).

    ``factory``: ``timeline(cfg) -> Timeline``, ``build(cfg, mode, system, seed) -> Problem``,
    optional ``ops_for(mode, system)`` (FilterOps per group) or ``ops`` (one FilterOps for
    every group; default ``tight_ops()``), ``modes`` / ``systems`` (allowed
    labels) and ``fingerprint()`` (hashed with the config so resumed chunks match the code's
    scenario). ``on_chunk(group, chunk)`` is called after each chunk is persisted. A factory
    with ``memory_bytes(cfg, rows, chunk_epochs)`` has its estimate checked against the memory
    available before the drive is built and again once the plan is known; beyond it the study
    is refused (``ConfigError`` naming the key to change) unless ``force``. ``workers`` > 1
    runs the chunks on a Dask ``LocalCluster`` of that many single-threaded processes, and a
    Dask ``client`` on its cluster (``jaxnav.study.parallel``); either gives the same dataset.
    ``workers = "auto"``: every core when the study is large enough to gain from it
    (``parallel.auto_workers``), else in-process.
    """
    t_wall = time.perf_counter()
    if workers != "auto" and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers = {workers!r}: expected 'auto' or a whole number >= 1")
    if client is not None:
        workers = 1  # the memory check counts this machine's workers; a cluster's are elsewhere
    plan = None
    if workers == "auto":  # decided by the plan, so the cluster cannot boot during the checks
        plan, workers = plan_and_workers(cfg, factory, workers, force=force)
    if client is not None or workers == 1:
        return _run_sweep(cfg, factory, out_dir, resume, overwrite, progress, devices, on_chunk,
                          force, 1, client, t_wall, plan)
    from jaxnav.study import parallel

    starting = parallel.StartingClient(workers)  # boots while the study is checked
    try:
        return _run_sweep(cfg, factory, out_dir, resume, overwrite, progress, devices, on_chunk,
                          force, workers, starting, t_wall, plan)
    finally:
        starting.close()


def _run_sweep(cfg, factory, out_dir, resume, overwrite, progress, devices, on_chunk, force,
               workers, client, t_wall, plan) -> SweepResult:
    """``run_sweep``'s body; ``client``: None (in-process), a Dask client or a StartingClient;
    ``plan``: the checked plan, or None to check the study here."""
    if plan is None:
        plan = check_study(cfg, factory, force=force, workers=workers)
    fingerprint = factory.fingerprint() if hasattr(factory, "fingerprint") else ""
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
    sizes = {
        (g, j): min(cfg.chunk_size, plan.n_per_group - j * cfg.chunk_size)
        for g in range(len(groups)) for j in range(plan.n_chunks)
    }
    if store.prepare(resume, overwrite):
        try:
            ds = load_results(store.results)
        except Exception as e:  # noqa: BLE001  (a truncated or foreign results.nc)
            store.verify(sizes)
            if store.done() != set(sizes):
                raise StoreError(
                    f"{store.results}: unreadable ({type(e).__name__}) and "
                    f"{len(set(sizes) - store.done())} chunk(s) are missing, so it cannot be "
                    "rebuilt: delete it and resume, or use --overwrite"
                ) from e
            warnings.warn(
                f"{store.results} is unreadable ({type(e).__name__}: {e}); rebuilding it from "
                "its chunks",
                stacklevel=2,
            )
            store.results.unlink()
        else:
            stats["chunks_reused"] = len(groups) * plan.n_chunks
            stats["wall_s"] = time.perf_counter() - t_wall
            return SweepResult(ds, store.results, stats)
    store.verify(sizes)  # a damaged chunk is reported now, not after hours of work
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
        if client is not None or workers > 1:
            _run_distributed(plan, factory, groups, done, store, bar, stats, on_chunk,
                             config_hash, client, workers)
            done = store.done()
        for g, (mode, system) in enumerate(groups):
            todo = [j for j in range(plan.n_chunks) if (g, j) not in done]
            if not todo:
                continue
            # a group's first chunk compiles its programs: shown as a phase, not as 0 scen/s
            bar.set_postfix_str(f"{mode}/{system}: compiling")
            runner = _GroupRunner(plan, factory, group_ops(factory, mode, system), mode, system,
                                  mesh, stats)
            for k, j in enumerate(todo):
                out = runner.chunk(j)
                if k == 0:
                    bar.set_postfix_str(f"{mode}/{system}")
                _persist_chunk(store, stats, bar, on_chunk, g, j, out)
            del runner
    finally:
        bar.close()
    ds = assemble(plan, store, groups, config_hash)
    tmp = store.results.with_name(f".{RESULTS_FILE}.tmp{os.getpid()}")
    ds.to_netcdf(tmp, engine=netcdf_engine())
    os.replace(tmp, store.results)
    stats["wall_s"] = time.perf_counter() - t_wall
    return SweepResult(ds, store.results, stats)
