"""Seeded fuzzing of jaxnav's readers: mutated copies of small cut-downs of the shared inputs.

Each reader gets a cut-down copy of a real file, made at run time from ``../shared/data`` (never
committed), and ``n`` mutations of it drawn by a seeded generator: truncation, a flipped byte,
a deleted / duplicated / swapped line or byte range, blank lines, tabs, a numeric field
replaced by NaN, Infinity or a huge value, another text encoding. Every case ends in one of:

- ``refused``: an ``InputError`` naming the file (what a reader should do with damage);
- ``warned``: read, with a warning (a documented repair or a counted skip);
- ``unchanged``: read silently, output equal to the original's;
- ``changed``: read silently, output differs, but every checkable property holds (a digit
  changed inside a number cannot be told from data);
- ``foreign``: any other exception, or an ``InputError`` without the file name (a defect);
- ``slow``: took longer than ``SLOW_S`` (a hang, in a harness that cannot interrupt);
- ``silent``: read silently with a checkable property broken (non-finite or out-of-range
  values, fewer records or values than the file holds, time going backwards, impossible IDs): a
  defect.

Run ``python tests/fuzz/harness.py --cases 200`` for the full form (docs/reliability.md); the
test suite runs a quick form (``tests/fuzz/test_fuzz.py``).
"""

from __future__ import annotations

import argparse
import functools
import gzip
import re
import time
import warnings
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
SLOW_S = 20.0
OUTCOMES = ("refused", "warned", "unchanged", "changed", "foreign", "slow", "silent")
DEFECTS = ("foreign", "slow", "silent")
_NUMBER = re.compile(rb"-?\d+\.\d+(?:[eEdD][+-]?\d+)?")


# ----------------------------------------------------------------------------------------------
# Mutations
# ----------------------------------------------------------------------------------------------
def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _body_index(lines, rng, skip: int) -> int:
    return int(rng.integers(min(skip, len(lines) - 1), len(lines)))


def mutate(data: bytes, rng: np.random.Generator, *, text: bool, skip: int) -> tuple[str, bytes]:
    """One random mutation of ``data`` (``skip``: header lines / bytes mostly left alone)."""
    kinds = ["truncate", "flip", "delete", "duplicate", "swap"]
    if text:
        kinds += ["blank", "tabs", "nan", "inf", "huge", "negative", "encoding"]
    kind = kinds[int(rng.integers(len(kinds)))]
    if not text:  # binary: byte positions and ranges
        n = len(data)
        p = int(rng.integers(skip, n))
        if kind == "truncate":
            return kind, data[:p]
        if kind == "flip":
            return kind, data[:p] + bytes([data[p] ^ (1 << int(rng.integers(8)))]) + data[p + 1:]
        length = int(rng.integers(1, 200))
        if kind == "delete":
            return kind, data[:p] + data[p + length:]
        if kind == "duplicate":
            return kind, data[:p + length] + data[p:p + length] + data[p + length:]
        q = int(rng.integers(skip, n))
        a, b = sorted((p, q))
        return kind, data[:a] + data[b:b + length] + data[a + length:b] + data[a:a + length] + \
            data[b + length:]
    lines = _lines(data)
    i = _body_index(lines, rng, skip)
    if kind == "truncate":
        cut = sum(len(x) + 1 for x in lines[:i]) + int(rng.integers(0, len(lines[i]) + 1))
        return kind, data[:cut]
    if kind == "flip":
        p = int(rng.integers(sum(len(x) + 1 for x in lines[:skip]), len(data)))
        return kind, data[:p] + bytes([data[p] ^ (1 << int(rng.integers(7)))]) + data[p + 1:]
    if kind == "delete":
        del lines[i]
    elif kind == "duplicate":
        lines.insert(i, lines[i])
    elif kind == "swap":
        j = _body_index(lines, rng, skip)
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "blank":
        lines[i:i] = [b""] * int(rng.integers(1, 4))
    elif kind == "tabs":
        lines[i] = lines[i].replace(b"  ", b"\t", 1)
    elif kind == "encoding":
        return kind, data.decode("latin-1").encode("utf-16")
    else:
        numbers = [(m.start(), m.end()) for m in _NUMBER.finditer(lines[i])]
        if not numbers:
            return "unchanged-no-number", data
        a, b = numbers[int(rng.integers(len(numbers)))]
        new = {"nan": b"nan", "inf": b"Infinity", "huge": b"9.99e99",
               "negative": b"-" + lines[i][a:b].lstrip(b"-")}[kind]
        lines[i] = lines[i][:a] + new.rjust(b - a) + lines[i][b:]
    return kind, b"\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Readers: a cut-down original, how to read it, and what must hold of a silent read
# ----------------------------------------------------------------------------------------------
class Reader(NamedTuple):
    name: str
    suffix: str
    text: bool
    skip: Callable[[bytes], int]  # header lines (text) or bytes (binary) mostly spared
    original: Callable[[], bytes]
    read: Callable[[Path], object]
    summary: Callable[[object], object]  # comparable digest of an output
    check: Callable[[object, object, bytes], list[str]]  # (output, original output, bytes)


def _gz(name: str) -> str:
    return gzip.decompress((DATA / "esbc_static" / name).read_bytes()).decode("ascii", "replace")


def _sp3_original() -> bytes:
    lines = _gz("GRG0MGXFIN_20201770000_01D_15M_ORB.SP3.gz").splitlines()
    epochs = [i for i, ln in enumerate(lines) if ln.startswith("*")]
    keep = lines[: epochs[4]] + ["EOF"]
    keep[0] = keep[0][:32] + f"{4:7d}" + keep[0][39:]
    return ("\n".join(keep) + "\n").encode()


def _clk_original() -> bytes:
    lines = _gz("GRG0MGXFIN_20201770000_01D_30S_CLK.CLK.gz").splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    body = [ln for ln in lines[end:] if ln.startswith("AS ")][:240]
    return ("\n".join(lines[:end] + body) + "\n").encode()


def _nav_original() -> bytes:
    lines = _gz("ESBC00DNK_R_20201770000_01D_MN.rnx.gz").splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    recs, seen = [], set()
    for i in range(end, len(lines)):
        if lines[i][:1] == "G" and lines[i][:3] not in seen:
            seen.add(lines[i][:3])
            recs += lines[i: i + 8]
        if len(seen) == 8:
            break
    return ("\n".join(lines[:end] + recs) + "\n").encode()


def _pos_original() -> bytes:
    lines = (DATA / "gnss_imu_drive" / "gnss_1934_sf.pos").read_bytes().split(b"\n")
    n_head = sum(ln.startswith(b"%") for ln in lines[:50])
    return b"\n".join(lines[: n_head + 200]) + b"\n"


def _imu_original() -> bytes:
    raw = (DATA / "gnss_imu_walk" / "imu_1730.csv").read_bytes()
    cut = raw[: raw.index(b"\n", 60_000) + 1]
    return cut


def _imu_tag_for(path: Path, csv: bytes) -> None:
    """The walk's tag cut to the records whose byte position lies inside the cut CSV."""
    tag = (DATA / "gnss_imu_walk" / "imu_1730.csv.tag").read_bytes()
    head, body = tag[:76], tag[76:]
    rec = np.frombuffer(body[: len(body) // 8 * 8], dtype=[("tick", "<u4"), ("fpos", "<u4")])
    n = int(np.searchsorted(rec["fpos"], len(csv), side="right"))
    Path(str(path) + ".tag").write_bytes(head + rec[:n].tobytes())


def _ubx_original() -> bytes:
    data = (DATA / "gnss_imu_walk" / "gnss_1730.ubx").read_bytes()
    p = 0
    while p < 100_000:  # whole frames only, so the original reads without a warning
        if data[p: p + 2] == b"\xb5\x62":
            p += 8 + (data[p + 4] | data[p + 5] << 8)
        else:
            p = data.index(b"\n", p) + 1
    return data[:p]


@functools.cache
def _obs_original() -> bytes:
    """ESBC's header and first 20 epochs, Hatanaka-expanded (the reader's own text routine)."""
    from jaxnav.io.text import read_text

    lines = read_text(DATA / "esbc_static" / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz")
    lines = lines.splitlines()
    epochs = [i for i, ln in enumerate(lines[:5000]) if ln.startswith(">")]
    return ("\n".join(lines[: epochs[20]]) + "\n").encode()


def _after(marker: bytes, offset: int = 1) -> Callable[[bytes], int]:
    """Lines before the first line starting with (or containing) ``marker``, plus offset - 1."""
    def skip(data: bytes) -> int:
        lines = data.split(b"\n")
        return next(i for i, ln in enumerate(lines) if ln.startswith(marker) or (
            len(marker) > 3 and marker in ln)) + offset - 1
    return skip


def _header_pct(data: bytes) -> int:
    return next(i for i, ln in enumerate(data.split(b"\n")) if not ln.startswith(b"%"))


def _finite_or_nan(a) -> bool:
    a = np.asarray(a, float)
    return not np.any(np.isinf(a))


def _sp3(path):
    from jaxnav.io import read_sp3
    return read_sp3(path)


def _sp3_check(o, ref, data) -> list[str]:
    bad = []
    if np.any(np.diff(o.time_gps_s) <= 0):
        bad.append("time not increasing")
    if not (_finite_or_nan(o.pos_ecef_m) and _finite_or_nan(o.clock_s)):
        bad.append("infinite value")
    r = np.linalg.norm(o.pos_ecef_m, axis=-1)
    if np.any((r[np.isfinite(r)] < 6.378e6) | (r[np.isfinite(r)] > 8.5e7)):
        bad.append("orbit radius out of range")
    if any(not re.fullmatch(r"[GRECJISL](0[1-9]|[1-9]\d)", str(s)) for s in o.sv):
        bad.append("impossible satellite ID")
    if np.isfinite(o.pos_ecef_m[..., 0]).sum() < np.isfinite(ref.pos_ecef_m[..., 0]).sum():
        bad.append("fewer position samples than the file declares")
    return bad


def _clk(path):
    from jaxnav.io import read_clk
    return read_clk(path)


def _clk_check(o, ref, data) -> list[str]:
    bad = []
    if np.any(np.diff(o.time_gps_s) <= 0):
        bad.append("time not increasing")
    c, s = o.clock_s[np.isfinite(o.clock_s)], o.sigma_s[np.isfinite(o.sigma_s)]
    if not (_finite_or_nan(o.clock_s) and _finite_or_nan(o.sigma_s)):
        bad.append("infinite value")
    if np.any(np.abs(c) > 0.0625) or np.any((s < 0) | (s > 0.0625)):
        bad.append("clock or sigma out of range")
    if any(not re.fullmatch(r"[GRECJIS](0[1-9]|[1-9]\d)", str(x)) for x in o.sv):
        bad.append("impossible satellite ID")
    return bad


def _nav(path):
    from jaxnav.io import read_rinex_nav
    return read_rinex_nav(path, use={"G"})


def _nav_summary(o):
    return {k: np.asarray(o[k].values, float).round(12).tobytes() for k in o.data_vars}


def _nav_check(o, ref, data) -> list[str]:
    bad = []
    sq = np.asarray(o["sqrtA"].values, float)
    # RINEX navigation files declare no record count: what the file holds is its GPS epoch lines
    held = len(re.findall(rb"(?m)^G\d\d \d{4}", data))
    if np.isfinite(sq).sum() < held:
        bad.append(f"{int(np.isfinite(sq).sum())} records read of the {held} the file holds")
    if any(np.isinf(np.asarray(o[k].values, float)).any() for k in o.data_vars):
        bad.append("infinite value")
    return bad


def _pos(path):
    from jaxnav.io import read_pos
    return read_pos(path)


def _pos_check(o, ref, data) -> list[str]:
    bad = []
    if np.any(np.diff(o.time_gps_s) <= 0):
        bad.append("time not increasing")
    arrays = (o.llh, o.sd_neu_m, o.sd_cross_m, o.age_s, o.ratio)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        bad.append("non-finite value")
    if np.any(o.sd_neu_m < 0) or np.any(np.abs(o.llh[:, 0]) > np.pi / 2):
        bad.append("value out of range")
    if np.any((o.llh[:, 2] < -1000) | (o.llh[:, 2] > 1e5)):
        bad.append("height out of range")
    return bad


def _imu(path):
    from jaxnav.io import read_imu_csv
    return read_imu_csv(path)


def _imu_check(o, ref, data) -> list[str]:
    bad = []
    if np.any(np.diff(o.time_gps_s) <= 0):
        bad.append("time not increasing")
    if not (np.all(np.isfinite(o.accel_mps2)) and np.all(np.isfinite(o.gyro_rad_s))):
        bad.append("non-finite value")
    if np.any(np.abs(o.accel_mps2) > 100 * 9.81) or np.any(np.abs(o.gyro_rad_s) > 70):
        bad.append("value beyond any IMU's full scale")
    if abs(float(o.time_gps_s[0]) - float(ref.time_gps_s[0])) > 1.0:
        bad.append("time shifted by more than 1 s")
    return bad


def _ubx(path):
    from jaxnav.io.ubx import read_ubx
    return read_ubx(path)


def _ubx_summary(o):
    arrays = [np.asarray(v, float) for s in o.obs.systems.values() for v in s.obs.values()]
    return (o.obs.time_gps_s.tobytes(), tuple(np.nan_to_num(a, nan=1e300).tobytes()
                                              for a in arrays), len(o.subframes))


def _ubx_check(o, ref, data) -> list[str]:
    # Every UBX frame is checksummed: a mutation of the frames must be seen, or change nothing.
    return [] if _ubx_summary(o) == _ubx_summary(ref) else ["checksummed data changed silently"]


def _obs(path):
    from jaxnav.io import read_rinex_obs
    return read_rinex_obs(path)


def _obs_summary(o):
    arrays = [np.nan_to_num(np.asarray(v, float), nan=1e300).tobytes()
              for s in o.systems.values() for v in s.obs.values()]
    return (o.time_gps_s.tobytes(), tuple(arrays))


_OBS_RANGE = {"C": (1.0e7, 5.0e7), "D": (-1.0e5, 1.0e5), "S": (0.0, 99.0)}


def _obs_check(o, ref, data) -> list[str]:
    bad = []
    if np.any(np.diff(o.time_gps_s) <= 0):
        bad.append("time not increasing")
    for sys, so in o.systems.items():
        for req, a in so.obs.items():
            if np.isinf(a).any():
                bad.append(f"infinite {sys} {req}")
            lo, hi = _OBS_RANGE.get(req[0], (-np.inf, np.inf))
            v = a[np.isfinite(a)]
            if np.any((v < lo) | (v > hi)):
                bad.append(f"{sys} {req} outside its physical range")
    # every non-blank requested field of a satellite record must come out as a value
    types: dict[str, list[str]] = {}
    for row in ref.header["SYS / # / OBS TYPES"]:  # 13 per line, continuations open blank
        sys = row[0] if row[0] != " " else sys
        types.setdefault(sys, []).extend(row[7:60].split())
    held = {(sys, req): 0 for sys, so in o.systems.items() for req in so.obs}
    for line in data.decode("ascii", "replace").splitlines():
        if line[:1] in o.systems and re.match(r"^[A-Z]\d\d", line):
            so = o.systems[line[0]]
            for req, code in so.codes.items():
                if code in types.get(line[0], []):
                    c = 3 + 16 * types[line[0]].index(code)
                    held[(line[0], req)] += bool(line[c: c + 14].strip())
    for (sys, req), n in held.items():
        got = int(o.systems[sys].mask[req].sum())
        if got < n:
            bad.append(f"{sys} {req}: {got} values read of the {n} the file holds")
    return bad


# A small valid study (the CLI's tiny test study, multi-GNSS): mutated per key, then checked by
# ``jaxnav sweep --check``, which must refuse in one line naming the file (exit 2) or pass.
STUDY = """\
[study]
name = "fuzz"
modes = ["sf_ppp", "float_ppp"]
systems = ["riss"]
durations_s = [20, 30.0]
satellites_kept = [0, 2, "all"]
realizations = 1
recovery_s = 10
chunk_size = 8

[placement]
kind = "grid"
convergence_s = 120
spacing_s = 40.0

[scenario]
duration_s = 240
constellations = ["gps", "galileo"]
drive_seed = 3
iono_scale = 1.0
imu_grade = "crossbow_imu300cc"
"""
_VALUES = ["nan", "inf", "-inf", "-1", "0", "1e9", "9.99e99", "2.5", '"x"', '"__name__"', "[]",
           "[1, 2]", "true", '""', "{}"]


def mutate_study(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One mutation of a study TOML: a value replaced, a key deleted / repeated / unknown, a
    table header lost."""
    lines = data.decode().split("\n")
    keys = [i for i, ln in enumerate(lines) if " = " in ln]
    i = keys[int(rng.integers(len(keys)))]
    kind = ["value", "value", "value", "delete", "duplicate", "unknown", "table"][
        int(rng.integers(7))]
    if kind == "value":
        v = _VALUES[int(rng.integers(len(_VALUES)))]
        key = lines[i].split(" = ")[0]
        lines[i] = f"{key} = {v}"
        kind = f"{key}={v}"
    elif kind == "delete":
        del lines[i]
    elif kind == "duplicate":
        lines.insert(i, lines[i])
    elif kind == "unknown":
        lines.insert(i, "colour = 3")
    else:
        tables = [j for j, ln in enumerate(lines) if ln.startswith("[")]
        del lines[tables[int(rng.integers(len(tables)))]]
    return kind, "\n".join(lines).encode()


def _study(path):
    """``jaxnav sweep PATH --check`` in this process: exit 2 with one line naming the file is an
    InputError (refused); anything else but exit 0 is a foreign outcome."""
    import contextlib
    import io

    from jaxnav import cli
    from jaxnav.io import InputError

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = cli.main(["sweep", str(path), "--check"])
    text = err.getvalue()
    if code == 2 and text.count("\n") == 1 and str(path) in text:
        raise InputError(text.strip().replace(str(path), path.name), file=path)
    if code != 0:
        raise RuntimeError(f"exit {code}: {text[-300:]}")
    return out.getvalue().replace(str(path), "<file>")


def _digest(o):
    """A comparable digest of a NamedTuple of arrays."""
    return tuple(np.asarray(v).tobytes() if isinstance(v, np.ndarray) else repr(v) for v in o)


READERS = {
    "sp3": Reader("sp3", ".sp3", True, _after(b"*"), _sp3_original, _sp3, _digest, _sp3_check),
    "clk": Reader("clk", ".clk", True, _after(b"END OF HEADER", 2), _clk_original, _clk,
                  _digest, _clk_check),
    "nav": Reader("nav", ".rnx", True, _after(b"END OF HEADER", 2), _nav_original, _nav,
                  _nav_summary, _nav_check),
    "pos": Reader("pos", ".pos", True, _header_pct, _pos_original, _pos, _digest, _pos_check),
    "imu": Reader("imu", ".csv", True, lambda d: 0, _imu_original, _imu, _digest, _imu_check),
    "ubx": Reader("ubx", ".ubx", False, lambda d: 0, _ubx_original, _ubx, _ubx_summary,
                  _ubx_check),
    "obs": Reader("obs", ".rnx", True, _after(b">"), _obs_original, _obs, _obs_summary,
                  _obs_check),
    "study": Reader("study", ".toml", True, lambda d: 0, lambda: STUDY.encode(), _study,
                    lambda o: o, lambda o, ref, data: []),
}


# ----------------------------------------------------------------------------------------------
# Running cases
# ----------------------------------------------------------------------------------------------
class Case(NamedTuple):
    reader: str
    index: int
    mutation: str
    outcome: str
    detail: str


def _write(reader: Reader, folder: Path, data: bytes, name: str) -> Path:
    path = folder / f"{name}{reader.suffix}"
    path.write_bytes(data)
    if reader.name == "imu":
        _imu_tag_for(path, _imu_original() if name == "original" else data)
    return path


def _plain(w, path: Path) -> str | None:
    """A warning's text with the file name taken out (None for library deprecations)."""
    if issubclass(w.category, FutureWarning | DeprecationWarning):
        return None
    return str(w.message).replace(str(path), "<file>").replace(path.name, "<file>")


def run_reader(reader: Reader, n: int, folder: Path, seed: int = 0) -> list[Case]:
    """``n`` seeded mutations of ``reader``'s cut-down original, each classified."""
    from jaxnav.io import InputError

    folder.mkdir(parents=True, exist_ok=True)
    original = reader.original()
    opath = _write(reader, folder, original, "original")
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        ref = reader.read(opath)
    # the original's own warnings (the walk log starts mid-line) do not count as a case's
    baseline = {_plain(w, opath) for w in rec}
    ref_digest = reader.summary(ref)
    skip = reader.skip(original)
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(n):
        if reader.name == "study":
            kind, data = mutate_study(original, rng)
        else:
            kind, data = mutate(original, rng, text=reader.text, skip=skip)
        path = _write(reader, folder, data, f"case{k:04d}")
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            try:
                out = reader.read(path)
                err = None
            except InputError as e:
                out, err = None, e
            except Exception as e:  # noqa: BLE001  (what the harness is looking for)
                out, err = None, e
        dt = time.perf_counter() - t0
        warned = [w for w in rec if _plain(w, path) not in baseline | {None}]
        if dt > SLOW_S:
            outcome, detail = "slow", f"{dt:.1f} s"
        elif err is not None:
            named = isinstance(err, InputError) and path.name in str(err)
            outcome = "refused" if named else "foreign"
            detail = f"{type(err).__name__}: {str(err)[:160]}"
        elif warned:
            outcome, detail = "warned", str(warned[0].message)[:160]
        else:
            bad = reader.check(out, ref, data)
            if bad:
                outcome, detail = "silent", "; ".join(bad)
            elif reader.summary(out) == ref_digest:
                outcome, detail = "unchanged", ""
            else:
                outcome, detail = "changed", ""
        cases.append(Case(reader.name, k, kind, outcome, detail))
        path.unlink()
        tag = Path(str(path) + ".tag")
        tag.unlink(missing_ok=True)
    return cases


def table(cases: list[Case]) -> str:
    """Markdown counts per reader and outcome."""
    by = Counter((c.reader, c.outcome) for c in cases)
    readers = list(dict.fromkeys(c.reader for c in cases))
    rows = ["| reader | cases | " + " | ".join(OUTCOMES) + " |",
            "|---|---|" + "---|" * len(OUTCOMES)]
    for r in readers:
        n = sum(by[(r, o)] for o in OUTCOMES)
        rows.append(f"| {r} | {n} | " + " | ".join(str(by[(r, o)]) for o in OUTCOMES) + " |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=200, help="mutations per reader")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--readers", default=",".join(READERS))
    ap.add_argument("--work", default="/tmp/jaxnav-fuzz", help="scratch folder")
    args = ap.parse_args(argv)
    cases = []
    for name in args.readers.split(","):
        t0 = time.perf_counter()
        cases += run_reader(READERS[name], args.cases, Path(args.work) / name, args.seed)
        print(f"{name}: {args.cases} cases in {time.perf_counter() - t0:.0f} s", flush=True)
    print(table(cases))
    for c in cases:
        if c.outcome in DEFECTS:
            print(f"{c.reader} #{c.index} {c.mutation}: {c.outcome}: {c.detail}")
    return int(any(c.outcome in DEFECTS for c in cases))


if __name__ == "__main__":
    raise SystemExit(main())
