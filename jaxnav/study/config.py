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
    max_traces = 16                    # per (mode, system): per-epoch error kept for plots
    metric_window = "core"             # "core" or "with_ramp"

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

    [scenario]                         # free-form, passed to the scenario factory
    drive = "kingston"

Every error names the key, the offending value and what is allowed (``ConfigError``). Values
in seconds are converted to epochs by the engine, which checks they are whole epochs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from jaxnav.study import outages

#: ``satellites_kept`` value meaning "no outage" (``outages.ALL``); written "all" in TOML.
ALL = outages.ALL
PLACEMENT_KINDS = ("grid", "random", "events", "schedule")
METRIC_WINDOWS = ("core", "with_ramp")
EVENT_NAMES = ("straight", "turn", "stop", "slope", "speed_change")


class ConfigError(ValueError):
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
    max_traces: int = 16  # chosen: enough curves for one error-growth figure per mode
    metric_window: str = "core"
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
    raise ConfigError(f"{key} = {value!r}: expected {expected}")


def _is_num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _seconds(key, v, *, positive: bool):
    if not _is_num(v) or (v <= 0 if positive else v < 0):
        _fail(key, v, "a number of seconds " + ("> 0" if positive else ">= 0"))
    return float(v)


def _nonempty_list(key, v):
    if not isinstance(v, list | tuple) or len(v) == 0:
        _fail(key, v, "a non-empty list")
    return list(v)


def _unique(key, values):
    seen = set()
    for i, v in enumerate(values):
        if v in seen:
            _fail(f"{key}[{i}]", v, "distinct values (duplicate)")
        seen.add(v)
    return values


def _choices(key, v, allowed: Sequence[str] | None):
    """A non-empty list of distinct strings, each in ``allowed`` (when given)."""
    out = []
    for i, s in enumerate(_nonempty_list(key, v)):
        if not isinstance(s, str) or not s:
            _fail(f"{key}[{i}]", s, "a non-empty string")
        if allowed is not None and s not in allowed:
            _fail(f"{key}[{i}]", s, f"one of {', '.join(map(repr, allowed))}")
        out.append(s)
    return tuple(_unique(key, out))


def _check_keys(section: str, table: Mapping, allowed: Sequence[str]):
    for k in table:
        if k not in allowed:
            raise ConfigError(
                f"unknown key {section}.{k} (value {table[k]!r}); allowed keys in [{section}]: "
                f"{', '.join(allowed)}"
            )


def _placement(t: Mapping, base_dir: Path | None) -> PlacementConfig:
    names = [f.name for f in dataclasses.fields(PlacementConfig)]
    _check_keys("placement", t, names)
    d = dict(t)
    kind = d.get("kind", "grid")
    if kind not in PLACEMENT_KINDS:
        _fail("placement.kind", kind, f"one of {', '.join(map(repr, PLACEMENT_KINDS))}")
    out: dict[str, Any] = {"kind": kind}
    if "convergence_s" in d:
        out["convergence_s"] = _seconds("placement.convergence_s", d["convergence_s"],
                                        positive=False)
    if "spacing_s" in d:
        out["spacing_s"] = _seconds("placement.spacing_s", d["spacing_s"], positive=True)
    if "min_spacing_s" in d:
        out["min_spacing_s"] = _seconds("placement.min_spacing_s", d["min_spacing_s"],
                                        positive=False)
    if "min_event_s" in d:
        out["min_event_s"] = _seconds("placement.min_event_s", d["min_event_s"], positive=True)
    if "count" in d:
        if not _is_int(d["count"]) or d["count"] < 1:
            _fail("placement.count", d["count"], "a whole number >= 1")
        out["count"] = d["count"]
    if "max_per_event" in d:
        if not _is_int(d["max_per_event"]) or d["max_per_event"] < 1:
            _fail("placement.max_per_event", d["max_per_event"], "a whole number >= 1")
        out["max_per_event"] = d["max_per_event"]
    if "events" in d:
        out["events"] = _choices("placement.events", d["events"], EVENT_NAMES)
    if "file" in d:
        f = d["file"]
        if not isinstance(f, str) or not f:
            _fail("placement.file", f, "the path of an id,start_s,length_s file")
        p = Path(f)
        if base_dir is not None and not p.is_absolute():
            p = base_dir / p
        out["file"] = str(p)
    if kind == "schedule" and "file" not in out:
        _fail("placement.file", None, "a schedule file when placement.kind = 'schedule'")
    if kind == "schedule" and not Path(out["file"]).is_file():
        _fail("placement.file", out["file"], "an existing id,start_s,length_s file")
    for k in ("spacing_s", "count", "events", "max_per_event", "min_event_s", "file"):
        used_by = {"spacing_s": ("grid",), "count": ("random",), "file": ("schedule",)}.get(
            k, ("events",)
        )
        if k in d and kind not in used_by:
            _fail(f"placement.{k}", d[k], f"no value: it is used only by kind {used_by[0]!r}")
    return PlacementConfig(**out)


def _metrics(t: Mapping) -> MetricsConfig:
    names = [f.name for f in dataclasses.fields(MetricsConfig)]
    _check_keys("metrics", t, names)
    out = {}
    for k, v in t.items():
        if k == "reconv_factor":
            if not _is_num(v) or v < 0:
                _fail("metrics.reconv_factor", v, "a number >= 0")
            out[k] = float(v)
        elif k == "pre_s":
            out[k] = _seconds("metrics.pre_s", v, positive=False)
        else:  # metres
            if not _is_num(v) or v <= 0:
                _fail(f"metrics.{k}", v, "a number of metres > 0")
            out[k] = float(v)
    return MetricsConfig(**out)


_STUDY_KEYS = (
    "name", "modes", "systems", "durations_s", "satellites_kept", "policies", "ramps_s",
    "realizations", "seed", "recovery_s", "chunk_size", "max_traces", "metric_window",
)


def from_dict(
    data: Mapping,
    *,
    base_dir: str | os.PathLike | None = None,
    modes: Sequence[str] | None = None,
    systems: Sequence[str] | None = None,
) -> StudyConfig:
    """Build and validate a StudyConfig from the TOML tables (``modes`` / ``systems``: the
    labels the scenario factory accepts; None = any non-empty string)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"expected a table of sections, got {type(data).__name__}")
    for k in data:
        if k not in _SECTIONS:
            raise ConfigError(
                f"unknown section or key [{k}]; allowed sections: {', '.join(_SECTIONS)}"
            )
        if not isinstance(data[k], Mapping):
            _fail(k, data[k], f"a [{k}] table")
    if "study" not in data:
        raise ConfigError("missing section [study] (with at least modes and systems)")
    s = dict(data["study"])
    _check_keys("study", s, _STUDY_KEYS)
    for k in ("modes", "systems"):
        if k not in s:
            raise ConfigError(f"missing key study.{k}")
    out: dict[str, Any] = {
        "modes": _choices("study.modes", s["modes"], modes),
        "systems": _choices("study.systems", s["systems"], systems),
    }
    if "name" in s:
        if not isinstance(s["name"], str) or not s["name"]:
            _fail("study.name", s["name"], "a non-empty string")
        out["name"] = s["name"]
    if "durations_s" in s:
        out["durations_s"] = tuple(
            _unique("study.durations_s", [
                _seconds(f"study.durations_s[{i}]", v, positive=True)
                for i, v in enumerate(_nonempty_list("study.durations_s", s["durations_s"]))
            ])
        )
    if "satellites_kept" in s:
        kept = []
        for i, v in enumerate(_nonempty_list("study.satellites_kept", s["satellites_kept"])):
            if v == "all":
                kept.append(ALL)
            elif _is_int(v) and v >= 0:
                kept.append(v)
            else:
                _fail(f"study.satellites_kept[{i}]", v, 'a whole number >= 0 or "all"')
        out["satellites_kept"] = tuple(_unique("study.satellites_kept", kept))
    if "policies" in s:
        out["policies"] = _choices("study.policies", s["policies"], outages.POLICIES)
    if "ramps_s" in s:
        out["ramps_s"] = tuple(
            _unique("study.ramps_s", [
                _seconds(f"study.ramps_s[{i}]", v, positive=False)
                for i, v in enumerate(_nonempty_list("study.ramps_s", s["ramps_s"]))
            ])
        )
    for k, lo in (("realizations", 1), ("seed", 0), ("chunk_size", 1), ("max_traces", 0)):
        if k in s:
            if not _is_int(s[k]) or s[k] < lo:
                _fail(f"study.{k}", s[k], f"a whole number >= {lo}")
            out[k] = s[k]
    if "recovery_s" in s:
        out["recovery_s"] = _seconds("study.recovery_s", s["recovery_s"], positive=False)
    if "metric_window" in s:
        if s["metric_window"] not in METRIC_WINDOWS:
            _fail("study.metric_window", s["metric_window"],
                  f"one of {', '.join(map(repr, METRIC_WINDOWS))}")
        out["metric_window"] = s["metric_window"]
    base = None if base_dir is None else Path(base_dir)
    out["placement"] = _placement(data.get("placement", {}), base)
    out["metrics"] = _metrics(data.get("metrics", {}))
    out["scenario"] = _freeze(dict(data.get("scenario", {})))
    if out["placement"].kind == "schedule" and "durations_s" in s:
        _fail("study.durations_s", s["durations_s"],
              "no value when placement.kind = 'schedule' (the file gives each length)")
    return validate(StudyConfig(**out), modes=modes, systems=systems)


def validate(
    cfg: StudyConfig, *, modes: Sequence[str] | None = None, systems: Sequence[str] | None = None
) -> StudyConfig:
    """Cross-field checks on a StudyConfig (and the factory's labels); returns it."""
    _choices("study.modes", list(cfg.modes), modes)
    _choices("study.systems", list(cfg.systems), systems)
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
