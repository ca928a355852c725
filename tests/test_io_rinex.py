"""RINEX 2/3 observation and navigation readers: slots, code selection, damaged files, real data."""

from __future__ import annotations

import datetime as dt
import gzip
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.gpstime import datetime64_to_gps_seconds
from jaxnav.io import InputError, read_rinex_nav, read_rinex_obs

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "esbc_static"
OBS = DATA / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
NAV = DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"

C_LIGHT = 299792458.0
LAMBDA_L1 = C_LIGHT / 1575.42e6

# Synthetic file content: the value of code c for satellite sv at epoch k is a closed form, so
# every slot can be checked exactly.
TYPES3 = {"G": ["C1C", "C1W", "C2L", "C2W", "L1C", "L2W", "D1C", "S1C"], "E": ["C1C", "C5Q"]}
SATS = {"G": [5, 7, 32], "E": [11]}
_CODE_OFFSET = {"C1C": 0.0, "C1W": 0.25, "C2L": 0.5, "C2W": 0.75, "C5Q": 0.125}


def value(code: str, sv: str, k: int) -> float:
    prn = int(sv[1:])
    base = 2.0e7 + 1.0e5 * prn + 30.0 * k + (1e6 if sv[0] == "E" else 0.0)
    if code[0] == "C":
        return base + _CODE_OFFSET[code]
    if code[0] == "L":
        return base / LAMBDA_L1 + (7.0 if code == "L2W" else 0.0)
    if code[0] == "D":
        return -100.0 * prn - k
    return 40.0 + prn / 10.0  # S


def missing(code: str, sv: str, k: int) -> bool:
    return (sv == "G07" and code == "C2W") or (sv == "G32" and k == 2 and code[0] == "L")


def _fmt(v, lli=" ", ssi="7"):
    return " " * 16 if v is None else f"{v:14.3f}{lli}{ssi}"


def _hline(content: str, label: str) -> str:
    return f"{content:<60s}{label}"


def rinex3_text(n_epochs=4, interval=30.0, lli_at=None):
    hdr = [
        _hline("     3.04           OBSERVATION DATA    M", "RINEX VERSION / TYPE"),
        _hline(
            "jaxnav test         jaxnav              20200625 000000 UTC", "PGM / RUN BY / DATE"
        ),
        _hline("SYNT", "MARKER NAME"),
        _hline("  3582105.2910   532589.7313  5232754.8054", "APPROX POSITION XYZ"),
        _hline("        0.0000        0.0000        0.0000", "ANTENNA: DELTA H/E/N"),
    ]
    for sys, codes in TYPES3.items():
        hdr.append(_hline(f"{sys}  {len(codes):3d} " + " ".join(codes), "SYS / # / OBS TYPES"))
    hdr += [
        _hline(f"{interval:10.3f}", "INTERVAL"),
        _hline("  2020     6    25     0     0    0.0000000     GPS", "TIME OF FIRST OBS"),
        _hline("", "END OF HEADER"),
    ]
    out = list(hdr)
    for k in range(n_epochs):
        t = k * interval
        mm, ss = divmod(t, 60.0)
        svs = [f"{s}{p:02d}" for s in TYPES3 for p in SATS[s]]
        out.append(f"> 2020 06 25 00 {int(mm):02d}{ss:11.7f}  0{len(svs):3d}")
        for sv in svs:
            fields = []
            for code in TYPES3[sv[0]]:
                v = None if missing(code, sv, k) else value(code, sv, k)
                lli = "1" if (lli_at == (sv, k) and code == "L1C") else " "
                fields.append(_fmt(v, lli))
            out.append((sv + "".join(fields)).rstrip())
    return out


def rinex2_text(n_epochs=3):
    types = ["C1", "P1", "L1", "P2", "L2", "C2"]
    hdr = [
        _hline("     2.11           OBSERVATION DATA    M (MIXED)", "RINEX VERSION / TYPE"),
        _hline(
            "jaxnav test         jaxnav              20200625 000000 UTC", "PGM / RUN BY / DATE"
        ),
        _hline("SYNT", "MARKER NAME"),
        _hline("  3582105.2910   532589.7313  5232754.8054", "APPROX POSITION XYZ"),
        _hline("        0.0000        0.0000        0.0000", "ANTENNA: DELTA H/E/N"),
        _hline("     1     1", "WAVELENGTH FACT L1/2"),
        _hline(f"{len(types):6d}" + "".join(f"{t:>6s}" for t in types), "# / TYPES OF OBSERV"),
        _hline("    30.000", "INTERVAL"),
        _hline("  2020     6    25     0     0    0.0000000     GPS", "TIME OF FIRST OBS"),
        _hline("", "END OF HEADER"),
    ]
    out = list(hdr)
    v3 = {"C1": "C1C", "P1": "C1W", "L1": "L1C", "P2": "C2W", "L2": "L2W", "C2": "C2L"}
    for k in range(n_epochs):
        svs = ["G05", "G07", "E11"]
        mm, ss = divmod(k * 30.0, 60.0)
        out.append(f" 20  6 25  0 {int(mm):2d}{ss:11.7f}  0{len(svs):3d}" + "".join(svs))
        for sv in svs:
            vals = []
            for t in types:
                code = v3[t]
                ok = sv[0] == "G" or t in ("C1", "L1")
                vals.append(value(code, sv, k) if ok and not missing(code, sv, k) else None)
            line1 = "".join(_fmt(v) for v in vals[:5]).rstrip()
            line2 = "".join(_fmt(v) for v in vals[5:]).rstrip()
            out += [line1, line2]
    return out


def write(tmp_path: Path, lines, name="syn.rnx") -> Path:
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def t_gps(k, interval=30.0):
    return datetime64_to_gps_seconds(np.datetime64("2020-06-25T00:00:00")) + k * interval


# ------------------------------------------------------------------------------------------


def test_rinex3_slots_values_and_priority(tmp_path):
    p = write(tmp_path, rinex3_text())
    obs = read_rinex_obs(
        p, {"G": ["C1", "C2", "L1", "L2", "C1W", "D1", "S1"], "E": ["C1", "C5"]}, indicators=True
    )
    np.testing.assert_array_equal(obs.time_gps_s, t_gps(np.arange(4)))
    assert obs.interval_s == 30.0 and obs.epoch_present.all()
    np.testing.assert_allclose(obs.approx_pos_ecef, [3582105.291, 532589.7313, 5232754.8054])
    g = obs.systems["G"]
    # default priority: band 1 civil C/A first, band 2 P(Y) (W) before L2C (L)
    assert g.codes == {
        "C1": "C1C", "C2": "C2W", "L1": "L1C", "L2": "L2W", "C1W": "C1W", "D1": "D1C",
        "S1": "S1C",
    }  # fmt: skip
    assert g.sv.shape == (32,) and g.sv[4] == "G05" and g.sv[31] == "G32"
    for req, code in g.codes.items():
        arr, m = g.obs[req], g.mask[req]
        assert arr.shape == (4, 32)
        for prn in range(1, 33):
            sv = f"G{prn:02d}"
            for k in range(4):
                present = prn in SATS["G"] and not missing(code, sv, k)
                assert m[k, prn - 1] == present
                if present:
                    assert arr[k, prn - 1] == pytest.approx(value(code, sv, k), abs=1e-3)
                else:
                    assert np.isnan(arr[k, prn - 1])
    e = obs.systems["E"]
    assert e.codes == {"C1": "C1C", "C5": "C5Q"} and e.sv.shape == (36,)
    assert e.obs["C5"][1, 10] == pytest.approx(value("C5Q", "E11", 1), abs=1e-3)
    assert set(g.lli) == {"L1", "L2"} and not g.lli["L1"].any()


def test_priority_override_and_lli(tmp_path):
    p = write(tmp_path, rinex3_text(lli_at=("G05", 2)))
    obs = read_rinex_obs(
        p, {"G": ["C2", "L1"]}, priority={"G": {"2": "LW", "1": "C"}}, indicators=True
    )
    assert obs.systems["G"].codes == {"C2": "C2L", "L1": "L1C"}
    lli = obs.systems["G"].lli["L1"]
    assert lli[2, 4] == 1 and lli.sum() == 1


def test_code_requests_rejected_or_missing(tmp_path):
    p = write(tmp_path, rinex3_text())
    with pytest.raises(InputError, match="unknown observation code 'C1Z' for constellation G"):
        read_rinex_obs(p, {"G": ["C1Z"]})
    with pytest.raises(InputError, match="unknown observation request 'X1'"):
        read_rinex_obs(p, {"G": ["X1"]})
    with pytest.raises(InputError, match=r"no observation code for G 'C5'.*expected one of"):
        read_rinex_obs(p, {"G": ["C5"]})
    with pytest.warns(UserWarning, match="all-missing"):
        obs = read_rinex_obs(p, {"G": ["C1", "C5Q"]}, on_missing="nan")
    assert not obs.systems["G"].mask["C5Q"].any() and obs.systems["G"].codes["C5Q"] is None
    with pytest.raises(InputError, match="G32 outside the 8 slots"):
        read_rinex_obs(p, {"G": ["C1"]}, slots={"G": (1, 8)})


def test_rinex2_types_map_to_rinex3(tmp_path):
    p = write(tmp_path, rinex2_text(), "syn.20o")
    obs = read_rinex_obs(p, {"G": ["C1", "C1W", "C2", "L1", "L2"], "E": ["C1", "L1"]})
    g = obs.systems["G"]
    # RINEX 2 P2 -> C2W and L2 -> L2W (P(Y) tracking), P1 -> C1W
    assert g.codes == {"C1": "C1C", "C1W": "C1W", "C2": "C2W", "L1": "L1C", "L2": "L2W"}
    assert obs.systems["E"].codes == {"C1": "C1X", "L1": "L1X"}
    for k in range(3):
        assert g.obs["C2"][k, 4] == pytest.approx(value("C2W", "G05", k), abs=1e-3)
        assert g.obs["L1"][k, 6] == pytest.approx(value("L1C", "G07", k), abs=1e-3)
        assert np.isnan(g.obs["C2"][k, 6])  # G07 C2W missing
    assert obs.systems["E"].obs["C1"][2, 10] == pytest.approx(value("C1C", "E11", 2), abs=1e-3)
    np.testing.assert_array_equal(obs.time_gps_s, t_gps(np.arange(3)))


def test_gzip_input(tmp_path):
    lines = rinex3_text()
    p = tmp_path / "syn.rnx.gz"
    p.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    a = read_rinex_obs(p, {"G": ["C1"]})
    b = read_rinex_obs(write(tmp_path, lines), {"G": ["C1"]})
    np.testing.assert_array_equal(a.systems["G"].obs["C1"], b.systems["G"].obs["C1"])


def test_hatanaka_compressed_input(tmp_path):
    hatanaka = pytest.importorskip("hatanaka")
    lines = rinex3_text()
    text = "\n".join(lines) + "\n"
    p = tmp_path / "syn.crx.gz"
    p.write_bytes(hatanaka.compress(text.encode()))  # CRX, then gzip (the package default)
    assert p.read_bytes()[:2] == b"\x1f\x8b"
    a = read_rinex_obs(p, {"G": ["C1", "L2"]})
    b = read_rinex_obs(write(tmp_path, lines), {"G": ["C1", "L2"]})
    for req in ("C1", "L2"):
        np.testing.assert_array_equal(a.systems["G"].obs[req], b.systems["G"].obs[req])
    bad = tmp_path / "bad.rnx.gz"
    bad.write_bytes(gzip.compress(text.encode())[:100])
    with pytest.raises(InputError, match="cannot decompress"):
        read_rinex_obs(bad, {"G": ["C1"]})


def test_damaged_rinex2(tmp_path):
    lines = rinex2_text(n_epochs=3)
    n_hdr = lines.index(next(x for x in lines if "END OF HEADER" in x)) + 1
    # epoch 2 loses one observation line: the scan meets an observation where an epoch is due
    cut = lines[: n_hdr + 7 + 3] + lines[n_hdr + 7 + 4 :]
    with pytest.raises(InputError, match="unparsable epoch record"):
        read_rinex_obs(write(tmp_path, cut, "c.20o"), {"G": ["C1"]})
    with pytest.raises(InputError, match="file ends.*truncated record"):
        read_rinex_obs(write(tmp_path, lines[:-2], "t.20o"), {"G": ["C1"]})
    bad = list(lines)
    bad[n_hdr + 1] = bad[n_hdr + 1][:16] + "  1100000x0.000" + bad[n_hdr + 1][31:]
    with pytest.raises(InputError, match=rf"line {n_hdr + 2}, epoch .*unparsable observation"):
        read_rinex_obs(write(tmp_path, bad, "b.20o"), {"G": ["C1W"]})
    # georinex parses every RINEX 2 field of the used systems: unrequested ones are checked too
    with pytest.raises(InputError, match=rf"line {n_hdr + 2}, epoch .*unparsable observation"):
        read_rinex_obs(write(tmp_path, bad, "b.20o"), {"G": ["C2"]})
    assert read_rinex_obs(write(tmp_path, bad, "b.20o"), {"E": ["C1"]}).time_gps_s.size == 3


def _blocks(lines):
    i0 = lines.index(next(x for x in lines if x.startswith(">")))
    idx = [i for i, x in enumerate(lines) if x.startswith(">")] + [len(lines)]
    return lines[:i0], [lines[a:b] for a, b in zip(idx[:-1], idx[1:], strict=True)]


def test_damaged_rinex3(tmp_path):
    hdr, blocks = _blocks(rinex3_text(n_epochs=5))
    n_hdr = len(hdr)

    def f(bl):
        return write(tmp_path, hdr + sum(bl, []), "bad.rnx")

    swapped = [blocks[0], blocks[2], blocks[1], blocks[3]]
    line_of_3rd = n_hdr + 2 * len(blocks[0]) + 1
    with pytest.raises(InputError, match=rf"line {line_of_3rd}, epoch .*out of order"):
        read_rinex_obs(f(swapped), {"G": ["C1"]})
    short = [blocks[0], blocks[1][:-1], blocks[2]]  # one satellite record missing
    with pytest.raises(InputError, match="expected satellite record 4 of 4"):
        read_rinex_obs(f(short), {"G": ["C1"]})
    with pytest.raises(InputError, match="file ends.*truncated record"):
        read_rinex_obs(f([blocks[0], blocks[1][:-2]]), {"G": ["C1"]})
    garbage = [list(b) for b in blocks[:3]]
    garbage[1][2] = garbage[1][2][:5] + "xx.yyy" + garbage[1][2][11:]
    bad_line = n_hdr + len(blocks[0]) + 3
    with pytest.raises(InputError, match=rf"line {bad_line}, epoch .*unparsable observation"):
        read_rinex_obs(f(garbage), {"G": ["C1"]})
    with pytest.warns(UserWarning, match="dropping 1 exactly repeated epoch"):
        obs = read_rinex_obs(f([blocks[0], blocks[1], blocks[1], blocks[2]]), {"G": ["C1"]})
    np.testing.assert_array_equal(obs.time_gps_s, t_gps(np.arange(3)))
    changed = [list(b) for b in blocks[1:2]][0]
    changed[1] = changed[1][:3] + f"{1.5e7:14.3f}" + changed[1][17:]
    with pytest.raises(InputError, match="repeated epoch with different observations"):
        read_rinex_obs(f([blocks[0], blocks[1], changed, blocks[2]]), {"G": ["C1"]})
    with pytest.warns(UserWarning, match="2 missing epoch"):
        obs = read_rinex_obs(f([blocks[0], blocks[3], blocks[4]]), {"G": ["C1"]})
    np.testing.assert_array_equal(obs.epoch_present, [True, False, False, True, True])
    assert not obs.systems["G"].mask["C1"][1:3].any()
    assert obs.systems["G"].obs["C1"][3, 4] == pytest.approx(value("C1C", "G05", 3), abs=1e-3)
    off = list(blocks[2])
    off[0] = off[0].replace("00 01  0.0", "00 01 10.0")  # 70 s on a 30 s grid
    with pytest.raises(InputError, match="off the 30 s grid"):
        read_rinex_obs(f([blocks[0], blocks[1], off, blocks[3], blocks[4]]), {"G": ["C1"]})
    no_types = [x for x in hdr if "OBS TYPES" not in x]
    with pytest.raises(InputError, match="missing SYS / # / OBS TYPES"):
        read_rinex_obs(write(tmp_path, no_types + sum(blocks, []), "bad.rnx"), {"G": ["C1"]})


def _set_field(line: str, q: int, text: str) -> str:
    """RINEX 3 satellite record with observation field ``q`` (0-based) replaced by ``text``."""
    c = 3 + 16 * q
    return line[:c] + text.rjust(14) + line[c + 14 :]


def test_damaged_rinex3_values(tmp_path):
    """Values RINEX cannot hold, satellites twice, long records, tabs and miscounted headers
    are refused with their line; out-of-range values are masked with a warning."""
    hdr, blocks = _blocks(rinex3_text(n_epochs=3))
    n_hdr = len(hdr)

    def f(bl, h=hdr):
        return write(tmp_path, h + sum(bl, []), "bad.rnx")

    rec_line = n_hdr + len(blocks[0]) + 2  # epoch 1, first satellite (G05)
    for junk in ("nan", "Infinity", "-inf"):
        bad = [list(b) for b in blocks]
        bad[1][1] = _set_field(bad[1][1], 0, junk)  # G05 C1C
        with pytest.raises(InputError, match=rf"line {rec_line}, .*non-finite .*G05 C1C"):
            read_rinex_obs(f(bad), {"G": ["C1"]})
    # out of physical range: C1C 0.000 ("not tracked" for some writers), D1C 2e5 Hz, S1C -3
    bad = [list(b) for b in blocks]
    bad[1][1] = _set_field(bad[1][1], 0, "0.000")
    bad[1][2] = _set_field(bad[1][2], 6, "200000.000")  # G07 D1C
    bad[2][1] = _set_field(bad[2][1], 7, "-3.000")  # G05 S1C
    with pytest.warns(UserWarning, match=rf"3 observation\(s\) outside .*G05 C1C = 0 at line "
                      rf"{rec_line}"):
        obs = read_rinex_obs(f(bad), {"G": ["C1", "D1", "S1", "L1"]})
    g = obs.systems["G"]
    assert not g.mask["C1"][1, 4] and not g.mask["D1"][1, 6] and not g.mask["S1"][2, 4]
    assert g.mask["C1"].sum() == 3 * 3 - 1 and g.mask["L1"][1, 4]  # nothing else lost
    twice = [list(b) for b in blocks]
    twice[1][2] = "G05" + twice[1][2][3:]
    with pytest.raises(InputError, match=rf"line {rec_line + 1}, .*G05 twice in one epoch"):
        read_rinex_obs(f(twice), {"G": ["C1"]})
    long = [list(b) for b in blocks]
    long[1][1] = long[1][1].ljust(3 + 16 * 8) + "  20000000.000"
    with pytest.raises(InputError, match=rf"line {rec_line}, .*longer than its 8 declared types"):
        read_rinex_obs(f(long), {"G": ["C1"]})
    tab = [list(b) for b in blocks]
    tab[1][3] = tab[1][3].replace("  ", "\t", 1)
    with pytest.raises(InputError, match=rf"line {rec_line + 2}: tab character"):
        read_rinex_obs(f(tab), {"G": ["C1"]})
    k = next(i for i, x in enumerate(hdr) if x.startswith("G") and "OBS TYPES" in x)
    miscount = list(hdr)
    miscount[k] = miscount[k][:3] + "  9" + miscount[k][6:]
    with pytest.raises(InputError, match=rf"line {k + 1}: .*G declares 9 types but lists 8"):
        read_rinex_obs(f(blocks, miscount), {"G": ["C1"]})
    alien = [list(b) for b in blocks]
    alien[1][1] = "J01" + alien[1][1][3:]
    with pytest.raises(InputError, match=rf"line {rec_line}, .*J01 of a system without"):
        read_rinex_obs(f(alien), {"G": ["C1"]})


def test_damaged_rinex2_header_and_ids(tmp_path):
    lines = rinex2_text()
    k = next(i for i, x in enumerate(lines) if "TYPES OF OBSERV" in x)
    miscount = list(lines)
    miscount[k] = f"{7:6d}" + miscount[k][6:]
    with pytest.raises(InputError, match=rf"line {k + 1}: .*7 types declared but 6 listed"):
        read_rinex_obs(write(tmp_path, miscount, "m.20o"), {"G": ["C1"]})
    e = next(i for i, x in enumerate(lines) if x.startswith(" 20  6 25"))
    twice = list(lines)
    twice[e] = twice[e][:32] + "G05G05E11"
    with pytest.raises(InputError, match=rf"line {e + 4}, .*G05 twice"):
        read_rinex_obs(write(tmp_path, twice, "t.20o"), {"G": ["C1"]})
    junk = list(lines)
    junk[e] = junk[e][:32] + "G0xG07E11"
    with pytest.raises(InputError, match=rf"line {e + 1}, .*satellite id 'G0x'"):
        read_rinex_obs(write(tmp_path, junk, "j.20o"), {"G": ["C1"]})


# ------------------------------------------------------------------------------------------
# Real data (ESBC, 2020-06-25)


def _need(p: Path):
    if not p.exists():
        pytest.skip(f"shared real data not present: {p} (only in the project workspace)")


@pytest.fixture(scope="module")
def esbc_hour():
    _need(OBS)
    tlim = (dt.datetime(2020, 6, 25, 0, 0), dt.datetime(2020, 6, 25, 0, 59, 59))
    return read_rinex_obs(OBS, tlim=tlim)  # default: GPS + Galileo, Hatanaka + gzip


def test_esbc_hour_code_ranges(esbc_hour):
    obs = esbc_hour
    assert obs.time_gps_s.size == 120 and obs.interval_s == 30.0
    assert obs.time_gps_s[0] == t_gps(0)
    g = obs.systems["G"]
    assert g.codes["C1"] == "C1C" and g.codes["C2"] == "C2W"
    c1 = g.obs["C1"][g.mask["C1"]]
    print(f"GPS C1C: {c1.min():.4e} .. {c1.max():.4e} m, {g.mask['C1'].any(0).sum()} satellites")
    # geometric ranges are 2.0e7-2.58e7 m; the receiver clock (+0.48 ms = +144 km here) and
    # satellite clocks (up to +-0.7 ms) push the measured maximum to 2.63e7 m (G21 at 1.6 deg)
    assert 2.0e7 < c1.min() and c1.max() < 2.7e7
    assert 8 <= g.mask["C1"].any(axis=0).sum() <= 16
    e = obs.systems["E"]
    c1e = e.obs["C1"][e.mask["C1"]]
    assert 2.2e7 < c1e.min() and c1e.max() < 3.0e7  # Galileo orbit radius 29600 km
    np.testing.assert_allclose(obs.approx_pos_ecef, [3582105.291, 532589.7313, 5232754.8054])


def test_esbc_doppler_matches_code_rate(esbc_hour):
    """-lambda_1 D1C [m/s] = d(C1C)/dt: both see the same range rate and receiver clock drift."""
    g = esbc_hour.systems["G"]
    c1, d1 = g.obs["C1"], g.obs["D1"]
    code_rate = np.diff(c1, axis=0) / 30.0
    dop = -LAMBDA_L1 * 0.5 * (d1[1:] + d1[:-1])
    diff = (code_rate - dop)[np.isfinite(code_rate - dop)]
    p95 = np.percentile(np.abs(diff), 95)
    print(f"code rate - Doppler: median {np.median(diff):.3f} m/s, p95 {p95:.3f} m/s")
    assert diff.size > 500
    assert np.percentile(np.abs(diff), 95) < 0.5
    assert np.nanmax(np.abs(dop)) < 1000.0  # GPS range rates are below ~900 m/s


def test_esbc_navigation_file_keeps_galileo_and_beidou_records():
    """sbf2rin (the ESBC file's writer) leaves 'spare' fields blank inside Galileo and BeiDou
    records; georinex drops such a record whole (all NaN) unless the blanks are zero-filled
    first (io/nav.py). Every record of the file must come back: 1602 Galileo, 357 BeiDou
    (counted with awk on the file), with semi-major axes of the systems' orbits."""
    _need(NAV)
    nav = read_rinex_nav(NAV, use={"E", "C"})
    # Galileo: nominal 29,600 km and E14 / E18 on their eccentric orbits (27,977 km); BeiDou:
    # MEO 27,906 km and GEO / IGSO 42,164 km.
    axes = {"E": [29_600, 27_977], "C": [27_906, 42_164]}
    for letter, n_records in (("E", 1602), ("C", 357)):
        axes_km = axes[letter]
        sv = [s for s in nav.sv.values if str(s).startswith(letter)]
        a_km = nav["sqrtA"].sel(sv=sv).values ** 2 / 1e3
        a_km = a_km[np.isfinite(a_km)]
        assert a_km.size == n_records, letter
        ax = np.array(axes_km, dtype=float)[None]
        rel = np.min(np.abs(a_km[:, None] - ax) / ax, axis=1)
        assert np.all(rel < 0.01), letter  # each record within 1 % of one of the orbits


def test_esbc_navigation_file():
    _need(NAV)
    nav = read_rinex_nav(NAV, use={"G"})
    sqrt_a = nav["sqrtA"].values
    sqrt_a = sqrt_a[np.isfinite(sqrt_a)]
    assert sqrt_a.size > 100
    np.testing.assert_allclose(sqrt_a, np.sqrt(26_559_700.0), rtol=2e-3)  # GPS a = 26560 km
    with pytest.raises(InputError, match="not navigation data"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            read_rinex_nav(OBS)


def test_rinex_requests_ask_each_code_once_and_both_l1_codes_for_p1c1():
    """``p1c1_from_observations`` needs the P code and C/A on L1; no code is asked twice."""
    from jaxnav.io.prepare import rinex_requests

    for freq in ("single", "dual"):
        req = rinex_requests(freq, ("G", "R", "E"), p1_codes=True)
        for letter, codes in req.items():
            assert len(codes) == len(set(codes)), (freq, letter, codes)
        assert {"C1W", "C1C"} <= set(req["G"]) and {"C1P", "C1C"} <= set(req["R"])
    assert rinex_requests("dual", ("G",)) == {"G": ("C1W", "C2W", "L1C", "L2W", "D1C")}


def _gps_cut(n_sats=8) -> tuple[list[str], list[list[str]]]:
    """Header and the first record of ``n_sats`` GPS satellites of the ESBC navigation file."""
    lines = gzip.decompress(NAV.read_bytes()).decode().splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    records, seen = [], set()
    for i in range(end, len(lines)):
        if lines[i][:1] == "G" and lines[i][:3] not in seen:
            seen.add(lines[i][:3])
            records.append(lines[i : i + 8])
        if len(records) == n_sats:
            break
    return lines[:end], records


@pytest.mark.parametrize("damage, n_read, warned", [
    ("none", 8, None),
    ("junk inside record 3", 7, "1 damaged navigation record.*line {r3} .*continuation line 2"),
    ("three blank lines", 8, "3 blank line"),
    ("Infinity in record 5", 7, "line {r5} .*G.. record: field 'Infinity' is not a finite"),
    ("junk between records", 8, "not a record's epoch line: 'junk'"),
    ("truncated last record", 7, "truncated: 4 of 7 continuation lines"),
])
def test_navigation_records_are_read_or_reported(tmp_path, damage, n_read, warned):
    """Issue 23: one junk line made georinex turn a whole GPS record into NaN and three blank
    lines turned 8 satellites into 1, silently; now every record is read or reported."""
    _need(NAV)
    head, recs = _gps_cut()
    body = [list(r) for r in recs]
    if damage == "junk inside record 3":
        body[2].insert(2, "junk")
    elif damage == "three blank lines":
        body[3] = ["", "", ""] + body[3]
    elif damage == "Infinity in record 5":
        body[4][2] = body[4][2][:4] + f"{'Infinity':>19s}" + body[4][2][23:]
    elif damage == "junk between records":
        body[5] = ["junk"] + body[5]
    elif damage == "truncated last record":
        body[-1] = body[-1][:5]
    p = tmp_path / "cut.rnx"
    p.write_text("\n".join(head + [ln for r in body for ln in r]) + "\n")
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        nav = read_rinex_nav(p, use={"G"})
    msgs = " ".join(str(w.message) for w in rec if not issubclass(w.category, FutureWarning))
    sqrt_a = nav["sqrtA"].values
    assert int(np.isfinite(sqrt_a).sum()) == n_read, msgs
    if warned is None:
        assert msgs == ""
    else:
        where = {"r3": len(head) + 2 * 8 + 1, "r5": len(head) + 4 * 8 + 1}
        assert re.search(warned.format(**where), msgs), msgs
