"""The sweep's scenario grid (host side): its dimensions, the drive's epoch timeline, one
(mode, system, realization) problem, and the flat plan of every scenario's window."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np

from jaxnav.sim.constellation import DEFAULT_ELEVATION_MASK_RAD
from jaxnav.sim.trajectory import Event
from jaxnav.study import metrics as mt
from jaxnav.study import outages as ot
from jaxnav.study.config import ConfigError, StudyConfig

#: Dimensions of every per-scenario variable, in order.
DIMS = (
    "mode", "system", "realization", "duration", "satellites_kept", "placement", "policy", "ramp"
)
GROUP_DIMS = DIMS[2:]  # the flattened axes within one (mode, system) group


class Timeline(NamedTuple):
    """The drive's epoch grid (shared by every mode, system and realization)."""

    n_epochs: int
    epoch_dt_s: float
    labels: np.ndarray | None = None  # [T] sim.trajectory.Event codes (for event placement)
    t0_gps_s: float | None = None  # GPS time of epoch 0 (None: the source has no clock)


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
    # Traces (first policy / ramp): realization 0 at placement 0 for every duration (longest
    # first) and level, then the other runs (realization fastest, then placement) in the same
    # order, so that the error-growth plot can draw a median and a band over runs per curve.
    order = np.argsort(-plan.lengths[:, 0], kind="stable")
    n_real, n_place = len(plan.seeds), plan.starts.shape[1]
    runs = [(r, p) for p in range(n_place) for r in range(n_real)]
    picks = [
        np.ravel_multi_index((r, d, k, p, 0, 0), plan.shape)
        for j in (runs[:1], runs[1:]) for d in order for (r, p) in j for k in range(len(n_keep))
    ][: cfg.max_traces]
    return plan._replace(trace_flat=np.sort(np.asarray(picks, np.int64)))
