"""Broadcast ephemerides from UBX-RXM-SFRBX words (``jaxnav.io.ubx_nav``).

Synthetic: GPS LNAV subframes and Galileo I/NAV pages are encoded here from the ICD layouts
(IS-GPS-200 figure 20-1 with the table 20-XIV parity, as transmitted, then complemented the way
u-blox delivers them; Galileo OS SIS ICD table 39 pages with a CRC-24Q computed by polynomial
division) and must decode back exactly; any single corrupted bit must be rejected.

Real: ``../shared/data/gnss_imu_walk/gnss_1730.ubx`` (u-blox X20, 2025-08-28, ~134 s at 4 Hz).
The decoded orbits must be at the radii of their constellations, and the L1 C/A / E1C
pseudoranges of RXM-RAWX must agree with the ranges computed from the decoded ephemerides to
within the errors of a single-frequency user once the common receiver clock is removed.
"""

from __future__ import annotations

import math
import random
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav import geodesy
from jaxnav.core.gpstime import day_of_year
from jaxnav.geodesy import C_LIGHT
from jaxnav.gnss import corrections, ephemeris
from jaxnav.gnss.signals import SYS_GAL, SYS_GPS
from jaxnav.io.ubx_nav import (
    SfrbxWords,
    decode_galileo_fnav_page,
    decode_galileo_inav_page,
    decode_gps_lnav_subframe,
    ephemeris_from_sfrbx,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "gnss_imu_walk"
UBX = DATA / "gnss_1730.ubx"
needs_data = pytest.mark.skipif(
    not UBX.exists(),
    reason=f"u-blox walk recording not found at {UBX} (a fresh clone has no ../shared)",
)

PI_ICD = 3.1415926535898  # IS-GPS-200 20.3.3.4.3
WEEK_S = 604800.0

# ------------------------------------------------------------------------------------------------
# A GPS LNAV encoder (IS-GPS-200), written from the ICD independently of the decoder
# ------------------------------------------------------------------------------------------------

# table 20-XIV: (previous-word bit added: 29 or 30, source data bits d1..d24)
PARITY_EQUATIONS = (
    (29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)


def _parity_bits(d: list[int], d29: int, d30: int) -> list[int]:
    """D25..D30 of source bits d[1..24] (d[0] unused)."""
    out = []
    for prev, idx in PARITY_EQUATIONS:
        v = d29 if prev == 29 else d30
        for i in idx:
            v ^= d[i]
        out.append(v)
    return out


def _put(bits: list[int], first: int, n: int, value: int):
    """Field of n bits at IS-GPS-200 bit numbers first..first+n-1 (two's complement if < 0)."""
    value &= (1 << n) - 1
    for k in range(n):
        bits[first - 1 + k] = (value >> (n - 1 - k)) & 1


def encode_lnav(fields: list[tuple[int, int, int]], subframe_id: int, tow_count: int, pad=0):
    """The 10 RXM-SFRBX words of one subframe: ICD transmission, then u-blox's complementing.

    ``fields``: (first bit, length, raw value). Words 2 and 10 end with the two
    non-information bits solved so that D29 = D30 = 0 (20.3.5.2). u-blox delivers each word
    XOR D30* (data bits in their true sense); ``pad`` goes into the two unused top bits.
    """
    bits = [0] * 300
    _put(bits, 1, 8, 0x8B)
    _put(bits, 31, 17, tow_count)
    _put(bits, 50, 3, subframe_id)
    for first, n, value in fields:
        _put(bits, first, n, value)
    words = []
    d29s = d30s = 0
    for w in range(10):
        d = [0] + bits[30 * w : 30 * w + 24]
        if w in (1, 9):  # solve bits 23-24 for D29 = D30 = 0
            for t in range(4):
                d[23], d[24] = t >> 1, t & 1
                if _parity_bits(d, d29s, d30s)[4:] == [0, 0]:
                    break
            else:
                raise AssertionError("no t bits")
        par = _parity_bits(d, d29s, d30s)
        sent = [b ^ d30s for b in d[1:]] + par  # transmitted D1..D30
        delivered = [b ^ d30s for b in sent]  # u-blox: complemented for D30*
        value = int("".join(map(str, delivered)), 2) | (pad << 30)
        words.append(value)
        d29s, d30s = sent[28], sent[29]
    return tuple(words)


def _split(first_msb, n_msb, first_lsb, n_lsb, value):
    """A field split across two words: its MSB part and LSB part as two fields."""
    n = n_msb + n_lsb
    value &= (1 << n) - 1
    return [(first_msb, n_msb, value >> n_lsb), (first_lsb, n_lsb, value & ((1 << n_lsb) - 1))]


WEEK = 2381
SF1 = dict(week=WEEK % 1024, ura=2, health=0, iodc=0x1A7, tgd=-23, toc=25650, af2=0, af1=-1234,
           af0=-876543, l2codes=1)  # fmt: skip
SF2 = dict(iode=0xA7, crs=-1234, dn=11789, m0=-1987654321, cuc=-2345, e=54321987, cus=7654,
           sqrta=2702426112, toe=25650, fit=0, aodo=3)  # fmt: skip
SF3 = dict(cic=-45, om0=1234567890, cis=67, i0=659912345, crc=7890, om=-876543210, omd=-23456,
           iode=0xA7, idot=-321)  # fmt: skip
# the ESBC 2020-06-25 header's Klobuchar set, in raw units (alpha 2^-30, 2^-27, 2^-24, 2^-24;
# beta 2^11, 2^14, 2^16, 2^16)
KLOB_RAW = (5, 2, -1, -2, 40, 6, -1, -8)


def gps_subframes(sf1=SF1, sf2=SF2, sf3=SF3, tow0=68116):
    f1 = [(61, 10, sf1["week"]), (71, 2, sf1["l2codes"]), (73, 4, sf1["ura"]),
          (77, 6, sf1["health"]), (83, 2, sf1["iodc"] >> 8), (211, 8, sf1["iodc"] & 0xFF),
          (197, 8, sf1["tgd"]), (219, 16, sf1["toc"]), (241, 8, sf1["af2"]),
          (249, 16, sf1["af1"]), (271, 22, sf1["af0"])]  # fmt: skip
    f2 = [(61, 8, sf2["iode"]), (69, 16, sf2["crs"]), (91, 16, sf2["dn"]),
          *_split(107, 8, 121, 24, sf2["m0"]), (151, 16, sf2["cuc"]),
          *_split(167, 8, 181, 24, sf2["e"]), (211, 16, sf2["cus"]),
          *_split(227, 8, 241, 24, sf2["sqrta"]), (271, 16, sf2["toe"]), (287, 1, sf2["fit"]),
          (288, 5, sf2["aodo"])]  # fmt: skip
    f3 = [(61, 16, sf3["cic"]), *_split(77, 8, 91, 24, sf3["om0"]), (121, 16, sf3["cis"]),
          *_split(137, 8, 151, 24, sf3["i0"]), (181, 16, sf3["crc"]),
          *_split(197, 8, 211, 24, sf3["om"]), (241, 24, sf3["omd"]), (271, 8, sf3["iode"]),
          (279, 14, sf3["idot"])]  # fmt: skip
    a = KLOB_RAW
    f4 = [(61, 2, 1), (63, 6, 56), (69, 8, a[0]), (77, 8, a[1]), (91, 8, a[2]), (99, 8, a[3]),
          (107, 8, a[4]), (121, 8, a[5]), (129, 8, a[6]), (137, 8, a[7]),
          (151, 24, -1234), *_split(181, 24, 211, 8, 98765), (219, 8, 144), (227, 8, 77),
          (241, 8, 18), (249, 8, 137), (257, 8, 7), (271, 8, 18)]  # fmt: skip
    return [
        encode_lnav(f1, 1, tow0 + 1, pad=2),
        encode_lnav(f2, 2, tow0 + 2, pad=3),
        encode_lnav(f3, 3, tow0 + 3, pad=1),
        encode_lnav(f4, 4, tow0 + 4),
    ]


def test_gps_lnav_round_trip_exact():
    words = gps_subframes()
    d1, d2, d3, d4 = (decode_gps_lnav_subframe(w) for w in words)
    assert [d["subframe_id"] for d in (d1, d2, d3, d4)] == [1, 2, 3, 4]
    assert d1["tow_count"] == 68117
    # subframe 1 (table 20-I): powers of two are exact in binary
    assert d1["week_mod1024"] == WEEK % 1024 and d1["ura_index"] == 2 and d1["health"] == 0
    assert d1["iodc"] == 0x1A7 and d1["l2_codes"] == 1
    assert d1["tgd_s"] == -23 * 2.0**-31
    assert d1["toc_sow_s"] == 25650 * 16.0  # 410400 s: 28 min after transmission
    assert d1["af2_s_s2"] == 0.0 and d1["af1_s_s"] == -1234 * 2.0**-43
    assert d1["af0_s"] == -876543 * 2.0**-31
    # subframe 2 (table 20-III)
    exact = pytest.approx  # semicircle fields: one rounding of x pi
    assert d2["iode"] == 0xA7 and d2["crs_m"] == -1234 * 2.0**-5
    assert d2["delta_n_rad_s"] == exact(11789 * 2.0**-43 * PI_ICD, rel=1e-15)
    assert d2["m0_rad"] == exact(-1987654321 * 2.0**-31 * PI_ICD, rel=1e-15)
    assert d2["cuc_rad"] == -2345 * 2.0**-29 and d2["cus_rad"] == 7654 * 2.0**-29
    assert d2["ecc"] == 54321987 * 2.0**-33
    assert d2["sqrt_a_sqrt_m"] == 2702426112 * 2.0**-19  # unsigned 32 bits, MSB set
    assert d2["toe_sow_s"] == 25650 * 16.0 and d2["fit_interval_flag"] == 0
    assert d2["aodo_s"] == 3 * 900.0
    # subframe 3
    assert d3["cic_rad"] == -45 * 2.0**-29 and d3["cis_rad"] == 67 * 2.0**-29
    assert d3["omega0_rad"] == exact(1234567890 * 2.0**-31 * PI_ICD, rel=1e-15)
    assert d3["i0_rad"] == exact(659912345 * 2.0**-31 * PI_ICD, rel=1e-15)
    assert d3["crc_m"] == 7890 * 2.0**-5
    assert d3["omega_rad"] == exact(-876543210 * 2.0**-31 * PI_ICD, rel=1e-15)
    assert d3["omega_dot_rad_s"] == exact(-23456 * 2.0**-43 * PI_ICD, rel=1e-15)
    assert d3["iode"] == 0xA7 and d3["idot_rad_s"] == exact(-321 * 2.0**-43 * PI_ICD, rel=1e-15)
    # subframe 4 page 18 (table 20-X): Klobuchar and UTC
    a = KLOB_RAW
    assert d4["page_sv_id"] == 56
    assert d4["iono_alpha"] == (a[0] * 2.0**-30, a[1] * 2.0**-27, a[2] * 2.0**-24, a[3] * 2.0**-24)
    assert d4["iono_beta"] == (a[4] * 2.0**11, a[5] * 2.0**14, a[6] * 2.0**16, a[7] * 2.0**16)
    np.testing.assert_allclose(d4["iono_alpha"], corrections.KLOBUCHAR_ALPHA_DEFAULT, rtol=1e-4)
    np.testing.assert_allclose(d4["iono_beta"], corrections.KLOBUCHAR_BETA_DEFAULT, rtol=1e-4)
    assert d4["utc_a1_s_s"] == -1234 * 2.0**-50 and d4["utc_a0_s"] == 98765 * 2.0**-30
    assert d4["delta_t_ls_s"] == 18.0 and d4["delta_t_lsf_s"] == 18.0
    utc = (d4["utc_tot_s"], d4["utc_wnt"], d4["utc_wnlsf"], d4["utc_dn"])
    assert utc == (144 * 4096.0, 77, 137, 7)


def test_gps_lnav_every_single_bit_error_is_rejected():
    """The (32, 26) Hamming-type parity detects every single-bit error of a word (20.3.5.2)."""
    words = gps_subframes()[1]
    assert decode_gps_lnav_subframe(words) is not None
    for w in range(10):
        for bit in range(30):
            bad = list(words)
            bad[w] ^= 1 << bit
            assert decode_gps_lnav_subframe(bad) is None, (w, bit)
    # the two pad bits above the 30-bit word carry nothing
    padded = [x ^ (3 << 30) for x in words]
    assert decode_gps_lnav_subframe(padded) == decode_gps_lnav_subframe(words)


def test_gps_assembly_week_health_and_rejections():
    t_rx = WEEK * WEEK_S + 68117 * 6.0 + 0.08
    frames = [SfrbxWords(0, 5, 0, w, t_rx + 6.0 * k) for k, w in enumerate(gps_subframes())]
    # a corrupted subframe and one with a broken preamble: counted and warned, never used
    bad = list(frames[0].words)
    bad[4] ^= 1 << 12
    frames.append(frames[0]._replace(words=tuple(bad)))
    bad = list(frames[0].words)
    bad[0] ^= 1 << 25
    frames.append(frames[0]._replace(words=tuple(bad)))
    # G07: unhealthy (SV health 6 bits != 0); G09: IODE of subframe 3 does not match
    sick = gps_subframes(sf1={**SF1, "health": 0b100000})
    frames += [SfrbxWords(0, 7, 0, w, t_rx) for w in sick[:3]]
    odd = gps_subframes(sf3={**SF3, "iode": 0xA8})
    frames += [SfrbxWords(0, 9, 0, w, t_rx) for w in odd[:3]]
    with pytest.warns(UserWarning) as caught:
        eph, rep = ephemeris_from_sfrbx(frames, t_ref_gps_s=WEEK * WEEK_S)
    msgs = sorted(str(w.message) for w in caught)
    assert len(msgs) == 2 and "1 RXM-SFRBX frame(s) rejected (gps_lnav_parity)" in msgs[0]
    assert "(gps_lnav_preamble)" in msgs[1]
    assert rep.rejected == {"gps_lnav_parity": 1, "gps_lnav_preamble": 1}
    assert rep.ephemerides == {"G05:lnav": 1} and rep.unhealthy == {"G07:lnav": 1}
    assert rep.gps_week_assumed == 0
    assert rep.klobuchar_alpha == (5 * 2.0**-30, 2 * 2.0**-27, -1 * 2.0**-24, -2 * 2.0**-24)
    np.testing.assert_array_equal(np.asarray(eph.iono_alpha), rep.klobuchar_alpha)
    np.testing.assert_array_equal(np.asarray(eph.iono_beta), rep.klobuchar_beta)
    assert np.asarray(eph.prn).tolist() == [5] and np.asarray(eph.system).tolist() == [SYS_GPS]
    k = eph.kepler
    assert bool(k.valid[0, 0])
    # full week from the receive time: toe = 2381 weeks + 410400 s, on the axis from week 2381
    assert float(k.toe_s[0, 0]) == 410400.0 and float(k.toc_s[0, 0]) == 410400.0
    assert float(k.sqrt_a[0, 0]) == 2702426112 * 2.0**-19
    assert float(k.af0[0, 0]) == -876543 * 2.0**-31 and float(k.tgd_s[0, 0]) == -23 * 2.0**-31
    assert float(k.m0[0, 0]) == pytest.approx(-1987654321 * 2.0**-31 * PI_ICD, rel=1e-15)

    # no receive time: the 10-bit week is taken in the 2019-2038 era (week 2381 there) and counted
    blind = [f._replace(t_gps_s=math.nan) for f in frames[:3]]
    eph2, rep2 = ephemeris_from_sfrbx(blind, t_ref_gps_s=WEEK * WEEK_S)
    assert rep2.gps_week_assumed == 0  # t_ref_gps_s serves as the hint
    eph3, rep3 = ephemeris_from_sfrbx(blind)
    assert rep3.gps_week_assumed == 1
    assert float(eph3.t_ref_gps_s) + float(eph3.kepler.toe_s[0, 0]) == WEEK * WEEK_S + 410400.0


# ------------------------------------------------------------------------------------------------
# A Galileo I/NAV encoder (Galileo OS SIS ICD 4.3.2, table 39), CRC by polynomial division
# ------------------------------------------------------------------------------------------------

CRC24Q_G = 0x1864CFB  # G(X) = (1 + X) P(X), degree 24 (ICD 5.1.9.4)


def crc24q_by_division(message: int, n_bits: int) -> int:
    """Remainder of m(X) X^24 divided by G(X) (carry-less long division)."""
    r = message << 24
    for i in range(n_bits + 23, 23, -1):
        if r >> i & 1:
            r ^= CRC24Q_G << (i - 24)
    return r


def _word128(fields: list[tuple[int, int, int]]) -> int:
    w = 0
    for start, n, value in fields:
        w |= (value & ((1 << n) - 1)) << (128 - start - n)
    return w


def encode_inav_page(word: int, rng: random.Random) -> tuple[int, ...]:
    """8 RXM-SFRBX words: even part (words 1-4) then odd part (words 5-8), nominal page."""
    even = (0 << 119) | (0 << 118) | ((word >> 16) << 6)  # even/odd, page type, data, tail
    osnma, sar = rng.getrandbits(40), rng.getrandbits(22)
    odd82 = (1 << 81) | (0 << 80) | ((word & 0xFFFF) << 64) | (osnma << 24) | (sar << 2)
    crc = crc24q_by_division(((even >> 6) << 82) | odd82, 196)
    odd = (odd82 << 38) | (crc << 14) | (rng.getrandbits(8) << 6)  # + CRC, SSP, tail
    bits256 = (even << 136) | (rng.getrandbits(8) << 128) | (odd << 8) | rng.getrandbits(8)
    return tuple((bits256 >> (32 * (7 - i))) & 0xFFFFFFFF for i in range(8))


GAL = dict(iod=345, toe=6830, m0=-1234567890, e=345678, sqrta=3610612736, om0=987654321,
           i0=650000000, om=-1765432109, idot=-1111, omd=-5555, dn=3333, cuc=-444, cus=555,
           crc=6666, crs=-777, sisa=107, svid=11, cic=-88, cis=99, toc=6830, af0=-123456789,
           af1=-54321, af2=0, bgd_a=-17, bgd_b=-15, wn=1357, tow=408000)  # fmt: skip


def galileo_words(g=GAL, e1b_hs=0, e1b_dvs=0):
    return [
        _word128([(0, 6, 1), (6, 10, g["iod"]), (16, 14, g["toe"]), (30, 32, g["m0"]),
                  (62, 32, g["e"]), (94, 32, g["sqrta"])]),
        _word128([(0, 6, 2), (6, 10, g["iod"]), (16, 32, g["om0"]), (48, 32, g["i0"]),
                  (80, 32, g["om"]), (112, 14, g["idot"])]),
        _word128([(0, 6, 3), (6, 10, g["iod"]), (16, 24, g["omd"]), (40, 16, g["dn"]),
                  (56, 16, g["cuc"]), (72, 16, g["cus"]), (88, 16, g["crc"]),
                  (104, 16, g["crs"]), (120, 8, g["sisa"])]),
        _word128([(0, 6, 4), (6, 10, g["iod"]), (16, 6, g["svid"]), (22, 16, g["cic"]),
                  (38, 16, g["cis"]), (54, 14, g["toc"]), (68, 31, g["af0"]),
                  (99, 21, g["af1"]), (120, 6, g["af2"])]),
        _word128([(0, 6, 5), (6, 11, 100), (17, 11, -20), (28, 14, 30), (47, 10, g["bgd_a"]),
                  (57, 10, g["bgd_b"]), (67, 2, 0), (69, 2, e1b_hs), (71, 1, 0),
                  (72, 1, e1b_dvs), (73, 12, g["wn"]), (85, 20, g["tow"])]),
    ]  # fmt: skip


def test_galileo_inav_round_trip_crc_and_assembly():
    rng = random.Random(7)
    pages = [encode_inav_page(w, rng) for w in galileo_words()]
    d1, d2, d3, d4, d5 = (decode_galileo_inav_page(p) for p in pages)
    g, sc = GAL, PI_ICD
    assert [d["word_type"] for d in (d1, d2, d3, d4, d5)] == [1, 2, 3, 4, 5]
    assert {d["iodnav"] for d in (d1, d2, d3, d4)} == {345}
    assert d1["toe_sow_s"] == 6830 * 60.0  # 409800 s: 30 min after word 5
    assert d1["ecc"] == g["e"] * 2.0**-33
    assert d1["m0_rad"] == pytest.approx(g["m0"] * 2.0**-31 * sc, rel=1e-15)
    assert d1["sqrt_a_sqrt_m"] == g["sqrta"] * 2.0**-19
    assert d2["omega0_rad"] == pytest.approx(g["om0"] * 2.0**-31 * sc, rel=1e-15)
    assert d2["i0_rad"] == pytest.approx(g["i0"] * 2.0**-31 * sc, rel=1e-15)
    assert d2["omega_rad"] == pytest.approx(g["om"] * 2.0**-31 * sc, rel=1e-15)
    assert d2["idot_rad_s"] == pytest.approx(g["idot"] * 2.0**-43 * sc, rel=1e-15)
    assert d3["omega_dot_rad_s"] == pytest.approx(g["omd"] * 2.0**-43 * sc, rel=1e-15)
    assert d3["delta_n_rad_s"] == pytest.approx(g["dn"] * 2.0**-43 * sc, rel=1e-15)
    assert (d3["cuc_rad"], d3["cus_rad"]) == (g["cuc"] * 2.0**-29, g["cus"] * 2.0**-29)
    assert (d3["crc_m"], d3["crs_m"], d3["sisa_index"]) == (6666 / 32, -777 / 32, 107)
    assert d4["svid"] == 11 and (d4["cic_rad"], d4["cis_rad"]) == (-88 * 2.0**-29, 99 * 2.0**-29)
    assert d4["toc_sow_s"] == 6830 * 60.0 and d4["af0_s"] == g["af0"] * 2.0**-34
    assert d4["af1_s_s"] == g["af1"] * 2.0**-46 and d4["af2_s_s2"] == 0.0
    assert (d5["bgd_e1e5a_s"], d5["bgd_e1e5b_s"]) == (-17 * 2.0**-32, -15 * 2.0**-32)
    assert (d5["e1b_hs"], d5["e1b_dvs"], d5["gst_week"], d5["gst_tow_s"]) == (0, 0, 1357, 408000)
    assert (d5["ai0_sfu"], d5["ai1_sfu_deg"], d5["ai2_sfu_deg2"]) == (25.0, -20 / 256, 30 / 2**15)

    # CRC-24Q: every single flipped bit of the protected 196 is caught; tail / pad are free
    words = pages[0]
    bits = sum(w << (32 * (7 - i)) for i, w in enumerate(words))
    for pos in [*range(0, 114), *range(128, 234)]:
        bad = bits ^ (1 << (255 - pos))
        bad_words = [(bad >> (32 * (7 - i))) & 0xFFFFFFFF for i in range(8)]
        assert decode_galileo_inav_page(bad_words) is None, pos
    tail = bits ^ (1 << (255 - 116)) ^ (1 << (255 - 250))
    assert decode_galileo_inav_page([(tail >> (32 * (7 - i))) & 0xFFFFFFFF for i in range(8)])

    # assembly: the week and TOW of word 5 give the time (GST week 0 = GPS week 1024)
    frames = [SfrbxWords(2, 11, 1, p) for p in pages]
    sick = [encode_inav_page(w, rng) for w in galileo_words(e1b_hs=1)]
    frames += [SfrbxWords(2, 12, 1, p) for p in sick]
    napa = [encode_inav_page(w, rng) for w in galileo_words({**GAL, "sisa": 255})]
    frames += [SfrbxWords(2, 13, 1, p) for p in napa]
    eph, rep = ephemeris_from_sfrbx(frames)
    assert rep.ephemerides == {"E11:inav": 1}
    assert rep.unhealthy == {"E12:inav": 1, "E13:inav": 1} and rep.rejected == {}
    assert rep.klobuchar_alpha is None
    np.testing.assert_array_equal(eph.iono_alpha, corrections.KLOBUCHAR_ALPHA_DEFAULT)
    k = eph.kepler
    toe_gps_s = (1357 + 1024) * WEEK_S + 6830 * 60.0
    assert float(eph.t_ref_gps_s) + float(k.toe_s[0, 0]) == toe_gps_s
    assert float(k.toe_week_s[0, 0]) == 6830 * 60.0
    assert float(k.tgd_s[0, 0]) == -17 * 2.0**-32  # BGD(E1,E5a), as the RINEX reader keeps
    assert float(k.gm[0, 0]) == ephemeris.GM_GAL and bool(k.valid[0, 0])


# ------------------------------------------------------------------------------------------------
# The real recording
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def walk():
    """SFRBX frames (receive time = the last RXM-RAWX epoch before them), RAWX and NAV-PVT."""
    from pyubx2 import ERR_RAISE, UBXReader

    frames, rawx, pvt = [], [], {}
    t_last = math.nan
    with open(UBX, "rb") as f:
        reader = UBXReader(f, protfilter=2, quitonerror=ERR_RAISE)
        while True:
            offset = f.tell()
            raw, msg = reader.read()
            if raw is None:
                break
            if msg.identity == "RXM-RAWX":
                t_last = msg.week * WEEK_S + msg.rcvTow
                rawx.append(msg)
            elif msg.identity == "NAV-PVT":
                pvt[msg.iTOW] = (msg.lat, msg.lon, msg.height * 1e-3)
            elif msg.identity == "RXM-SFRBX":
                words = tuple(getattr(msg, f"dwrd_{i:02d}") for i in range(1, msg.numWords + 1))
                frames.append(SfrbxWords(msg.gnssId, msg.svId, msg.sigId, words, t_last, offset))
    return frames, rawx, pvt


def _lnav(frames):
    return [f for f in frames if f.gnss_id == 0 and f.sig_id == 0]


def _inav(frames):
    return [f for f in frames if f.gnss_id == 2 and f.sig_id == 1]


@needs_data
def test_real_frames_pass_parity_crc_and_match_the_receive_time(walk):
    frames, _, _ = walk
    gps, gal = _lnav(frames), _inav(frames)
    assert len(gps) == 80 and len(gal) == 396  # the recording's content (brief)
    # the receiver forwards only words it has checked: an ICD-correct parity / CRC check must
    # accept every one of them
    decoded = [decode_gps_lnav_subframe(f.words) for f in gps]
    assert all(d is not None for d in decoded)
    pages = [decode_galileo_inav_page(f.words) for f in gal]
    assert all(p is not None for p in pages)
    # HOW: TOW count x 6 s = the end of the subframe just received; SFRBX follows it, and its
    # receive time here is the RAWX epoch before it (<= 0.25 s earlier at 4 Hz): within 3 s
    for f, d in zip(gps, decoded, strict=True):
        assert abs(d["tow_count"] * 6.0 - f.t_gps_s % WEEK_S) < 3.0
    # word type 5 / 0: GST (GST week 0 = GPS week 1024, GST = GPST) at the start of the 2 s
    # page pair: 2 s before its end, +- the 0.25 s RAWX epoch spacing and latency
    n = 0
    for f, p in zip(gal, pages, strict=True):
        if "gst_week" in p:
            gst = (p["gst_week"] + 1024) * WEEK_S + p["gst_tow_s"]
            assert -4.0 < gst - f.t_gps_s < 0.0
            n += 1
    assert n >= 7  # word 5 every 30 s on each of 7 satellites tracked for ~134 s


@pytest.fixture(scope="module")
def decoded(walk):
    frames, _, _ = walk
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no rejection warning on receiver-checked words
        inav = ephemeris_from_sfrbx(frames, galileo_source="inav")
        fnav = ephemeris_from_sfrbx(frames, galileo_source="fnav")
    return inav, fnav


def _subframe_runs_with_123(frames):
    """GPS satellites that sent subframes 1, 2, 3 back to back (HOW counts consecutive)."""
    seq: dict[int, list[tuple[int, int]]] = {}
    for f in _lnav(frames):
        d = decode_gps_lnav_subframe(f.words)
        seq.setdefault(f.sv_id, []).append((d["tow_count"], d["subframe_id"]))
    out = set()
    for sv, s in seq.items():
        for i in range(len(s) - 2):
            tows, ids = zip(*s[i : i + 3], strict=True)
            if ids == (1, 2, 3) and tows == (tows[0], tows[0] + 1, tows[0] + 2):
                out.add(sv)
    return out


@needs_data
def test_real_ephemerides_complete_and_orbits_physical(walk, decoded):
    frames, rawx, _ = walk
    (eph, rep), _ = decoded
    print(f"\nephemerides {rep.ephemerides}, unhealthy {rep.unhealthy}")
    assert rep.rejected == {} and rep.gps_week_assumed == 0
    system, prn = np.asarray(eph.system), np.asarray(eph.prn)
    gps = set(prn[system == SYS_GPS].tolist())
    gal = set(prn[system == SYS_GAL].tolist())
    # a GPS satellite that sent subframes 1-3 of one frame must have an ephemeris (the IODs of
    # one frame agree, IS-GPS-200 20.3.4.4)
    must = _subframe_runs_with_123(frames)
    assert must and must <= gps, (must, gps)
    # a Galileo satellite that sent word types 1-5 (one 30 s subframe) has one, healthy or not
    seen: dict[int, set] = {}
    for f in _inav(frames):
        seen.setdefault(f.sv_id, set()).add(decode_galileo_inav_page(f.words).get("word_type"))
    complete = {sv for sv, w in seen.items() if {1, 2, 3, 4, 5} <= w}
    sick = {int(k[1:3]) for k in rep.unhealthy if k.startswith("E")}
    assert complete and complete == gal | sick, (complete, gal, sick)
    assert len(gps) >= 4 and len(gal) >= 4

    k = eph.kepler
    valid = np.asarray(k.valid)
    assert np.all(valid.any(axis=1))
    a_m = np.where(valid, np.asarray(k.sqrt_a) ** 2, np.nan)
    ecc = np.where(valid, np.asarray(k.ecc), np.nan)
    is_gps = system == SYS_GPS
    # nominal semi-major axes: GPS 26 559.7 km (12 h sidereal period), Galileo 29 600.3 km
    # (14/17 day repeat); a few km of station keeping, 100 km allowed. Eccentricity: GPS
    # <= 0.02, Galileo FOC < 0.002 (E14 / E18, e = 0.16, are unhealthy here)
    a_nom = np.where(is_gps, 26559.7e3, 29600.3e3)
    assert np.nanmax(np.abs(a_m - a_nom[:, None])) < 100e3
    assert np.nanmax(np.where(is_gps[:, None], ecc, 0.0)) < 0.02
    assert np.nanmax(np.where(~is_gps[:, None], ecc, 0.0)) < 0.002
    # position at mid-file: r = a (1 - e cos E) lies within a (1 +- e_max) of the nominal axis
    # (the brief's +-200 km is too tight for GPS: G10, e = 0.0104, is at +224 km)
    t_mid = rawx[len(rawx) // 2].week * WEEK_S + rawx[len(rawx) // 2].rcvTow
    st = ephemeris.satellite_state(eph, t_mid - float(eph.t_ref_gps_s))
    assert np.all(np.asarray(st.ok))
    r = np.linalg.norm(np.asarray(st.pos_ecef), axis=1)
    print("radii [km]", dict(zip(prn.tolist(), np.round(r / 1e3, 1).tolist(), strict=True)))
    bound = np.where(is_gps, 0.02 * 26559.7e3 + 100e3, 200e3)
    assert np.all(np.abs(r - a_nom) < bound), r
    # energy: the inertial speed (ECEF velocity + w x r) obeys vis-viva v^2 = GM (2/r - 1/a)
    # to the J2 perturbation, J2 (R_E / r)^2 ~ 1e-4
    pos, vel = np.asarray(st.pos_ecef), np.asarray(st.vel_ecef)
    v_in = vel + np.cross([0.0, 0.0, geodesy.OMEGA_E], pos)
    a_sel = np.nanmax(a_m, axis=1)  # one record per satellite at mid-file is enough here
    vis_viva = np.asarray(k.gm)[:, 0] * (2.0 / r - 1.0 / a_sel)
    rel = np.sum(v_in**2, axis=1) / vis_viva - 1.0
    print("vis-viva relative", np.round(rel, 6))
    assert np.all(np.abs(rel) < 1e-3), rel


_sat_state = jax.jit(ephemeris.satellite_state)
RAWX_FIELDS = ("gnssId", "svId", "sigId", "prValid")


def _pseudorange_residuals(eph, raw, pvt):
    """L1 C/A / E1C pseudorange - modelled range per satellite of ``eph`` at one RAWX epoch,
    minus their median (the receiver clock); NaN without a pseudorange."""
    t_rx = raw.week * WEEK_S + raw.rcvTow
    pr = {}
    for i in range(1, raw.numMeas + 1):
        g, sv, sig, ok = (getattr(raw, f"{k}_{i:02d}") for k in RAWX_FIELDS)
        if g in (0, 2) and sig == 0 and ok:  # GPS L1 C/A, Galileo E1C
            pr[(SYS_GPS if g == 0 else SYS_GAL, sv)] = getattr(raw, f"prMes_{i:02d}")
    system, prn = np.asarray(eph.system), np.asarray(eph.prn)
    p = np.array([pr.get((int(s), int(n)), np.nan) for s, n in zip(system, prn, strict=True)])
    # the receiver at that epoch (RTK-fixed NAV-PVT; the walk spans ~20 m, so not the first fix)
    lat, lon, h = pvt[min(pvt, key=lambda itow: abs(itow - raw.rcvTow * 1e3))]
    llh = jnp.array([math.radians(lat), math.radians(lon), h])
    rcv = geodesy.llh_to_ecef(llh)
    dtr_s = 0.0
    for _ in range(3):  # receiver clock (-1.6 ms here) moves the transmit time: iterate
        t_sv = t_rx - dtr_s - p / C_LIGHT - float(eph.t_ref_gps_s)
        st0 = _sat_state(eph, jnp.asarray(t_sv))
        st = _sat_state(eph, jnp.asarray(t_sv) - st0.clock_s)
        rho, rot = corrections.geometric_range_m(rcv, st.pos_ecef)
        # satellite clock for a single-frequency user: af0 + af1 dt + af2 dt^2 + relativity
        # - TGD (GPS C/A, IS-GPS-200 20.3.3.3.3.2); Galileo E1: - BGD (the ephemeris keeps
        # BGD(E1,E5a), within 0.4 m of the I/NAV's BGD(E1,E5b) here)
        dts = (st.clock_s + corrections.relativistic_clock_s(st.pos_ecef, st.vel_ecef)
               - eph.kepler.tgd_s[:, 0])  # fmt: skip
        el, az = corrections.elevation_azimuth(rcv, rot, llh)
        trop = corrections.tropo_slant_delay_m(el, llh[0], llh[2], day_of_year(t_rx))
        iono = C_LIGHT * corrections.klobuchar_delay_s(
            llh[0], llh[1], az, el, t_rx % WEEK_S, eph.iono_alpha, eph.iono_beta
        )
        res = p - np.asarray(rho - C_LIGHT * dts + trop + iono)
        dtr_s = np.nanmedian(res) / C_LIGHT
    return res - np.nanmedian(res), np.degrees(np.asarray(el))


# Allowance for |residual - median| of a single-frequency user [m]: Klobuchar leaves 50 % or
# more of the slant ionosphere (up to ~10 m at low elevation near solar maximum, 2025; the
# file has no subframe 4 page 18, so the coefficients are the defaults), troposphere model
# ~0.5 m, pedestrian multipath and code noise ~5 m, broadcast orbit + clock ~2 m, a GPS-Galileo
# receiver bias of a few m. A wrong bit or scale in any ephemeris or clock field of weight gives
# hundreds of metres or more.
SF_RESIDUAL_TOL_M = 30.0


@needs_data
@pytest.mark.parametrize("source", ["inav", "fnav"])
def test_real_pseudorange_residuals_agree_across_satellites(walk, decoded, source):
    _, rawx, pvt = walk
    eph, _ = decoded[0] if source == "inav" else decoded[1]
    prn, system = np.asarray(eph.prn), np.asarray(eph.system)
    worst = 0.0
    for q in (2, 1, 3):  # mid-file, then a quarter and three quarters in
        raw = rawx[q * len(rawx) // 4]
        res, el = _pseudorange_residuals(eph, raw, pvt)
        if q == 2:  # every decoded satellite has an L1 C/A / E1C pseudorange at mid-file
            assert np.all(np.isfinite(res)), res
        assert np.sum(np.isfinite(res)) >= 8, res
        names = [f"{'G' if s == SYS_GPS else 'E'}{n:02d}" for s, n in zip(system, prn, strict=True)]
        shown = {nm: f"{r:+.2f} m @ {e:.0f} deg" for nm, r, e in zip(names, res, el, strict=True)}
        print(f"\n{source} t={raw.rcvTow:.2f}:", shown)
        worst = max(worst, float(np.nanmax(np.abs(res))))
    print(f"{source}: max |residual - median| {worst:.2f} m")
    assert worst < SF_RESIDUAL_TOL_M


@needs_data
def test_real_inav_and_fnav_carry_the_same_ephemeris(walk):
    """Galileo OS SIS ICD 5.1.9.2: one IODnav identifies one ephemeris, whichever message
    carries it; the clocks differ (E1/E5b vs E1/E5a references) by the BGDs, a few ns."""
    frames, _, _ = walk
    inav: dict = {}
    fnav: dict = {}
    for f in frames:
        if f.gnss_id == 2 and f.sig_id == 1:
            d = decode_galileo_inav_page(f.words)
            if d.get("word_type") in (1, 2, 3, 4):
                inav.setdefault((f.sv_id, d["iodnav"]), {}).update(d)
            if d.get("word_type") == 5:
                inav.setdefault((f.sv_id, "w5"), {}).update(d)
        elif f.gnss_id == 2 and f.sig_id == 3:
            d = decode_galileo_fnav_page(f.words)
            assert d is not None  # receiver-checked: the CRC must pass
            if d["page_type"] in (1, 2, 3, 4):
                fnav.setdefault((f.sv_id, d["iodnav"]), {}).update(d)
    orbit = ("toe_sow_s", "m0_rad", "ecc", "sqrt_a_sqrt_m", "omega0_rad", "i0_rad", "omega_rad",
             "idot_rad_s", "omega_dot_rad_s", "delta_n_rad_s", "cuc_rad", "cus_rad", "crc_m",
             "crs_m", "cic_rad", "cis_rad", "toc_sow_s", "svid")  # fmt: skip
    both = [key for key in set(inav) & set(fnav) if len(inav[key]) > 12 and len(fnav[key]) > 12]
    assert len(both) >= 4
    for key in both:
        a, b = inav[key], fnav[key]
        for name in orbit:
            if name in a and name in b:
                assert a[name] == b[name], (key, name)
        if "af0_s" in a and "af0_s" in b:
            assert abs(a["af0_s"] - b["af0_s"]) < 10e-9, key
        w5 = inav.get((key[0], "w5"))
        if w5 and "bgd_e1e5a_s" in b:
            assert w5["bgd_e1e5a_s"] == b["bgd_e1e5a_s"], key  # the same BGD(E1,E5a)


@needs_data
def test_real_klobuchar_if_present(decoded):
    (eph, rep), _ = decoded
    if rep.klobuchar_alpha is None:
        pytest.skip(
            "no GPS subframe 4 page 18 in the file (sent once per 12.5 min, the file lasts 134 s);"
            " the decoding is covered by test_gps_lnav_round_trip_exact"
        )
    alpha, beta = np.asarray(rep.klobuchar_alpha), np.asarray(rep.klobuchar_beta)
    assert np.all(np.isfinite(alpha)) and np.all(np.isfinite(beta))
    # IS-GPS-200 20.3.3.5.2.5: alpha0 ~ 1e-9..1e-7 s, beta0 ~ 1e4..3e5 s; the day-time vertical
    # delay at 40 deg N is between the 5 ns floor and ~50 m / c
    assert 1e-10 < abs(alpha[0]) < 2e-7 and 1e3 < beta[0] < 5e5
    vertical = corrections.klobuchar_vertical_delay_s(
        math.radians(40.1), math.radians(-105.1), 63000.0, alpha, beta
    )
    assert 5e-9 <= float(vertical) < 50.0 / C_LIGHT
