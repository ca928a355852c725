"""A sweep's files: chunk .npz files beside a manifest (config hash), written atomically, and the
xarray Dataset assembled from them (``results.nc``)."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from xarray.indexes import PandasIndex

import jaxnav
from jaxnav.core import gpstime
from jaxnav.study import metrics as mt
from jaxnav.study.config import ALL
from jaxnav.study.plan import DIMS, Plan

#: The ``solution`` coordinate of a study with ``smooth = true``.
SOLUTIONS = ("forward", "smoothed")

RESULTS_FILE = "results.nc"
MANIFEST_FILE = "manifest.json"
CHUNK_DIR = "chunks"
METRIC_FIELDS = mt.WindowMetrics._fields
#: (units, long_name) of each metric in results.nc (CF conventions; jaxnav.study.metrics).
METRIC_ATTRS = {
    "max_2d_m": ("m", "maximum horizontal error in the outage window"),
    "rms_2d_m": ("m", "RMS horizontal error in the outage window"),
    "max_3d_m": ("m", "maximum 3D error in the outage window"),
    "end_2d_m": ("m", "horizontal error at the last outage epoch"),
    "end_enu_m": ("m", "east, north, up error at the last outage epoch"),
    "distance_m": ("m", "distance travelled during the outage"),
    "pct_of_distance": ("percent", "maximum horizontal error as a share of the distance"),
    "max_azimuth_err_rad": ("rad", "maximum azimuth error in the outage window"),
    "pre_2d_rms_m": ("m", "horizontal RMS error before the outage (metrics.pre_s)"),
    "reconv_threshold_m": ("m", "re-convergence threshold of the scenario"),
    "reconv_s": ("s", "re-convergence time after the outage (NaN: not within recovery_s)"),
    "reconverged": ("1", "re-converged within the recovery period"),
    "nees_pos": ("1", "mean position NEES over the outage window (3 dof)"),
    "nees_posvel": ("1", "mean position and velocity NEES over the outage window (6 dof)"),
}
_UNITS = {k: u for k, (u, _) in METRIC_ATTRS.items()}
#: NetCDF conventions the results follow (a test checks the attributes they require).
CONVENTIONS = "CF-1.10"


# ----------------------------------------------------------------------------------------------
# Persistence
# ----------------------------------------------------------------------------------------------
class StoreError(OSError):
    """A sweep folder that cannot be used as asked; the message names the file and what to do."""


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
            raise StoreError(
                "pass either resume (reuse what the folder holds) or overwrite (discard it), "
                "not both"
            )
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
            old = self._read_manifest()
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

    def _read_manifest(self) -> dict:
        """The folder's manifest; a damaged one is rebuilt when every chunk is this study's."""
        try:
            old = json.loads(self.manifest_path.read_text())
            if not isinstance(old, dict):
                raise ValueError(f"a JSON {type(old).__name__}, not an object")
            return old
        except (OSError, UnicodeDecodeError, ValueError) as e:
            reason = f"{type(e).__name__}: {e}"
        hashes = {self._chunk_hash(p) for p in self._chunk_files()}
        if hashes == {self.hash}:
            warnings.warn(
                f"{self.manifest_path} is damaged ({reason}); every chunk file belongs to this "
                "study, so the manifest is written again",
                stacklevel=4,
            )
            _atomic_write_text(self.manifest_path, json.dumps(self.manifest, indent=1))
            return dict(self.manifest)
        raise StoreError(
            f"{self.manifest_path}: damaged ({reason}) and the chunk files do not all carry this "
            "study's hash, so which study the folder holds cannot be told: use another "
            "directory or --overwrite"
        )

    @staticmethod
    def _chunk_hash(path: Path) -> str | None:
        try:
            with np.load(path) as z:
                return str(z["config_hash"])
        except Exception:  # noqa: BLE001  (any damage: the caller reports the file)
            return None

    def verify(self, sizes: dict[tuple[int, int], int]) -> None:
        """Check every existing chunk before any work: this study's, in its plan, readable.

        ``sizes`` maps (group, chunk) of the plan to its number of scenarios. A damaged or
        foreign chunk is reported with its file now, not after the missing ones are computed.
        """
        for g, j in sorted(self.done()):
            if (g, j) not in sizes:
                raise StoreError(
                    f"{self.chunk_path(g, j)}: chunk {j} of group {g} is not in this study's plan "
                    f"({len({k[0] for k in sizes})} groups x "
                    f"{1 + max(k[1] for k in sizes)} chunks); remove it or use --overwrite"
                )
            self.read_chunk(g, j, sizes[(g, j)])

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
            raise StoreError(
                f"{path}: cannot read the chunk ({type(e).__name__}: {e}); delete it and resume "
                "(it is computed again)"
            ) from e
        try:
            ok = (str(data["config_hash"]) == self.hash and int(data["group"]) == g
                  and int(data["chunk"]) == j and data["max_2d_m"].shape[0] == n
                  and all(k in data for k in METRIC_FIELDS))
        except (KeyError, TypeError, ValueError, IndexError):
            ok = False
        if not ok:
            raise StoreError(
                f"{path}: not chunk {j} of group {g} of this study ({self.hash[:12]}, {n} "
                "scenarios); delete it and resume (it is computed again)"
            )
        return data


def _atomic_write_text(path: Path, text: str):
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


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
        sol = ("solution",) if cfg.smooth else ()
        dims = DIMS + sol + (("enu",) if a.ndim > len(DIMS) + len(sol) else ())
        units, long_name = METRIC_ATTRS.get(k, ("1", k))
        attrs = {"units": units, "long_name": long_name}
        if a.dtype == bool:  # CF flags: NetCDF stores booleans as 0 / 1
            attrs = {"long_name": long_name, "flag_values": np.array([0, 1], np.int8),
                     "flag_meanings": "false true"}
        data_vars[k] = xr.Variable(dims, a, attrs)
    dt = float(plan.timeline.epoch_dt_s)
    coords = {
        "mode": ("mode", np.asarray(cfg.modes, dtype=object), {"long_name": "PPP mode"}),
        "system": ("system", np.asarray(cfg.systems, dtype=object),
                   {"long_name": "navigation system"}),
        "realization": ("realization", plan.seeds,
                        {"units": "1", "long_name": "noise realization seed"}),
        "duration": ("duration", plan.duration_s,
                     {"units": "s", "long_name": "outage duration (-1: per placement, length_s)"}),
        "satellites_kept": ("satellites_kept", plan.n_keep,
                            {"units": "1", "long_name": "satellites kept during the outage "
                             "(-1: all, no outage)"}),
        "placement": ("placement", np.arange(plan.starts.shape[1]),
                      {"units": "1", "long_name": "outage placement index"}),
        "policy": ("policy", np.asarray(cfg.policies, dtype=object),
                   {"long_name": "which satellites an outage keeps"}),
        "ramp": ("ramp", plan.ramps * dt,
                 {"units": "s", "long_name": "gradual degradation before and after the outage"}),
        "enu": ("enu", np.asarray(["east", "north", "up"], dtype=object),
                {"long_name": "local-level axis"}),
        **({"solution": ("solution", np.asarray(SOLUTIONS, dtype=object),
                         {"long_name": "forward filter, or forward + RTS smoother over the "
                                       "scenario window"})} if cfg.smooth else {}),
        "start_s": (("duration", "placement"), plan.starts * dt,
                    {"units": "s", "long_name": "outage start after the first epoch"}),
        "length_s": (("duration", "placement"), plan.lengths * dt,
                     {"units": "s", "long_name": "outage length"}),
    }
    if plan.timeline.t0_gps_s is not None:
        t_gps_s = plan.timeline.t0_gps_s + plan.starts * dt
        coords["start_time"] = (("duration", "placement"), gpstime.gps_seconds_to_datetime64(
            t_gps_s), {"long_name": "GPS time (GPST, no leap seconds) of the outage's first "
                       "epoch", "comment": "written as the CF standard calendar; subtract the "
                       "GPS-UTC leap seconds (18 s since 2017) for UTC"})
    if plan.placement_event is not None:
        coords["placement_event"] = ("placement", np.asarray(plan.placement_event, dtype=object),
                                     {"long_name": "drive event the outage starts on"})
    if plan.placement_id is not None:
        coords["placement_id"] = ("placement", np.asarray(plan.placement_id, dtype=object),
                                  {"long_name": "outage id of the schedule file"})
    ds = xr.Dataset(data_vars, coords)
    if traces:
        g_idx = np.array([t[0] for t in traces])
        flat = np.array([t[1] for t in traces])
        f = plan.scenarios(flat)
        r, d, k, p, pol, rm = np.unravel_index(flat, plan.shape)
        L = plan.prefix + plan.window
        t_rel = (np.arange(L)[None, :] - plan.prefix - f["ramp"][:, None]) * dt
        ds["trace_err_enu_m"] = xr.Variable(
            ("trace",) + (("solution",) if cfg.smooth else ()) + ("trace_epoch", "enu"),
            np.stack([t[2] for t in traces]),
            {"units": "m", "long_name": "estimate - truth, ENU, per epoch (NaN after recovery)"},
        )
        def one(long_name, units=None):
            return {"long_name": long_name} | ({"units": units} if units else {})

        ds = ds.assign_coords(
            trace=("trace", np.arange(len(traces)), one("kept error trace index", "1")),
            trace_epoch=("trace_epoch", np.arange(L), one("epoch of the trace window", "1")),
            trace_time_s=(("trace", "trace_epoch"), t_rel,
                          one("time since the outage start", "s")),
            trace_mode=("trace", np.asarray([cfg.modes[i // n_sys] for i in g_idx], object),
                        one("PPP mode of the trace")),
            trace_system=("trace", np.asarray([cfg.systems[i % n_sys] for i in g_idx], object),
                          one("navigation system of the trace")),
            trace_realization=("trace", plan.seeds[r], one("noise realization seed", "1")),
            trace_duration=("trace", plan.duration_s[d], one("outage duration axis value", "s")),
            trace_satellites_kept=("trace", plan.n_keep[k],
                                   one("satellites kept (-1: all)", "1")),
            trace_placement=("trace", p, one("outage placement index", "1")),
            trace_policy=("trace", np.asarray([cfg.policies[i] for i in pol], object),
                          one("satellites-kept policy")),
            trace_ramp_s=("trace", plan.ramps[rm] * dt, one("ramp length", "s")),
            trace_outage_s=("trace", f["length"] * dt, one("outage length", "s")),
        )
    ds.attrs.update(
        {
            "Conventions": CONVENTIONS,
            "title": f"jaxnav outage sweep {cfg.name!r}",
            "source": f"jaxnav {jaxnav.__version__} Monte-Carlo outage sweep",
            "references": "docs/models.md, docs/simulation.md of the jaxnav repository",
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
    return with_kept_index(ds)


class KeptIndex(PandasIndex):
    """Index of ``satellites_kept`` that also takes the label ``"all"`` (stored as -1, the
    no-outage reference) and digit strings, so ``ds.sel(satellites_kept="all")`` and
    ``ds.sel(satellites_kept=[2, "all"])`` work; the coordinate stays int64 on disk."""

    @staticmethod
    def _label(v):
        if isinstance(v, str):
            if v.strip().lower() == "all":
                return ALL
            if v.strip().lstrip("-").isdigit():
                return int(v)
            raise KeyError(f"satellites_kept label {v!r}: allowed are integers and 'all'")
        return v

    def sel(self, labels, method=None, tolerance=None):
        def conv(v):
            if isinstance(v, (str, int, np.integer)):
                return self._label(v)
            if isinstance(v, (slice, xr.DataArray, xr.Variable)):
                return v
            a = np.asarray(v, dtype=object)
            return np.vectorize(self._label, otypes=[np.int64])(a) if a.size else v

        return super().sel({k: conv(v) for k, v in labels.items()}, method, tolerance)


def with_kept_index(ds: xr.Dataset) -> xr.Dataset:
    """Give ``satellites_kept`` the :class:`KeptIndex` (label ``"all"`` = -1)."""
    if "satellites_kept" not in ds.indexes or isinstance(
            ds.xindexes["satellites_kept"], KeptIndex):
        return ds
    return ds.drop_indexes("satellites_kept").set_xindex("satellites_kept", KeptIndex)


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
    """Read a sweep's results.nc into memory, with ``satellites_kept`` selectable by "all"
    (a plain ``xr.open_dataset`` gives the stored int index, where "all" is -1)."""
    return with_kept_index(xr.load_dataset(path, engine=netcdf_engine()))
