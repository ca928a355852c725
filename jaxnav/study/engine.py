"""The sweep's device functions: one scenario as the filter run over its window from a checkpoint
(vmapped, sharded over local devices), the checkpointed full-availability run, and the cache of
compiled executables (``study/sweep.py`` drives them; its docstring gives the scheme)."""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as Spec

from jaxnav.core.ops import FilterOps
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study.plan import scenario_key


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
    smooth: bool = False  # also the RTS-smoothed metrics (a leading solution axis of 2)


def _n_valid(st: _Static, length, ramp, sel):
    """Epochs of a scenario's record (prefix + window) that count: up to the end of its
    recovery period or of the drive."""
    P = st.prefix
    return jnp.minimum(P + 2 * ramp + length + st.recovery, P + st.n_epochs - sel)


def _record_metrics(st: _Static, est_rec, truth_rec, P_rec, start, length, ramp, sel):
    P = st.prefix
    if st.with_ramp:
        m_start, m_len = P, length + 2 * ramp
    else:
        m_start, m_len = P + ramp, length
    n_valid = _n_valid(st, length, ramp, sel)
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
    pre = jax.tree.map(lambda a: _window(a, s.row, s.sel - P, P), ctx.track)
    truth_rec = jax.tree.map(lambda a: _window(a, s.row, s.sel - P, P + W), ctx.truth)

    def metrics(out):
        est, P_nav = st.ops.readout(out)
        est_rec = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pre, est)
        P_rec = None
        if P_nav is not None:  # the prefix's covariance is never used (NEES is over the window)
            k = P_nav.shape[-1]
            P_rec = jnp.concatenate([jnp.broadcast_to(jnp.eye(k), (P, k, k)), P_nav])
        return _record_metrics(st, est_rec, truth_rec, P_rec, s.start, s.length, s.ramp, s.sel)

    if not st.smooth:
        return metrics(st.ops.run(tf, carry, inp)[1])
    # Smoothed over the scenario's valid epochs only (sweep docstring: "smooth"): neither the
    # padding past the drive's end nor data beyond its recovery period reaches it. The prefix of
    # the record is the forward full run's for both solutions.
    fwd, smo = st.ops.smooth(tf, carry, inp, _n_valid(st, s.length, s.ramp, s.sel) - P)
    return jax.tree.map(lambda a, b: jnp.stack([a, b]), metrics(fwd), metrics(smo))


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
