"""``jaxnav init``: a study TOML holding every key with its default and what it means.

The defaults are read from the dataclasses (``config.StudyConfig``, ``PlacementConfig``,
``MetricsConfig``) and the simulated factory's ``SCENARIO_DEFAULTS``, so the template cannot
drift from what a study without the key gets (tests/test_cli.py checks both). Keys that only
another placement kind uses are written commented out (a grid study refuses them).
"""

from __future__ import annotations

import dataclasses
import json

from jaxnav.study import config as sc
from jaxnav.study import factory

#: One line per key: what it is, its unit and where its values are listed.
_HELP = {
    "study.name": "label of the results (title of table.md)",
    "study.modes": "required: PPP modes, `jaxnav list modes`",
    "study.systems": "required: navigation systems, `jaxnav list systems`",
    "study.durations_s": "outage lengths [s]",
    "study.satellites_kept": "satellites left during an outage; \"all\" = no outage (reference)",
    "study.policies": "which satellites are kept: " + ", ".join(sc.outages.POLICIES),
    "study.ramps_s": "gradual loss and return of satellites before and after an outage [s]",
    "study.realizations": "noise realizations per scenario (seeds seed .. seed + n - 1)",
    "study.seed": "first noise seed",
    "study.recovery_s": "evaluated after each outage: re-convergence [s]",
    "study.chunk_size": "scenarios per engine chunk (bounds memory)",
    "study.max_traces": "per (mode, system): per-epoch error curves kept for error_growth.png",
    "study.metric_window": "\"core\" (the outage) or \"with_ramp\" (the ramps count as outage)",
    "study.smooth": "also the RTS-smoothed solution's metrics (a \"solution\" dimension)",
    "placement.kind": "where outages start: " + " | ".join(sc.PLACEMENT_KINDS),
    "placement.convergence_s": "no outage (or ramp) before this time [s]",
    "placement.spacing_s": "grid: distance between outage starts [s]",
    "placement.count": "random: number of placements (seeded by [study] seed)",
    "placement.min_spacing_s": "random / events: minimum distance between starts [s]",
    "placement.events": "events: drive labels to place outages on: " + ", ".join(sc.EVENT_NAMES),
    "placement.max_per_event": "events: at most this many outages per label (absent: all)",
    "placement.min_event_s": "events: shorter runs of a label are ignored [s]",
    "placement.file": "schedule: id,start_s,length_s file, relative to this TOML",
    "metrics.reconv_threshold_m": "re-converged below max(this, reconv_factor x pre-outage "
                                  "RMS) [m]",
    "metrics.reconv_factor": "see reconv_threshold_m",
    "metrics.pre_s": "pre-outage 2D RMS averaged over this time [s]",
    "metrics.min_distance_m": "below this distance travelled, % of distance is NaN [m]",
    "scenario.drive_seed": "seed of the simulated drive",
    "scenario.drive_style": "`jaxnav list drives`",
    "scenario.duration_s": "simulated drive length [s]",
    "scenario.imu_grade": "RISS sensors, `jaxnav list presets`",
    "scenario.ins_grade": "full IMU of the ins*/lc_* systems, `jaxnav list presets`",
    "scenario.odometer": "wheel odometer, `jaxnav list presets`",
    "scenario.iono_scale": "ionosphere activity relative to a quiet day (VTEC scale)",
    "scenario.constellations": ", ".join(factory._CONSTELLATIONS),
    "scenario.slots": "satellite slots per constellation (gps, glonass, galileo)",
    "scenario.bssd": "between-satellite single differences",
    "scenario.iono_model": "single-frequency ionosphere model: " + " | ".join(factory.IONO_MODELS),
    "scenario.environment": "cycle-slip and loss-of-lock rates: "
                            + " | ".join(factory.observations.SLIP_ENVIRONMENTS),
    "scenario.slip_flags": " | ".join(factory.scenario.SLIP_FLAGS)
                           + " (the real-data detector, or the simulator's true slips)",
    "scenario.lc_fix_errors": "LC systems: white or correlated PPP fix errors",
}
#: Placement keys a grid study must not set (``config._PLACEMENT_USED_BY``).
_OTHER_KINDS = ("count", "min_spacing_s", "events", "max_per_event", "min_event_s", "file")
#: The template's required values (no defaults exist for them).
_REQUIRED = {"modes": ("float_ppp",), "systems": ("riss",)}


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def _line(section: str, key: str, value, commented: bool = False) -> str:
    text = f"{'# ' if commented else ''}{key} = {_toml(value)}"
    return f"{text:38s} # {_HELP[f'{section}.{key}']}"


def study_template() -> str:
    """The commented TOML of a valid study (float_ppp / riss on the default simulated drive)
    that spells out every key's default."""
    study = {f.name: f.default for f in dataclasses.fields(sc.StudyConfig)
             if f.name not in ("placement", "metrics", "scenario")}
    study |= _REQUIRED
    study["satellites_kept"] = ["all" if k == sc.ALL else k for k in study["satellites_kept"]]
    order = ["name", "modes", "systems", *[k for k in study if k not in
                                           ("name", "modes", "systems")]]
    lines = ["# jaxnav study: `jaxnav sweep THIS.toml --out DIR` (--check validates only).",
             "# Every key with its default; keep the ones you change. Seconds are whole epochs.",
             "", "[study]"]
    lines += [_line("study", k, study[k]) for k in order]
    lines += ["", "[placement]"]
    for f in dataclasses.fields(sc.PlacementConfig):
        value = f.default if f.default is not None else {"max_per_event": 2,
                                                          "file": "outages.csv"}[f.name]
        lines.append(_line("placement", f.name, value, commented=f.name in _OTHER_KINDS))
    lines += ["", "[metrics]"]
    lines += [_line("metrics", f.name, f.default) for f in dataclasses.fields(sc.MetricsConfig)]
    lines += ["", "[scenario]                            # the simulated drive (study.factory)"]
    lines += [_line("scenario", k, v) for k, v in factory.SCENARIO_DEFAULTS.items()]
    return "\n".join(lines) + "\n"
