"""Typed study definitions (a Monte-Carlo outage sweep), loaded from TOML and validated.

A study is data (DESIGN invariant 7): the axes of the scenario grid, the placement of the
outages along the drive, the recovery period evaluated after each outage, the metric parameters
and the engine's chunk size. Example::

    [study]
    name = "demo"
    modes = ["sf_code", "df_code", "sdf_code", "float_ppp"]
    systems = ["riss"]                 # system / sensor-grade labels of the scenario factory
    durations_s = [60]
    satellites_kept = [0, 1, 2, 3, "all"]
    policies = ["highest"]             # jaxnav.study.outages.POLICIES
    ramps_s = [0]                      # gradual degradation before and after (S002)
    realizations = 4                   # noise realizations: seeds seed .. seed + n - 1
    seed = 0
    recovery_s = 60                    # evaluated after each outage (re-convergence)
    chunk_size = 64                    # scenarios per engine chunk (bounds memory)
    max_traces = 100                   # per (mode, system): per-epoch error kept for plots
    metric_window = "core"             # "core" or "with_ramp"
    smooth = false                     # also RTS-smoothed metrics (a "solution" dimension)

    [placement]
    kind = "grid"                      # grid | random | events | schedule
    convergence_s = 300                # no outage (or ramp) before this time
    spacing_s = 120                    # grid
    # count = 20, min_spacing_s = 90   # random (seeded by [study] seed)
    # events = ["turn", "straight", "stop", "slope"], max_per_event = 2   # events
    # file = "outages.csv"             # schedule: id,start_s,length_s (relative to the TOML)

    [metrics]                          # jaxnav.study.metrics.MetricConfig
    reconv_threshold_m = 0.2
    reconv_factor = 2.0
    pre_s = 10
    min_distance_m = 1.0

    [scenario]                         # the scenario factory's table (study.factory)
    duration_s = 900                   # simulated drive length
    drive_style = "mixed"              # mixed | urban | suburban | highway | circuit | airborne

Every error names the key, the offending value and what is allowed (``ConfigError``). Values
in seconds are converted to epochs by the engine, which checks they are whole epochs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jaxnav.core import schema
from jaxnav.study import outages

#: ``satellites_kept`` value meaning "no outage" (``outages.ALL``); written "all" in TOML.
ALL = outages.ALL
PLACEMENT_KINDS = ("grid", "random", "events", "schedule")
METRIC_WINDOWS = ("core", "with_ramp")
EVENT_NAMES = ("straight", "turn", "stop", "slope", "speed_change")


class ConfigError(schema.SchemaError):
    """An invalid study definition; the message names the key, the value and what is allowed."""


@dataclass(frozen=True)
class PlacementConfig:
    """Where outages start along the drive (``jaxnav.study.outages`` generators)."""

    kind: str = "grid"
    # chosen: 300 s lets a float PPP / INS filter converge before the first outage (S002 ch.4
    # excludes the first 5 min from its RMS).
    convergence_s: float = 300.0
    spacing_s: float = 120.0  # grid: chosen, two outage lengths of 60 s apart
    count: int = 10  # random: number of placements
    min_spacing_s: float = 0.0  # random / events: minimum distance between starts
    events: tuple[str, ...] = ("turn", "straight", "stop", "slope")  # seed 000's four kinds
    max_per_event: int | None = None  # events: cap per kind (None = every run of the label)
    min_event_s: float = 1.0  # events: shorter runs of a label are ignored
    file: str | None = None  # schedule: path of an id,start_s,length_s file


@dataclass(frozen=True)
class MetricsConfig:
    """Metric parameters (``jaxnav.study.metrics.MetricConfig``; reasons documented there)."""

    reconv_threshold_m: float = 0.2  # S002 ch.5: re-convergence to 20 cm
    reconv_factor: float = 2.0  # chosen (metrics.MetricConfig)
    pre_s: float = 10.0  # chosen: pre-outage error averaged over 10 s
    min_distance_m: float = 1.0  # chosen: % of distance is NaN below 1 m (a stop)


@dataclass(frozen=True)
class StudyConfig:
    """One sweep: the scenario axes and the engine settings (module docstring: the TOML)."""

    modes: tuple[str, ...]
    systems: tuple[str, ...]
    durations_s: tuple[float, ...] = (60.0,)
    satellites_kept: tuple[int, ...] = (0, 1, 2, 3, ALL)
    name: str = "study"
    policies: tuple[str, ...] = (outages.DEFAULT_POLICY,)
    ramps_s: tuple[float, ...] = (0.0,)
    realizations: int = 1
    seed: int = 0
    recovery_s: float = 60.0  # chosen: one minute shows the re-convergence of code modes
    # chosen: 64. Bounds memory; also, chunks of >~108 scenarios stalled jaxlib's batched
    # matrix solve on 2 CPU cores (all threads parked), with jax/jaxlib 0.10.2.
    chunk_size: int = 64
    max_traces: int = 100  # chosen: 20 runs per curve at 5 levels, for a 10-90 % band
    metric_window: str = "core"
    # Also the RTS-smoothed solution's metrics, beside the forward filter's (a ``solution``
    # dimension of the Dataset: "forward", "smoothed"); jaxnav.study.sweep docstring.
    smooth: bool = False
    placement: PlacementConfig = field(default_factory=PlacementConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    scenario: tuple[tuple[str, Any], ...] = ()  # free-form [scenario] table, sorted items

    @property
    def realization_seeds(self) -> tuple[int, ...]:
        """Seed of each noise realization: seed, seed + 1, ..."""
        return tuple(self.seed + i for i in range(self.realizations))

    @property
    def scenario_dict(self) -> dict[str, Any]:
        return _thaw(self.scenario)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able form ("all" for ALL), the inverse of ``from_dict``."""
        d = dataclasses.asdict(self)
        d["satellites_kept"] = ["all" if k == ALL else k for k in self.satellites_kept]
        d["scenario"] = self.scenario_dict
        if not d["smooth"]:  # a key added with a default leaves older studies' hashes as they were
            del d["smooth"]
        return _jsonable(d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    def hash(self, extra: str = "") -> str:
        """sha256 of the canonical JSON (plus ``extra``, e.g. the factory's fingerprint)."""
        return hashlib.sha256((self.to_json() + "\n" + extra).encode()).hexdigest()

    def replace(self, **changes) -> StudyConfig:
        """Copy with changed fields, validated again."""
        return validate(dataclasses.replace(self, **changes))


# ----------------------------------------------------------------------------------------------
# Loading and validation
# ----------------------------------------------------------------------------------------------
_SECTIONS = ("study", "placement", "metrics", "scenario")
MAX_REALIZATIONS = 1_000_000  # chosen bound (see the rule below)
MAX_CHUNK = 4096  # benchmarks/RESULTS.md: batch_max 4096 (per-scenario time flat beyond ~16)


def _jsonable(x):
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    return x


def _freeze(x):
    """Nested mappings / lists to sorted tuples (hashable, order-independent)."""
    if isinstance(x, Mapping):
        return tuple(sorted((str(k), _freeze(v)) for k, v in x.items()))
    if isinstance(x, list | tuple):
        return ("__list__",) + tuple(_freeze(v) for v in x)
    return x


def _thaw(x):
    if isinstance(x, tuple) and x and x[0] == "__list__":
        return [_thaw(v) for v in x[1:]]
    if isinstance(x, tuple):
        return {k: _thaw(v) for k, v in x}
    return x


def _fail(key: str, value, expected: str):
    schema.fail(key, value, expected, ConfigError)


def _labels(allowed: Sequence[str] | None) -> schema.Rule:
    """The factory's labels (a declared table) or, without a factory, any non-empty string."""
    return schema.items(schema.text() if allowed is None else schema.choice(allowed))


_SECONDS = schema.number(0, unit="seconds")
_POSITIVE_SECONDS = schema.number(0, strict=True, unit="seconds")
_METRES = schema.number(0, strict=True, unit="metres")
_KEPT = schema.either(schema.whole(0), schema.literal("all"))

_PLACEMENT_SCHEMA = {
    "kind": schema.choice(PLACEMENT_KINDS),
    "convergence_s": _SECONDS,
    "spacing_s": _POSITIVE_SECONDS,
    "count": schema.whole(1),
    "min_spacing_s": _SECONDS,
    "events": schema.items(schema.choice(EVENT_NAMES)),
    "max_per_event": schema.whole(1),
    "min_event_s": _POSITIVE_SECONDS,
    "file": schema.text(),
}
#: placement keys that only one kind uses
_PLACEMENT_USED_BY = {"spacing_s": ("grid",), "count": ("random",), "file": ("schedule",),
                      "events": ("events",), "max_per_event": ("events",),
                      "min_event_s": ("events",), "min_spacing_s": ("random", "events")}
_METRICS_SCHEMA = {
    "reconv_threshold_m": _METRES,
    "reconv_factor": schema.number(0),
    "pre_s": _SECONDS,
    "min_distance_m": _METRES,
}


def _study_schema(modes, systems) -> dict[str, schema.Rule]:
    return {
        "name": schema.text(),
        "modes": _labels(modes),
        "systems": _labels(systems),
        "durations_s": schema.items(_POSITIVE_SECONDS),
        "satellites_kept": schema.items(_KEPT),
        "policies": schema.items(schema.choice(outages.POLICIES)),
        "ramps_s": schema.items(_SECONDS),
        "realizations": schema.whole(1, MAX_REALIZATIONS, "a million full-drive runs per mode "
                                    "and system is days of CPU; more is a typo"),
        "seed": schema.whole(0),
        "recovery_s": _SECONDS,
        "chunk_size": schema.whole(1, MAX_CHUNK, "the largest batch benchmarks/scaling.py "
                                  "measured"),
        "max_traces": schema.whole(0),
        "metric_window": schema.choice(METRIC_WINDOWS),
        "smooth": schema.boolean(),
    }


_STUDY_KEYS = tuple(_study_schema(None, None))


def _placement(t: Mapping, base_dir: Path | None) -> PlacementConfig:
    out = schema.check_section("placement", t, _PLACEMENT_SCHEMA, error=ConfigError)
    kind = out.setdefault("kind", "grid")
    if kind == "schedule":
        if "file" not in out:
            _fail("placement.file", None, "a schedule file when placement.kind = 'schedule'")
        p = Path(out["file"])
        if base_dir is not None and not p.is_absolute():
            p = base_dir / p
        out["file"] = str(p)
        if not p.is_file():
            _fail("placement.file", out["file"], "an existing id,start_s,length_s file")
    for k, used_by in _PLACEMENT_USED_BY.items():
        if k in out and kind not in used_by:
            kinds = " and ".join(repr(u) for u in used_by)
            _fail(f"placement.{k}", t[k], f"no value: it is used only by kind {kinds}")
    return PlacementConfig(**out)


def from_dict(
    data: Mapping,
    *,
    base_dir: str | os.PathLike | None = None,
    modes: Sequence[str] | None = None,
    systems: Sequence[str] | None = None,
) -> StudyConfig:
    """Build and validate a StudyConfig from the TOML tables (``modes`` / ``systems``: the
    labels the scenario factory accepts; None = any non-empty string)."""
    schema.check_sections(data, _SECTIONS, ConfigError)
    if "study" not in data:
        raise ConfigError("missing section [study] (with at least modes and systems)")
    out = schema.check_section("study", data["study"], _study_schema(modes, systems),
                               required=("modes", "systems"), error=ConfigError)
    if "satellites_kept" in out:
        out["satellites_kept"] = tuple(ALL if k == "all" else k for k in out["satellites_kept"])
    base = None if base_dir is None else Path(base_dir)
    out["placement"] = _placement(data.get("placement", {}), base)
    out["metrics"] = MetricsConfig(**schema.check_section(
        "metrics", data.get("metrics", {}), _METRICS_SCHEMA, error=ConfigError))
    out["scenario"] = _freeze(dict(data.get("scenario", {})))
    if out["placement"].kind == "schedule" and "durations_s" in out:
        _fail("study.durations_s", data["study"]["durations_s"],
              "no value when placement.kind = 'schedule' (the file gives each length)")
    return validate(StudyConfig(**out), modes=modes, systems=systems)


def validate(
    cfg: StudyConfig, *, modes: Sequence[str] | None = None, systems: Sequence[str] | None = None
) -> StudyConfig:
    """Cross-field checks on a StudyConfig (and the factory's labels); returns it."""
    for key, labels in (("modes", modes), ("systems", systems)):
        schema.check_section("study", {key: list(getattr(cfg, key))},
                             {key: _labels(labels)}, error=ConfigError)
    if cfg.seed + cfg.realizations >= 2**31:
        _fail("study.seed", cfg.seed, f"seed + realizations < 2**31 (realizations = "
              f"{cfg.realizations})")
    if cfg.metric_window not in METRIC_WINDOWS:
        _fail("study.metric_window", cfg.metric_window,
              f"one of {', '.join(map(repr, METRIC_WINDOWS))}")
    return cfg


def loads(
    text: str,
    *,
    base_dir: str | os.PathLike | None = None,
    modes: Sequence[str] | None = None,
    systems: Sequence[str] | None = None,
    source: str = "<string>",
) -> StudyConfig:
    """Parse a TOML study definition (module docstring)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML: {e}") from None
    try:
        return from_dict(data, base_dir=base_dir, modes=modes, systems=systems)
    except ConfigError as e:
        raise ConfigError(f"{source}: {e}") from None


def load(
    path: str | os.PathLike,
    *,
    modes: Sequence[str] | None = None,
    systems: Sequence[str] | None = None,
) -> StudyConfig:
    """Read a TOML study definition; relative schedule paths are resolved against its folder."""
    path = Path(path)
    return loads(path.read_text(), base_dir=path.parent, modes=modes, systems=systems,
                 source=str(path))


def from_json(text: str) -> StudyConfig:
    """Inverse of ``StudyConfig.to_json`` (e.g. from a results file's attributes)."""
    d = json.loads(text)
    study = {k: d[k] for k in _STUDY_KEYS if k in d}
    placement = {k: v for k, v in d.get("placement", {}).items() if v is not None}
    if placement.get("kind") != "schedule":
        placement.pop("file", None)
    kind = placement.get("kind", "grid")
    for k, used in (("spacing_s", "grid"), ("count", "random")):
        if kind != used:
            placement.pop(k, None)
    if kind != "events":
        for k in ("events", "max_per_event", "min_event_s"):
            placement.pop(k, None)
    if kind != "random" and kind != "events":
        placement.pop("min_spacing_s", None)
    if kind == "schedule":
        study.pop("durations_s", None)
    return from_dict(
        {"study": study, "placement": placement, "metrics": d.get("metrics", {}),
         "scenario": d.get("scenario", {})}
    )
