"""GNSS outage definitions: satellite-availability masks, placements and schedule files.

An outage is an ``Outage`` (start epoch, length in epochs, satellites kept ``n_keep`` in
{0, 1, 2, 3} or ``ALL`` = no outage, optional ramp) plus a static selection policy. It becomes
the per-epoch availability mask ``keep [T, S]`` that ``filter.tight.EpochInput.keep`` honours: a
mask, never a reshape (DESIGN invariant 2), so thousands of outages are one ``jax.vmap`` of
``keep_mask`` over ``Outage`` arrays.

Which satellites stay visible in a partial outage (SEED_SPEC 3.2 and 5: "the selection rule is
not in the seeds and must be chosen and documented"):

- ``"highest"`` (DEFAULT): the k satellites of highest elevation. Chosen because it is what
  survives where real partial outages happen: in urban canyons, under overpasses' edges and
  under foliage the remaining line-of-sight signals are the ones above the buildings and trees,
  i.e. the high ones (S001 Table 5: real urban-canyon / foliage outages with 2-3 satellites
  left). It is also the honest (pessimistic) choice for horizontal positioning, since high
  satellites' lines of sight are mostly vertical and carry little horizontal information.
- ``"lowest"``: the k lowest satellites above the elevation mask (e.g. an open side of a street).
- ``"random"``: k satellites drawn uniformly without replacement from a PRNG key.
- ``"best_geometry"`` / ``"worst_geometry"``: the k-subset with the largest / smallest
  information measure D = det(I_k + G G^T), G the k x 4 matrix of rows [u_i^T, 1] (unit line
  of sight in ENU, and the receiver-clock column). By Sylvester's identity this equals
  det(I_4 + G^T G), the D-optimal (Bayesian, unit prior on east, north, up and clock) design
  criterion, which tends to 1/PDOP-like ranking for k >= 4 but stays defined for k <= 3 where
  position is not determined. Its k x k form has entries 1 + cos(angle_ij) off the diagonal and
  3 on it, so D depends only on the pairwise angles between lines of sight: "best" = the most
  spread in azimuth and elevation (k = 2: D = 9 - (1 + cos a)^2, largest for opposite
  satellites), "worst" = the most clustered. For k = 1 every satellite has D = 3; a tie-break
  of 1e-6 sum(sin E) makes best = the highest and worst = the lowest satellite. Subsets are
  enumerated up to size ``GEOMETRY_MAX_K`` = 3; for k > 3 the geometry policies keep the best /
  worst 3-subset and fill up by elevation (highest first).

Holding rules (documented choices):

- The kept set is chosen ONCE, at the selection epoch (the outage start, or the start of the
  ramp when there is one), among the satellites available and above the elevation mask there.
  It is held fixed: a kept satellite that sets (becomes unavailable) is NOT replaced, and a
  satellite that rises during the outage is not admitted. (A kept satellite that drops out and
  reappears inside the window is admitted again: it is the same line of sight.)
- Ramp (S002: real outages are worse than simulated ones): over ``ramp`` epochs before the
  outage the number of satellites allowed falls linearly from all (the N0 candidates at the
  selection epoch) to k, and over ``ramp`` epochs after it rises back:
  n(r) = k + round((N0 - k) r / (ramp + 1)) at r = 1..ramp epochs away from the window. The
  satellites are dropped and restored in the reverse of the policy's priority order, so the
  sets are nested and the k core satellites are kept throughout. Satellites that were not
  candidates at the selection epoch return only after the ramp.
- Outside the outage (and its ramps), and for ``n_keep = ALL`` or ``length <= 0``,
  keep = available.

Placement generators (numpy, host side, for building the study grid) return start epochs: a
regular grid, random (seeded) with a minimum spacing, and at labelled events (turns, straights,
stops, slopes, as seed 000 placed its 60-s outages), all with a convergence exclusion at the
start of the drive. Schedules read from / written to plain ``id,start_s,length_s`` CSV files.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable, Sequence
from functools import partial
from itertools import combinations
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.sim.constellation import DEFAULT_ELEVATION_MASK_RAD
from jaxnav.sim.trajectory import Event

#: ``n_keep`` value meaning "no outage": every available satellite is kept.
ALL = -1
POLICIES = ("highest", "lowest", "random", "best_geometry", "worst_geometry")
DEFAULT_POLICY = "highest"
#: Largest subset enumerated by the geometry policies (the study keeps 0-3 satellites; the
#: measure uses a closed-form 3 x 3 determinant, so this is fixed).
GEOMETRY_MAX_K = 3
# Tie-break weight for the geometry measure (k = 1 ties exactly): small against any real
# difference in log D, large against rounding (1e-16).
_GEOMETRY_TIE_BREAK = 1e-6


class Outage(NamedTuple):
    """One outage (leaves may be traced ints or stacked int arrays for ``jax.vmap``)."""

    start: jnp.ndarray  # first outage epoch (index into the epoch axis)
    length: jnp.ndarray  # outage length [epochs]; <= 0 means no outage
    n_keep: jnp.ndarray  # satellites kept during the outage, or ALL (-1) for no outage
    ramp: jnp.ndarray = 0  # degradation ramp before and after [epochs] (0 = abrupt)


# ----------------------------------------------------------------------------------------------
# Keep masks (pure JAX, vmappable over outages and keys)
# ----------------------------------------------------------------------------------------------
def _subset_table(n_slots: int, max_k: int):
    """All subsets of size 1..max_k of n_slots slots, padded: (index [M, max_k], size [M])."""
    idx, size = [], []
    for k in range(1, min(max_k, n_slots) + 1):
        for c in combinations(range(n_slots), k):
            idx.append(list(c) + [0] * (max_k - k))
            size.append(k)
    return np.asarray(idx, dtype=np.int32), np.asarray(size, dtype=np.int32)


def los_enu(elevation, azimuth):
    """Unit line of sight in ENU: (cos E sin A, cos E cos A, sin E), A clockwise from north."""
    ce = jnp.cos(elevation)
    return jnp.stack([ce * jnp.sin(azimuth), ce * jnp.cos(azimuth), jnp.sin(elevation)], axis=-1)


def _logdet_sym3(a, b, c, d, e, f):
    """log det of the symmetric [[a, d, e], [d, b, f], [e, f, c]] (positive definite here)."""
    return jnp.log(a * b * c + 2.0 * d * e * f - a * f * f - b * e * e - c * d * d)


def geometry_measure(los, member):
    """log det(I_k + G G^T) with G rows [u_i^T, 1] for the members of three lines of sight
    (``los`` [3, 3], ``member`` [3] bool). Non-members contribute identity rows and columns, so
    one 3 x 3 form serves k = 1, 2, 3.
    """
    gram = 1.0 + los @ los.T
    both = member[:, None] & member[None, :]
    mat = jnp.eye(3) + jnp.where(both, gram, 0.0)
    return _logdet_sym3(mat[0, 0], mat[1, 1], mat[2, 2], mat[0, 1], mat[0, 2], mat[1, 2])


def _geometry_core(elevation, azimuth, cand, k_eff, worst: bool):
    """[S] bool: the best (or worst) k_eff-subset of the candidates (k_eff <= GEOMETRY_MAX_K)."""
    n_slots = elevation.shape[0]
    idx_np, size_np = _subset_table(n_slots, GEOMETRY_MAX_K)
    idx, size = jnp.asarray(idx_np), jnp.asarray(size_np)
    member = jnp.arange(GEOMETRY_MAX_K)[None, :] < size[:, None]  # [M, 3]
    u = los_enu(elevation, azimuth)
    gram = 1.0 + u @ u.T  # [S, S] once, gathered per subset (same as geometry_measure)

    def entry(p, q):
        return jnp.where(member[:, p] & member[:, q], gram[idx[:, p], idx[:, q]], 0.0)

    logdet = _logdet_sym3(
        1.0 + entry(0, 0),
        1.0 + entry(1, 1),
        1.0 + entry(2, 2),
        entry(0, 1),
        entry(0, 2),
        entry(1, 2),
    )
    tie = _GEOMETRY_TIE_BREAK * jnp.sum(jnp.where(member, jnp.sin(elevation[idx]), 0.0), axis=1)
    measure = logdet + tie
    valid = (size == k_eff) & jnp.all(cand[idx] | ~member, axis=1)
    score = jnp.where(valid, -measure if worst else measure, -jnp.inf)
    best = jnp.argmax(score)
    chosen = jnp.zeros(n_slots, bool).at[idx[best]].max(member[best])
    return chosen & (k_eff > 0)


def _priority_rank(elevation, azimuth, cand, n_keep, key, policy: str):
    """Rank [S] of each slot in the policy's priority order (0 = kept first); non-candidates
    come after every candidate."""
    n_slots = elevation.shape[0]
    if policy == "highest":
        score = elevation
    elif policy == "lowest":
        score = -elevation
    elif policy == "random":
        score = jax.random.uniform(key, (n_slots,))
    elif policy in ("best_geometry", "worst_geometry"):
        n_cand = jnp.sum(cand)
        k_eff = jnp.minimum(jnp.minimum(n_keep, n_cand), GEOMETRY_MAX_K)
        core = _geometry_core(elevation, azimuth, cand, k_eff, policy == "worst_geometry")
        # Core first (elevation lies in [-pi/2, pi/2], so +10 puts it ahead), then by elevation.
        score = elevation + jnp.where(core, 10.0, 0.0)
    else:
        raise ValueError(f"unknown selection policy {policy!r}; allowed: {', '.join(POLICIES)}")
    key_sort = jnp.where(cand, -score, jnp.inf)
    order = jnp.argsort(key_sort, stable=True)
    return jnp.zeros(n_slots, jnp.int32).at[order].set(jnp.arange(n_slots, dtype=jnp.int32))


def allowed_count(outage: Outage, n_all, n_epochs: int):
    """[T] number of satellites allowed per epoch (n_all outside the outage and its ramps).

    Inside [start, start + length): k; r = 1..ramp epochs before or after: the linear ramp
    k + round((n_all - k) r / (ramp + 1)).
    """
    t = jnp.arange(n_epochs)
    start, length = jnp.asarray(outage.start), jnp.asarray(outage.length)
    ramp = jnp.maximum(jnp.asarray(outage.ramp), 0)
    k = jnp.minimum(jnp.asarray(outage.n_keep), n_all)
    end = start + length  # first epoch after the outage
    r = jnp.where(t < start, start - t, t - end + 1)  # epochs away from the window (>= 1)
    ramp_n = k + jnp.floor((n_all - k) * r / (ramp + 1.0) + 0.5).astype(jnp.int32)
    inside = (t >= start) & (t < end)
    in_ramp = ~inside & (r <= ramp)
    return jnp.where(inside, k, jnp.where(in_ramp, ramp_n, n_all))


def keep_mask(
    elevation,
    available,
    outage: Outage,
    key=None,
    *,
    policy: str = DEFAULT_POLICY,
    azimuth=None,
    elevation_mask_rad: float = DEFAULT_ELEVATION_MASK_RAD,
):
    """Per-epoch availability mask keep [T, S] of one outage (module docstring: the rules).

    ``elevation`` / ``azimuth`` [T, S] rad, ``available`` [T, S] bool; ``key`` is needed by the
    ``"random"`` policy, ``azimuth`` by the geometry policies. The policy is static; the outage
    fields may be traced. keep = available outside the outage; inside, available & (priority
    rank < allowed count), the ranking fixed at the selection epoch max(start - ramp, 0).
    """
    if policy not in POLICIES:
        raise ValueError(f"unknown selection policy {policy!r}; allowed: {', '.join(POLICIES)}")
    if policy == "random" and key is None:
        raise ValueError("policy 'random' needs a PRNG key")
    if policy.endswith("_geometry") and azimuth is None:
        raise ValueError(f"policy {policy!r} needs the azimuth [T, S]")
    elevation = jnp.asarray(elevation, jnp.float64)
    azimuth = jnp.zeros_like(elevation) if azimuth is None else jnp.asarray(azimuth, jnp.float64)
    return _keep_mask(elevation, jnp.asarray(available, bool), outage, key, azimuth,
                      elevation_mask_rad, policy=policy)


# Jitted (the policy static): a host-side call compiles one kernel per shape, not one per op.
@partial(jax.jit, static_argnames=("policy",))
def _keep_mask(elevation, available, outage: Outage, key, azimuth, elevation_mask_rad, *, policy):
    n_epochs, n_slots = elevation.shape

    start = jnp.asarray(outage.start)
    ramp = jnp.maximum(jnp.asarray(outage.ramp), 0)
    n_keep = jnp.asarray(outage.n_keep)
    sel = jnp.clip(start - ramp, 0, n_epochs - 1)
    el0, az0 = elevation[sel], azimuth[sel]
    cand = available[sel] & (el0 >= elevation_mask_rad)
    n_cand = jnp.sum(cand).astype(jnp.int32)
    n_keep_eff = jnp.where(n_keep < 0, n_slots, n_keep)
    rank = _priority_rank(el0, az0, cand, n_keep_eff, key, policy)

    count = allowed_count(outage._replace(n_keep=n_keep_eff), n_cand, n_epochs)
    t = jnp.arange(n_epochs)
    degraded = (t >= start - ramp) & (t < start + jnp.asarray(outage.length) + ramp)
    active = (n_keep >= 0) & (jnp.asarray(outage.length) > 0)
    held = available & (rank[None, :] < count[:, None])
    return jnp.where((active & degraded)[:, None], held, available)


# ----------------------------------------------------------------------------------------------
# Study grid and placements (numpy, host side)
# ----------------------------------------------------------------------------------------------
def outage_grid(starts, lengths, n_keep, ramps=(0,)) -> Outage:
    """Cartesian product of the axes as an ``Outage`` of int arrays shaped
    [len(starts), len(lengths), len(n_keep), len(ramps)] (flatten with ``np.ravel`` per leaf
    before ``jax.vmap``)."""
    axes = [np.asarray(a, dtype=np.int64).reshape(-1) for a in (starts, lengths, n_keep, ramps)]
    grids = np.meshgrid(*axes, indexing="ij")
    return Outage(*grids)


def _check_epochs(name, value):
    if int(value) != value or value < 0:
        raise ValueError(f"{name} must be a non-negative whole number of epochs, got {value}")
    return int(value)


def _valid_start_range(n_epochs, length, convergence_epochs, tail_epochs):
    """First and last start such that the window + tail fits after the convergence exclusion."""
    lo = _check_epochs("convergence_epochs", convergence_epochs)
    hi = n_epochs - _check_epochs("length", length) - _check_epochs("tail_epochs", tail_epochs)
    return lo, hi


def grid_starts(
    n_epochs: int, length: int, spacing: int, *, convergence_epochs: int = 0, tail_epochs: int = 0
) -> np.ndarray:
    """Start epochs convergence_epochs + i * spacing with start + length + tail <= n_epochs."""
    if spacing < 1:
        raise ValueError(f"spacing must be >= 1 epoch, got {spacing}")
    lo, hi = _valid_start_range(n_epochs, length, convergence_epochs, tail_epochs)
    return np.arange(lo, hi + 1, int(spacing), dtype=np.int64)


def random_starts(
    n_epochs: int,
    length: int,
    count: int,
    seed: int,
    *,
    min_spacing: int = 0,
    convergence_epochs: int = 0,
    tail_epochs: int = 0,
) -> np.ndarray:
    """``count`` sorted random start epochs, consecutive starts at least ``min_spacing`` apart.

    Uniform over all valid placements: ``count`` distinct sorted values c_i from
    [0, span + count), span = (hi - lo) - (count - 1) min_spacing, map one-to-one onto the
    non-decreasing sequences c_i - i in [0, span]; adding i * min_spacing spaces them out.
    """
    lo, hi = _valid_start_range(n_epochs, length, convergence_epochs, tail_epochs)
    if count > max(hi - lo + 1, 0):  # more placements than start epochs: repeats, not a study
        raise ValueError(
            f"count = {count} placements, but only {max(hi - lo + 1, 0)} start epochs "
            f"[{lo}, {hi}] of the {n_epochs}-epoch drive can hold an outage of {length} epochs"
        )
    span = hi - lo - (count - 1) * int(min_spacing)
    if count < 0 or span < 0:
        raise ValueError(
            f"cannot place {count} outages of {length} epochs {min_spacing} epochs apart in "
            f"epochs [{lo}, {hi}] of a {n_epochs}-epoch drive"
        )
    rng = np.random.default_rng(seed)
    c = np.sort(rng.choice(span + count, size=count, replace=False)).astype(np.int64)
    i = np.arange(count, dtype=np.int64)
    return lo + c - i + i * int(min_spacing)


class EventPlacement(NamedTuple):
    start: np.ndarray  # [n] start epochs
    event: np.ndarray  # [n] event code of the interval the window overlaps
    event_start: np.ndarray  # [n] first epoch of that interval
    event_end: np.ndarray  # [n] last epoch of that interval (inclusive)


def event_starts(
    labels,
    length: int,
    events: Iterable[int] = (Event.TURN, Event.STRAIGHT, Event.STOP, Event.SLOPE),
    *,
    min_spacing: int = 0,
    convergence_epochs: int = 0,
    tail_epochs: int = 0,
    min_event_epochs: int = 1,
    max_per_event: int | None = None,
) -> EventPlacement:
    """Outage windows centred on labelled events (seed 000 placed its outages on turns,
    straights, slopes and stops), one per maximal run of a requested label.

    ``labels`` [n_epochs] int codes per epoch (``sim.trajectory.Event``, e.g. the ``event`` of
    ``truth_at_epochs``). The window is centred on the run's middle and shifted into the valid
    range; runs whose window would then not overlap them are skipped. Candidates are taken in
    time order and accepted when their start is at least ``min_spacing`` from every accepted
    start and their label has fewer than ``max_per_event`` accepted.
    """
    labels = np.asarray(labels).reshape(-1)
    n_epochs = labels.size
    lo, hi = _valid_start_range(n_epochs, length, convergence_epochs, tail_epochs)
    wanted = {int(e) for e in events}
    change = np.flatnonzero(np.diff(labels)) + 1
    run_start = np.concatenate([[0], change]).astype(np.int64)
    run_end = np.concatenate([change, [n_epochs]]).astype(np.int64) - 1
    out = {"start": [], "event": [], "event_start": [], "event_end": []}
    per_event: dict[int, int] = {}
    for a, b in zip(run_start, run_end, strict=True):
        code = int(labels[a])
        if code not in wanted or b - a + 1 < min_event_epochs or hi < lo:
            continue
        s = int(np.clip((a + b + 1) // 2 - length // 2, lo, hi))
        if s > b or s + length - 1 < a:  # pushed off the event by the valid range
            continue
        if any(abs(s - q) < min_spacing for q in out["start"]):
            continue
        if max_per_event is not None and per_event.get(code, 0) >= max_per_event:
            continue
        per_event[code] = per_event.get(code, 0) + 1
        for name, value in zip(out, (s, code, a, b), strict=True):
            out[name].append(value)
    return EventPlacement(*(np.asarray(out[n], dtype=np.int64) for n in out))


# ----------------------------------------------------------------------------------------------
# Schedule files: id,start_s,length_s
# ----------------------------------------------------------------------------------------------
SCHEDULE_HEADER = ("id", "start_s", "length_s")
#: The optional fourth column: satellites kept during the outage (0-3 or more; 0 = complete).
KEPT_COLUMN = "satellites_kept"


class ScheduleError(ValueError):
    """A malformed outage schedule file (the message names the file, line and expectation)."""


class Schedule(NamedTuple):
    id: tuple[str, ...]
    start_s: np.ndarray  # [n] start relative to the first epoch [s]
    length_s: np.ndarray  # [n] [s]
    satellites_kept: np.ndarray | None = None  # [n] int (0 = complete outage); None: column
    # absent, every outage complete


def _number(path, line_no, field, text, positive: bool):
    try:
        value = float(text)
    except ValueError:
        raise ScheduleError(
            f"{path}:{line_no}: {field}: expected a number of seconds, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise ScheduleError(f"{path}:{line_no}: {field}: expected a finite number, got {text!r}")
    if positive and value <= 0:
        raise ScheduleError(f"{path}:{line_no}: {field}: expected a value > 0 s, got {text!r}")
    if not positive and value < 0:
        raise ScheduleError(f"{path}:{line_no}: {field}: expected a value >= 0 s, got {text!r}")
    return value


def read_schedule(path: str | os.PathLike, *, allow_overlap: bool = True) -> Schedule:
    """Read an ``id,start_s,length_s[,satellites_kept]`` CSV (header line first; blank and
    ``#`` lines ignored); the optional column gives the satellites kept during each outage.

    Rejects, naming file and line: a wrong header, a wrong number of fields, an empty or
    duplicate id, a non-numeric / non-finite / negative start, a length <= 0, a kept count
    that is no whole number >= 0, and (with ``allow_overlap=False``, for outages sharing one
    run) overlapping windows. Independent scenarios of a sweep may overlap in time, hence the
    default.
    """
    path = Path(path)
    ids, starts, lengths, kept, lines = [], [], [], [], []
    header = None
    with path.open(newline="") as f:
        for line_no, row in enumerate(csv.reader(f), start=1):
            if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
                continue
            fields = [c.strip() for c in row]
            if header is None:
                if tuple(fields) not in (SCHEDULE_HEADER, (*SCHEDULE_HEADER, KEPT_COLUMN)):
                    raise ScheduleError(
                        f"{path}:{line_no}: expected the header line "
                        f"{','.join(SCHEDULE_HEADER)!r} (optionally with "
                        f"',{KEPT_COLUMN}'), got {','.join(fields)!r}"
                    )
                header = tuple(fields)
                continue
            if len(fields) != len(header):
                raise ScheduleError(
                    f"{path}:{line_no}: expected {len(header)} fields ({','.join(header)}), "
                    f"got {len(fields)}: {','.join(fields)!r}"
                )
            oid = fields[0]
            if not oid:
                raise ScheduleError(f"{path}:{line_no}: id: expected a non-empty id")
            if oid in ids:
                first = lines[ids.index(oid)]
                raise ScheduleError(
                    f"{path}:{line_no}: id: expected unique ids, {oid!r} already used on line "
                    f"{first}"
                )
            ids.append(oid)
            starts.append(_number(path, line_no, "start_s", fields[1], positive=False))
            lengths.append(_number(path, line_no, "length_s", fields[2], positive=True))
            if len(header) == 4:
                if not fields[3].isdigit():
                    raise ScheduleError(f"{path}:{line_no}: {KEPT_COLUMN}: expected a whole "
                                        f"number >= 0 of satellites, got {fields[3]!r}")
                kept.append(int(fields[3]))
            lines.append(line_no)
    if header is None:
        raise ScheduleError(
            f"{path}:1: expected the header line {','.join(SCHEDULE_HEADER)!r}, got an empty file"
        )
    if not allow_overlap:
        order = np.argsort(starts, kind="stable")
        for i, j in zip(order[:-1], order[1:], strict=True):
            if starts[i] + lengths[i] > starts[j]:
                raise ScheduleError(
                    f"{path}:{lines[j]}: expected non-overlapping outages, {ids[j]!r} starts at "
                    f"{starts[j]} s before {ids[i]!r} (line {lines[i]}) ends at "
                    f"{starts[i] + lengths[i]} s"
                )
    return Schedule(tuple(ids), np.asarray(starts, float), np.asarray(lengths, float),
                    np.asarray(kept, np.int64) if len(header) == 4 else None)


def write_schedule(
    path: str | os.PathLike,
    ids: Sequence,
    start_s,
    length_s,
    *,
    overwrite: bool = False,
) -> None:
    """Write an ``id,start_s,length_s`` CSV (floats in shortest round-trip form); an existing
    file is only replaced with ``overwrite=True``."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    ids = [str(i) for i in ids]
    start_s = np.asarray(start_s, float).reshape(-1)
    length_s = np.asarray(length_s, float).reshape(-1)
    if not len(ids) == start_s.size == length_s.size:
        raise ValueError(
            f"ids, start_s and length_s differ in length: {len(ids)}, {start_s.size}, "
            f"{length_s.size}"
        )
    for i in ids:
        if not i or "," in i or i != i.strip() or "\n" in i:
            raise ValueError(f"id {i!r}: expected a non-empty id without commas or spaces")
    with path.open("w", newline="") as f:
        f.write(",".join(SCHEDULE_HEADER) + "\n")
        for i, s, n in zip(ids, start_s, length_s, strict=True):
            f.write(f"{i},{float(s)!r},{float(n)!r}\n")


def schedule_to_epochs(schedule: Schedule, epoch_interval_s: float, n_epochs: int | None = None):
    """Start epochs and lengths [epochs] of a schedule (times must be whole epochs, within
    1e-6 of an interval; with ``n_epochs`` every window must end inside the drive)."""
    out = []
    for name, values in (("start_s", schedule.start_s), ("length_s", schedule.length_s)):
        q = np.asarray(values, float) / epoch_interval_s
        r = np.round(q)
        bad = np.flatnonzero(np.abs(q - r) > 1e-6)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"outage {schedule.id[i]!r}: {name} = {values[i]} s is not a whole number of "
                f"{epoch_interval_s} s epochs"
            )
        out.append(r.astype(np.int64))
    start, length = out
    if n_epochs is not None:
        over = np.flatnonzero(start + length > n_epochs)
        if over.size:
            i = int(over[0])
            raise ValueError(
                f"outage {schedule.id[i]!r} ends at epoch {start[i] + length[i]}, after the "
                f"drive's {n_epochs} epochs"
            )
    return start, length
