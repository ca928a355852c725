"""Golden outputs of whole runs: experiments' quick forms, the ESBC runs, the car drive, sweeps.

``check(name, values)`` compares a run's numbers with ``outputs/<name>.npz``: every array to
1e-6 of its own largest magnitude, integer and boolean arrays exactly, NaN where NaN was.
Tolerance: issue 15 asked for 1e-9, which holds on the machine that recorded the files but not
across CPUs: XLA's CPU code (vector width, FMA contraction, reduction order) rounds differently
on another processor, and on an AMD EPYC host (2026-12-04) every float array of the recorded
runs differed by up to 2.5e-7 of its scale (ESBC NIS; the rest 1e-9 to 5e-8) with every integer
(satellites used, gating decisions) and every position (1 um) unchanged. CI runs on whichever
machine a session gets, so 1e-6 (4x that spread) keeps the check machine-independent while a
change of a model, a noise figure or a gate still moves the outputs by far more. Limit: the
tolerance is relative to each array's largest entry, so the small entries of a mixed-scale array
(a covariance diagonal of m^2 and rad^2) are held loosely; a per-element tolerance would need
the cross-CPU spread of near-zero entries, which was not measured.

The numbers come from the files a run writes (``numbers_in``: each ``results.nc``'s data
variables, every ``*.json`` number, every ``*.npz`` array) or from the test's own arrays.
``JAXNAV_RECORD_GOLDENS=1 python -m pytest ...`` writes the files instead (and says so); do
that only for a change meant to alter the numbers, and give the size of the change and its
reason in the commit.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

DIR = Path(__file__).with_name("outputs")
RTOL = 1e-6  # module docstring: cross-CPU rounding reaches 2.5e-7
RECORD = os.environ.get("JAXNAV_RECORD_GOLDENS") == "1"


def _json_numbers(prefix: str, obj, out: dict):
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            _json_numbers(f"{prefix}.{k}", v, out)
    elif isinstance(obj, list) and obj and all(isinstance(v, int | float) and
                                               not isinstance(v, bool) for v in obj):
        out[prefix] = np.asarray(obj, float)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _json_numbers(f"{prefix}[{i}]", v, out)
    elif isinstance(obj, int | float) and not isinstance(obj, bool):
        out[prefix] = np.asarray(float(obj))


#: the sweep engine's own state (its chunks repeat results.nc; the manifest is bookkeeping)
ENGINE_STATE = ("chunks/", "manifest.json")


def numbers_in(folder: Path, skip: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The numeric content of the files a run wrote under ``folder`` (keys: relative path and
    variable), without the engine's state; ``skip``: more name fragments to leave out."""
    import xarray as xr

    out: dict[str, np.ndarray] = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.suffix == ".nc":
            with xr.open_dataset(path) as ds:
                for k, v in ds.data_vars.items():
                    if v.dtype.kind in "iufb":
                        out[f"{rel}:{k}"] = np.asarray(v.values)
        elif path.suffix == ".json":
            _json_numbers(rel, json.loads(path.read_text()), out)
        elif path.suffix == ".npz":
            with np.load(path) as z:
                for k in z.files:
                    if z[k].dtype.kind in "iufb":
                        out[f"{rel}:{k}"] = z[k]
    return {k: v for k, v in out.items() if not any(s in k for s in ENGINE_STATE + skip)}


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def table_numbers(text: str, key: str = "report.md") -> dict[str, np.ndarray]:
    """Every number in the markdown tables of a report, one array per table (the reports' run
    times are bullets, not tables; cells naming a temporary path are left out)."""
    out, rows, k = {}, [], 0
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            rows += [c for c in line.strip("|").split("|") if "tmp" not in c and "pytest" not in c]
        elif rows:
            out[f"{key}:table{k}"] = np.array([float(x) for c in rows for x in _NUMBER.findall(c)])
            rows, k = [], k + 1
    return out


def check(name: str, values: Mapping[str, np.ndarray],
          atol: Mapping[str, float] | None = None) -> None:
    """Assert ``values`` equal the recorded ``outputs/<name>.npz`` (module docstring);
    ``atol`` replaces the relative tolerance of some keys by an absolute one (positions in
    metres: 1 um, as tests/test_goldens.py)."""
    path = DIR / f"{name}.npz"
    values = {k: np.asarray(v) for k, v in values.items()}
    assert values, f"{name}: no numbers to compare"
    if RECORD:
        DIR.mkdir(exist_ok=True)
        np.savez_compressed(path, **values)
        warnings.warn(f"recorded golden {path}", stacklevel=2)
        return
    assert path.is_file(), f"no golden {path} (record it: JAXNAV_RECORD_GOLDENS=1)"
    with np.load(path) as z:
        want = {k: z[k] for k in z.files}
    assert sorted(values) == sorted(want), (sorted(set(values) ^ set(want)))
    for k, w in want.items():
        g = values[k]
        assert g.shape == w.shape, (k, g.shape, w.shape)
        if w.dtype.kind in "iub":
            np.testing.assert_array_equal(g, w, err_msg=f"{name} {k}")
            continue
        finite = np.isfinite(w)
        scale = np.max(np.abs(w[finite])) if finite.any() else 0.0
        tol = (atol or {}).get(k, RTOL * scale)
        np.testing.assert_allclose(g, w, rtol=0.0, atol=tol, equal_nan=True,
                                   err_msg=f"{name} {k}")
