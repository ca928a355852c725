"""Broadcast ephemerides from u-blox UBX-RXM-SFRBX words: GPS LNAV, Galileo I/NAV and F/NAV.

The decoders work on the plain 32-bit integers ``dwrd_01 ... dwrd_NN`` of RXM-SFRBX messages
(:class:`SfrbxWords`; reading the UBX stream, e.g. with pyubx2, is the caller's business) as the
u-blox Interface Description ("Broadcast navigation data") lays them out:

- GPS L1 C/A (gnssId 0, sigId 0): 10 words, each the 30-bit navigation word in bits 29..0,
  complemented as a whole when D30* of the word before is 1 (data bits in their true sense; the
  parity then checks as in ``_gps_word_parity_ok``, on every word of the shared recording); the
  two bits above are pad.
- Galileo E1-B I/NAV (gnssId 2, sigId 1): 8 words = the even page part (words 1-4, 114 bits
  from bit 31 of word 1: even/odd, page type, 112 data bits, then tail and pad) and the odd page
  part (words 5-8: even/odd, page type, 16 data bits, OSNMA, SAR, spare, CRC-24Q, SSP, tail).
- Galileo E5a-I F/NAV (gnssId 2, sigId 3): 8 words = the 244-bit page from bit 31 of word 1
  (page type, 208 data bits, CRC-24Q, tail).

:func:`ephemeris_from_sfrbx` collects complete, consistent sets (GPS subframes 1-3 of one
IODC/IODE; Galileo word types 1-4 of one IODnav plus word type 5 for health, BGD and the week,
or F/NAV page types 1-4), turns them into the record dicts of ``io/nav.ephemeris_from_records``
(georinex field names, radians, seconds) and builds the ``BroadcastEphemeris`` with it.

Health policy (healthy only; the rest counted in :class:`NavDecodeReport`): GPS SV health (6 bits)
== 0; Galileo E1-B HS == 0 and DVS == 0 (I/NAV) or E5a HS == 0 and DVS == 0 (F/NAV), and SISA
!= 255 ("NAPA", no accuracy prediction available: the Galileo OS SDD calls such a signal
marginal, not healthy). The GPS URA index is kept in the record (``SVacc`` in metres) but not
used for selection.

Time: GST is taken equal to GPST (as ``io/rinex.py`` does: GST is steered to GPST, offset of a
few ns) and GST week 0 began at GPS week 1024 (1999-08-22), so Galileo times in GPS seconds are
(WN + 1024) 604800 + TOW; records carry ``GALWeek`` on the GPS week count, like RINEX 3.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from typing import NamedTuple

from jaxnav.core.gpstime import SECONDS_PER_WEEK
from jaxnav.gnss.ephemeris import BroadcastEphemeris
from jaxnav.io.nav import ephemeris_from_records

UBX_GNSS_GPS = 0
UBX_GNSS_GALILEO = 2
UBX_SIG_GPS_L1CA = 0
UBX_SIG_GAL_E1B = 1
UBX_SIG_GAL_E5AI = 3

# IS-GPS-200 20.3.3.4.3: the value of pi the broadcast parameters in semicircles are defined with
GPS_PI = 3.1415926535898
GPS_PREAMBLE = 0x8B  # TLM word bits 1-8 (IS-GPS-200 20.3.3.1)
GST_WEEK0_GPS_WEEK = 1024  # GST week 0 = GPS week 1024 (Galileo OS SIS ICD 5.1.2)
GAL_SISA_NAPA = 255  # "No Accuracy Prediction Available" (Galileo OS SIS ICD table 87)

# RINEX 3.05 table A8 "data sources" bits of Galileo records
_DATASRC_INAV_E1B = 1
_DATASRC_FNAV = 2
_DATASRC_CLOCK_E5A = 1 << 8
_DATASRC_CLOCK_E5B = 1 << 9

# GPS URA index -> nominal URA [m] (IS-GPS-200 20.3.3.3.1.3; index 15: no accuracy prediction)
_URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0,
          3072.0, 6144.0, math.nan)  # fmt: skip


class SfrbxWords(NamedTuple):
    """One UBX-RXM-SFRBX message: its navigation words as plain integers."""

    gnss_id: int  # UBX gnssId (0 GPS, 2 Galileo)
    sv_id: int
    sig_id: int  # UBX sigId (GPS 0 = L1 C/A; Galileo 1 = E1-B, 3 = E5a-I)
    words: tuple[int, ...]  # dwrd_01 ... dwrd_NN (unsigned 32-bit)
    t_gps_s: float = math.nan  # receive time in GPS seconds (NaN when unknown)
    offset: int = -1  # byte offset of the message in its file (for messages)


class NavDecodeReport(NamedTuple):
    """What :func:`ephemeris_from_sfrbx` read, rejected and assembled."""

    frames_read: int
    rejected: dict[str, int]  # kind -> frames failing preamble / parity / CRC / length / layout
    skipped: dict[str, int]  # kind -> frames not used (other signals, Galileo alert pages)
    ephemerides: dict[str, int]  # "G05:lnav", "E11:inav", "E11:fnav" -> complete healthy sets
    unhealthy: dict[str, int]  # same keys: complete sets left out by the health policy
    klobuchar_alpha: tuple[float, ...] | None  # [s, s/sc, s/sc^2, s/sc^3], GPS subfr. 4 p. 18
    klobuchar_beta: tuple[float, ...] | None  # [s, s/sc, s/sc^2, s/sc^3]
    gps_week_assumed: int  # GPS ephemerides whose 10-bit week was resolved without a time


# ------------------------------------------------------------------------------------------------
# Bit fields
# ------------------------------------------------------------------------------------------------


def _signed(value: int, n_bits: int) -> int:
    """Two's complement value of an n-bit field."""
    return value - (1 << n_bits) if value >> (n_bits - 1) else value


class _Bits:
    """An n-bit big-endian field reader; bit positions count from 0 (the first bit sent)."""

    def __init__(self, value: int, n_bits: int):
        self.value, self.n_bits = value, n_bits

    def u(self, start: int, length: int) -> int:
        return (self.value >> (self.n_bits - start - length)) & ((1 << length) - 1)

    def s(self, start: int, length: int) -> int:
        return _signed(self.u(start, length), length)


def _join_words(words: Sequence[int], bits_per_word: int) -> int:
    out = 0
    for w in words:
        out = (out << bits_per_word) | (int(w) & ((1 << bits_per_word) - 1))
    return out


# ------------------------------------------------------------------------------------------------
# GPS LNAV (IS-GPS-200)
# ------------------------------------------------------------------------------------------------

# IS-GPS-200 table 20-XIV: data bits d1..d24 entering each parity bit D25..D30, and whether
# D29* (True) or D30* (False) of the previous word is added to it.
_PARITY_TERMS = (
    (True, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (False, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (True, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (False, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (False, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (True, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)
_PARITY_MASKS = tuple(
    (use_d29, sum(1 << (24 - i) for i in bits)) for use_d29, bits in _PARITY_TERMS
)


def gps_lnav_parity(data_24: int, d29_prev: int, d30_prev: int) -> int:
    """The 6 parity bits D25..D30 of 24 source data bits d1..d24 (IS-GPS-200 table 20-XIV)."""
    out = 0
    for use_d29, mask in _PARITY_MASKS:
        bit = ((data_24 & mask).bit_count() + (d29_prev if use_d29 else d30_prev)) & 1
        out = (out << 1) | bit
    return out


def _gps_word_parity_ok(words: Sequence[int]) -> bool:
    """Parity of the 10 words as u-blox delivers them (data complemented for D30* already).

    The receiver XORs each whole 30-bit word with D30* of the transmitted word before it, so the
    data bits are the source bits d1..d24 and the parity bits are D25..D30 XOR D30*. By table
    20-XIV that equals the parity of d with (D29*, D30*) replaced by (D29* XOR D30*, 0), and
    D29* XOR D30* is unchanged by the complementing: it is bit 1 XOR bit 0 of the word before as
    delivered. Word 1 follows word 10 of the previous subframe, whose D29 = D30 = 0 (20.3.5.2).
    """
    q = 0
    for w in words:
        w = int(w) & 0x3FFFFFFF
        if gps_lnav_parity(w >> 6, q, 0) != w & 0x3F:
            return False
        q = ((w >> 1) ^ w) & 1
    return True


def _gps_reject_reason(words: Sequence[int]) -> str | None:
    if len(words) != 10:
        return "gps_lnav_length"
    if (int(words[0]) >> 22) & 0xFF != GPS_PREAMBLE:
        return "gps_lnav_preamble"
    if not _gps_word_parity_ok(words):
        return "gps_lnav_parity"
    return None


def decode_gps_lnav_subframe(words: Sequence[int]) -> dict | None:
    """Fields of one GPS LNAV subframe (IS-GPS-200 20.3.3.3 / 20.3.3.4, figure 20-1, tables 20-I,
    20-III, 20-V, 20-X) in SI units, or None when the preamble or the parity (table 20-XIV) fails.

    Always: ``subframe_id``, ``tow_count`` (HOW TOW of the *next* subframe, 6 s units),
    ``alert``, ``anti_spoof``. Subframe 1: clock and health; 2 and 3: ephemeris (rad, rad/s, m,
    s); 4 and 5: ``data_id``, ``page_sv_id``, and for subframe 4 page 18 (SV ID 56) the
    Klobuchar ``iono_alpha`` / ``iono_beta`` (s, s/sc, s/sc^2, s/sc^3) and UTC parameters.
    """
    if _gps_reject_reason(words) is not None:
        return None
    b = _Bits(_join_words(words, 30), 300)

    # IS-GPS-200 numbers bits 1..300 within the subframe: field(first bit, length)
    def u(first, n):
        return b.u(first - 1, n)

    def s(first, n):
        return b.s(first - 1, n)

    def s_split(first_msb, n_msb, first_lsb, n_lsb):  # a field split by the parity bits
        return _signed((u(first_msb, n_msb) << n_lsb) | u(first_lsb, n_lsb), n_msb + n_lsb)

    def u_split(first_msb, n_msb, first_lsb, n_lsb):
        return (u(first_msb, n_msb) << n_lsb) | u(first_lsb, n_lsb)

    sc = GPS_PI  # semicircles -> rad
    out = {
        "subframe_id": u(50, 3),
        "tow_count": u(31, 17),
        "alert": u(48, 1),
        "anti_spoof": u(49, 1),
    }
    sf = out["subframe_id"]
    if sf == 1:  # table 20-I
        out.update(
            week_mod1024=u(61, 10),
            l2_codes=u(71, 2),
            ura_index=u(73, 4),
            health=u(77, 6),
            iodc=u_split(83, 2, 211, 8),
            l2p_flag=u(91, 1),
            tgd_s=s(197, 8) * 2.0**-31,
            toc_sow_s=u(219, 16) * 16.0,
            af2_s_s2=s(241, 8) * 2.0**-55,
            af1_s_s=s(249, 16) * 2.0**-43,
            af0_s=s(271, 22) * 2.0**-31,
        )
    elif sf == 2:  # table 20-III
        out.update(
            iode=u(61, 8),
            crs_m=s(69, 16) * 2.0**-5,
            delta_n_rad_s=s(91, 16) * 2.0**-43 * sc,
            m0_rad=s_split(107, 8, 121, 24) * 2.0**-31 * sc,
            cuc_rad=s(151, 16) * 2.0**-29,
            ecc=u_split(167, 8, 181, 24) * 2.0**-33,
            cus_rad=s(211, 16) * 2.0**-29,
            sqrt_a_sqrt_m=u_split(227, 8, 241, 24) * 2.0**-19,
            toe_sow_s=u(271, 16) * 16.0,
            fit_interval_flag=u(287, 1),
            aodo_s=u(288, 5) * 900.0,
        )
    elif sf == 3:  # table 20-III
        out.update(
            cic_rad=s(61, 16) * 2.0**-29,
            omega0_rad=s_split(77, 8, 91, 24) * 2.0**-31 * sc,
            cis_rad=s(121, 16) * 2.0**-29,
            i0_rad=s_split(137, 8, 151, 24) * 2.0**-31 * sc,
            crc_m=s(181, 16) * 2.0**-5,
            omega_rad=s_split(197, 8, 211, 24) * 2.0**-31 * sc,
            omega_dot_rad_s=s(241, 24) * 2.0**-43 * sc,
            iode=u(271, 8),
            idot_rad_s=s(279, 14) * 2.0**-43 * sc,
        )
    elif sf in (4, 5):
        out.update(data_id=u(61, 2), page_sv_id=u(63, 6))
        if sf == 4 and out["page_sv_id"] == 56:  # page 18: table 20-X
            out.update(
                iono_alpha=(
                    s(69, 8) * 2.0**-30,
                    s(77, 8) * 2.0**-27,
                    s(91, 8) * 2.0**-24,
                    s(99, 8) * 2.0**-24,
                ),
                iono_beta=(
                    s(107, 8) * 2.0**11,
                    s(121, 8) * 2.0**14,
                    s(129, 8) * 2.0**16,
                    s(137, 8) * 2.0**16,
                ),
                utc_a1_s_s=s(151, 24) * 2.0**-50,
                utc_a0_s=s_split(181, 24, 211, 8) * 2.0**-30,
                utc_tot_s=u(219, 8) * 4096.0,
                utc_wnt=u(227, 8),
                delta_t_ls_s=float(s(241, 8)),
                utc_wnlsf=u(249, 8),
                utc_dn=u(257, 8),
                delta_t_lsf_s=float(s(271, 8)),
            )
    return out


def _resolve_gps_week(week_mod1024: int, t_hint_gps_s: float) -> int:
    """The full GPS week nearest the hint with this 10-bit week (IS-GPS-200 20.3.3.3.1.1)."""
    hint_week = t_hint_gps_s / SECONDS_PER_WEEK
    return week_mod1024 + 1024 * round((hint_week - week_mod1024) / 1024.0)


# GPS weeks 2048-3071 (2019-04-07 to 2038-11-20): the era assumed when no time is known
_GPS_ERA_FIRST_WEEK = 2048


def _nearest_week_time(sow_s: float, t_near_gps_s: float) -> float:
    """GPS seconds of a time of week in the week that puts it nearest ``t_near_gps_s``."""
    t = math.floor(t_near_gps_s / SECONDS_PER_WEEK) * SECONDS_PER_WEEK + sow_s
    return t + SECONDS_PER_WEEK * round((t_near_gps_s - t) / SECONDS_PER_WEEK)


def _gps_record(sf1: dict, sf2: dict, sf3: dict, full_week: int) -> dict:
    """georinex-named record (RINEX 3.04 table A6) of one consistent subframe 1-3 set."""
    # HOW TOW count = start of the next subframe; subframe 1 started 6 s before (in week WN)
    sow_tx = (sf1["tow_count"] * 6.0 - 6.0) % SECONDS_PER_WEEK
    t_tx = full_week * SECONDS_PER_WEEK + sow_tx
    return {
        "SVclockBias": sf1["af0_s"],
        "SVclockDrift": sf1["af1_s_s"],
        "SVclockDriftRate": sf1["af2_s_s2"],
        "IODE": float(sf2["iode"]),
        "Crs": sf2["crs_m"],
        "DeltaN": sf2["delta_n_rad_s"],
        "M0": sf2["m0_rad"],
        "Cuc": sf2["cuc_rad"],
        "Eccentricity": sf2["ecc"],
        "Cus": sf2["cus_rad"],
        "sqrtA": sf2["sqrt_a_sqrt_m"],
        "Toe": sf2["toe_sow_s"],
        "Cic": sf3["cic_rad"],
        "Omega0": sf3["omega0_rad"],
        "Cis": sf3["cis_rad"],
        "Io": sf3["i0_rad"],
        "Crc": sf3["crc_m"],
        "omega": sf3["omega_rad"],
        "OmegaDot": sf3["omega_dot_rad_s"],
        "IDOT": sf3["idot_rad_s"],
        "CodesL2": float(sf1["l2_codes"]),
        "GPSWeek": float(full_week),
        "L2Pflag": float(sf1["l2p_flag"]),
        "SVacc": _URA_M[sf1["ura_index"]],
        "health": float(sf1["health"]),
        "TGD": sf1["tgd_s"],
        "IODC": float(sf1["iodc"]),
        "TransTime": sow_tx,
        "FitIntvl": 4.0 if sf2["fit_interval_flag"] == 0 else 6.0,  # hours (at least)
        "_toc": _nearest_week_time(sf1["toc_sow_s"], t_tx),
    }


# ------------------------------------------------------------------------------------------------
# Galileo I/NAV and F/NAV (Galileo OS SIS ICD)
# ------------------------------------------------------------------------------------------------

_CRC24Q_POLY = 0x864CFB  # Galileo OS SIS ICD 5.1.9.4 / RTCM: G(X) = (1 + X) P(X)


def crc24q(value: int, n_bits: int) -> int:
    """CRC-24Q of the n-bit message ``value`` (first bit = MSB), zero initial value."""
    crc = 0
    for i in range(n_bits - 1, -1, -1):
        top = ((crc >> 23) ^ (value >> i)) & 1
        crc = (crc << 1) & 0xFFFFFF
        if top:
            crc ^= _CRC24Q_POLY
    return crc


def _sisa_m(index: int) -> float:
    """SISA index -> metres (Galileo OS SIS ICD table 87); NaN for spare values and NAPA."""
    if index < 50:
        return 0.01 * index
    if index < 75:
        return 0.5 + 0.02 * (index - 50)
    if index < 100:
        return 1.0 + 0.04 * (index - 75)
    if index < 126:
        return 2.0 + 0.16 * (index - 100)
    return math.nan


def _inav_reject_reason(words: Sequence[int]) -> str | None:
    if len(words) != 8:
        return "gal_inav_length"
    b = _Bits(_join_words(words, 32), 256)
    if b.u(0, 1) != 0 or b.u(128, 1) != 1:  # even part first, then odd (ICD table 39)
        return "gal_inav_layout"
    # CRC over the even part's 114 bits and the odd part's first 82 (up to the CRC) (4.3.2.1)
    protected = (b.u(0, 114) << 82) | b.u(128, 82)
    if crc24q(protected, 196) != b.u(210, 24):
        return "gal_inav_crc"
    return None


def decode_galileo_inav_page(words: Sequence[int]) -> dict | None:
    """The I/NAV word of one E1-B page pair (Galileo OS SIS ICD 4.3.2 table 39 and 4.3.5 word
    types 0-6, tables 40-45) in SI units; None when the layout or CRC-24Q fails;
    ``{"alert": True}`` for an alert page (no navigation word).

    Word types 1-4: ephemeris and clock (``iodnav``, rad, rad/s, m, s); 5: ``e1b_hs``,
    ``e1b_dvs``, ``e5b_hs``, ``e5b_dvs``, BGDs [s], ``gst_week``, ``gst_tow_s``, NeQuick ai;
    0: ``gst_week`` / ``gst_tow_s`` when its time field is 2; 6: GST-UTC and ``gst_tow_s``.
    """
    if _inav_reject_reason(words) is not None:
        return None
    b = _Bits(_join_words(words, 32), 256)
    if b.u(1, 1) or b.u(129, 1):  # page type 1: alert page, no navigation word
        return {"alert": True}
    w = _Bits((b.u(2, 112) << 16) | b.u(130, 16), 128)  # the 128-bit word (ICD 4.3.2)
    return _decode_inav_word(w)


def _decode_inav_word(w: _Bits) -> dict:
    sc = GPS_PI  # semicircles -> rad (the Galileo ICD uses the same pi)
    wt = w.u(0, 6)
    out: dict = {"word_type": wt, "alert": False}
    if wt == 1:  # table 40
        out.update(
            iodnav=w.u(6, 10),
            toe_sow_s=w.u(16, 14) * 60.0,
            m0_rad=w.s(30, 32) * 2.0**-31 * sc,
            ecc=w.u(62, 32) * 2.0**-33,
            sqrt_a_sqrt_m=w.u(94, 32) * 2.0**-19,
        )
    elif wt == 2:  # table 41
        out.update(
            iodnav=w.u(6, 10),
            omega0_rad=w.s(16, 32) * 2.0**-31 * sc,
            i0_rad=w.s(48, 32) * 2.0**-31 * sc,
            omega_rad=w.s(80, 32) * 2.0**-31 * sc,
            idot_rad_s=w.s(112, 14) * 2.0**-43 * sc,
        )
    elif wt == 3:  # table 42
        out.update(
            iodnav=w.u(6, 10),
            omega_dot_rad_s=w.s(16, 24) * 2.0**-43 * sc,
            delta_n_rad_s=w.s(40, 16) * 2.0**-43 * sc,
            cuc_rad=w.s(56, 16) * 2.0**-29,
            cus_rad=w.s(72, 16) * 2.0**-29,
            crc_m=w.s(88, 16) * 2.0**-5,
            crs_m=w.s(104, 16) * 2.0**-5,
            sisa_index=w.u(120, 8),
        )
    elif wt == 4:  # table 43
        out.update(
            iodnav=w.u(6, 10),
            svid=w.u(16, 6),
            cic_rad=w.s(22, 16) * 2.0**-29,
            cis_rad=w.s(38, 16) * 2.0**-29,
            toc_sow_s=w.u(54, 14) * 60.0,
            af0_s=w.s(68, 31) * 2.0**-34,
            af1_s_s=w.s(99, 21) * 2.0**-46,
            af2_s_s2=w.s(120, 6) * 2.0**-59,
        )
    elif wt == 5:  # table 44
        out.update(
            ai0_sfu=w.u(6, 11) * 2.0**-2,
            ai1_sfu_deg=w.s(17, 11) * 2.0**-8,
            ai2_sfu_deg2=w.s(28, 14) * 2.0**-15,
            bgd_e1e5a_s=w.s(47, 10) * 2.0**-32,
            bgd_e1e5b_s=w.s(57, 10) * 2.0**-32,
            e5b_hs=w.u(67, 2),
            e1b_hs=w.u(69, 2),
            e5b_dvs=w.u(71, 1),
            e1b_dvs=w.u(72, 1),
            gst_week=w.u(73, 12),
            gst_tow_s=float(w.u(85, 20)),
        )
    elif wt == 0:  # table 45 (spare word): WN / TOW valid only when the time field is 2
        if w.u(6, 2) == 2:
            out.update(gst_week=w.u(96, 12), gst_tow_s=float(w.u(108, 20)))
    elif wt == 6:  # table 45 (GST-UTC conversion)
        out.update(
            utc_a0_s=w.s(6, 32) * 2.0**-30,
            utc_a1_s_s=w.s(38, 24) * 2.0**-50,
            delta_t_ls_s=float(w.s(62, 8)),
            utc_tot_s=w.u(70, 8) * 3600.0,
            gst_tow_s=float(w.u(105, 20)),
        )
    return out


def _fnav_reject_reason(words: Sequence[int]) -> str | None:
    if len(words) != 8:
        return "gal_fnav_length"
    b = _Bits(_join_words(words, 32), 256)
    if crc24q(b.u(0, 214), 214) != b.u(214, 24):  # CRC over page type + data (4.2.2.1)
        return "gal_fnav_crc"
    return None


def decode_galileo_fnav_page(words: Sequence[int]) -> dict | None:
    """Fields of one E5a-I F/NAV page (Galileo OS SIS ICD 4.2.2 table 33 and 4.2.4 page types
    1-4, tables 34-37) in SI units, or None when the CRC-24Q fails.

    Page type 1: clock, ``sisa_index``, ``bgd_e1e5a_s``, ``e5a_hs``, ``e5a_dvs``, ``gst_week``,
    ``gst_tow_s``; 2-4: ephemeris (``iodnav``, rad, rad/s, m, s) and the GST of 2-4.
    """
    if _fnav_reject_reason(words) is not None:
        return None
    w = _Bits(_join_words(words, 32), 256)
    sc = GPS_PI
    pt = w.u(0, 6)
    out: dict = {"page_type": pt}
    if pt == 1:  # table 34
        out.update(
            svid=w.u(6, 6),
            iodnav=w.u(12, 10),
            toc_sow_s=w.u(22, 14) * 60.0,
            af0_s=w.s(36, 31) * 2.0**-34,
            af1_s_s=w.s(67, 21) * 2.0**-46,
            af2_s_s2=w.s(88, 6) * 2.0**-59,
            sisa_index=w.u(94, 8),
            bgd_e1e5a_s=w.s(143, 10) * 2.0**-32,
            e5a_hs=w.u(153, 2),
            gst_week=w.u(155, 12),
            gst_tow_s=float(w.u(167, 20)),
            e5a_dvs=w.u(187, 1),
        )
    elif pt == 2:  # table 35
        out.update(
            iodnav=w.u(6, 10),
            m0_rad=w.s(16, 32) * 2.0**-31 * sc,
            omega_dot_rad_s=w.s(48, 24) * 2.0**-43 * sc,
            ecc=w.u(72, 32) * 2.0**-33,
            sqrt_a_sqrt_m=w.u(104, 32) * 2.0**-19,
            omega0_rad=w.s(136, 32) * 2.0**-31 * sc,
            idot_rad_s=w.s(168, 14) * 2.0**-43 * sc,
            gst_week=w.u(182, 12),
            gst_tow_s=float(w.u(194, 20)),
        )
    elif pt == 3:  # table 36
        out.update(
            iodnav=w.u(6, 10),
            i0_rad=w.s(16, 32) * 2.0**-31 * sc,
            omega_rad=w.s(48, 32) * 2.0**-31 * sc,
            delta_n_rad_s=w.s(80, 16) * 2.0**-43 * sc,
            cuc_rad=w.s(96, 16) * 2.0**-29,
            cus_rad=w.s(112, 16) * 2.0**-29,
            crc_m=w.s(128, 16) * 2.0**-5,
            crs_m=w.s(144, 16) * 2.0**-5,
            toe_sow_s=w.u(160, 14) * 60.0,
            gst_week=w.u(174, 12),
            gst_tow_s=float(w.u(186, 20)),
        )
    elif pt == 4:  # table 37
        out.update(
            iodnav=w.u(6, 10),
            cic_rad=w.s(16, 16) * 2.0**-29,
            cis_rad=w.s(32, 16) * 2.0**-29,
            gst_tow_s=float(w.u(189, 20)),
        )
    return out


def _gst_to_gps_s(gst_week: int, gst_tow_s: float, t_hint_gps_s: float) -> float:
    """GPS seconds of a GST week (12 bits) and TOW (GST = GPST; GST week 0 = GPS week 1024)."""
    week = gst_week + GST_WEEK0_GPS_WEEK
    if math.isfinite(t_hint_gps_s):  # the 12-bit week rolls over every 4096 weeks (2078)
        week += 4096 * round((t_hint_gps_s / SECONDS_PER_WEEK - week) / 4096.0)
    return week * SECONDS_PER_WEEK + gst_tow_s


def _galileo_record(eph: dict, clock: dict, t_tx_gps_s: float, data_src: int) -> dict:
    """georinex-named record (RINEX 3.04 table A8) of one Galileo ephemeris set."""
    week = math.floor(t_tx_gps_s / SECONDS_PER_WEEK)
    return {
        "SVclockBias": clock["af0_s"],
        "SVclockDrift": clock["af1_s_s"],
        "SVclockDriftRate": clock["af2_s_s2"],
        "IODnav": float(eph["iodnav"]),
        "Crs": eph["crs_m"],
        "DeltaN": eph["delta_n_rad_s"],
        "M0": eph["m0_rad"],
        "Cuc": eph["cuc_rad"],
        "Eccentricity": eph["ecc"],
        "Cus": eph["cus_rad"],
        "sqrtA": eph["sqrt_a_sqrt_m"],
        "Toe": eph["toe_sow_s"],
        "Cic": eph["cic_rad"],
        "Omega0": eph["omega0_rad"],
        "Cis": eph["cis_rad"],
        "Io": eph["i0_rad"],
        "Crc": eph["crc_m"],
        "omega": eph["omega_rad"],
        "OmegaDot": eph["omega_dot_rad_s"],
        "IDOT": eph["idot_rad_s"],
        "DataSrc": float(data_src),
        "GALWeek": float(week),  # GPS week count, as in RINEX 3
        "SISA": _sisa_m(eph["sisa_index"]),
        "TransTime": t_tx_gps_s - week * SECONDS_PER_WEEK,
        "_toc": _nearest_week_time(clock["toc_sow_s"], t_tx_gps_s),
    }


# ------------------------------------------------------------------------------------------------
# Assembly
# ------------------------------------------------------------------------------------------------


class _Sat:
    """Latest decoded pieces of one satellite's navigation message."""

    def __init__(self):
        self.parts: dict = {}  # GPS subframe id / Galileo word or page type -> fields
        self.t_hint_gps_s = math.nan  # receive time of the latest frame
        self.gst_gps_s = math.nan  # latest GST (in GPS seconds) read from the message
        self.gst_at_rx_gps_s = math.nan  # receive time when that GST was read


def _count(d: dict, key: str, n: int = 1):
    d[key] = d.get(key, 0) + n


def _gps_set(st: _Sat, t_ref_gps_s: float | None):
    """(key, record, healthy, week assumed) of the subframe 1-3 set of ``st``, or None."""
    sf1, sf2, sf3 = (st.parts.get(k) for k in (1, 2, 3))
    if not (sf1 and sf2 and sf3) or not (sf1["iodc"] & 0xFF == sf2["iode"] == sf3["iode"]):
        return None  # incomplete, or subframes of two data sets (IS-GPS-200 20.3.4.4)
    hint = st.t_hint_gps_s
    if not math.isfinite(hint) and t_ref_gps_s is not None:
        hint = float(t_ref_gps_s)
    assumed = not math.isfinite(hint)
    if assumed:
        week = _GPS_ERA_FIRST_WEEK + (sf1["week_mod1024"] - _GPS_ERA_FIRST_WEEK) % 1024
    else:
        week = _resolve_gps_week(sf1["week_mod1024"], hint)
    key = ("lnav", sf1["iodc"], sf2["toe_sow_s"], sf1["toc_sow_s"])
    return key, _gps_record(sf1, sf2, sf3, week), sf1["health"] == 0, assumed


def _galileo_set(st: _Sat, inav: bool):
    """(key, record, healthy) of the I/NAV word 1-5 or F/NAV page 1-4 set of ``st``, or None."""
    eph_parts = [st.parts.get(k) for k in (1, 2, 3, 4)]
    status = st.parts.get(5) if inav else st.parts.get(1)  # health, BGD
    if not all(eph_parts) or status is None or len({p["iodnav"] for p in eph_parts}) != 1:
        return None
    # transmission time: the latest GST read, carried forward with the receive time
    t_tx = st.gst_gps_s
    if math.isfinite(st.gst_at_rx_gps_s) and math.isfinite(st.t_hint_gps_s):
        t_tx += st.t_hint_gps_s - st.gst_at_rx_gps_s
    if not math.isfinite(t_tx):
        t_tx = st.t_hint_gps_s
    if not math.isfinite(t_tx):
        return None  # no week yet: a later word 5 / 0 (page 1-3) completes it
    eph = {k: v for p in eph_parts for k, v in p.items()}
    clock = st.parts[4] if inav else st.parts[1]
    if inav:
        rec = _galileo_record(eph, clock, t_tx, _DATASRC_INAV_E1B | _DATASRC_CLOCK_E5B)
        rec.update(
            BGDe5a=status["bgd_e1e5a_s"],
            BGDe5b=status["bgd_e1e5b_s"],
            # RINEX health bits of E1-B (bit 0 DVS, bits 1-2 HS); E5b's kept apart (not used)
            health=float(status["e1b_dvs"] | status["e1b_hs"] << 1),
            E5bHS=float(status["e5b_hs"]),
            E5bDVS=float(status["e5b_dvs"]),
        )
    else:
        rec = _galileo_record(eph, clock, t_tx, _DATASRC_FNAV | _DATASRC_CLOCK_E5A)
        # RINEX health bits of E5a (bit 3 DVS, bits 4-5 HS)
        rec.update(
            BGDe5a=status["bgd_e1e5a_s"],
            health=float(status["e5a_dvs"] << 3 | status["e5a_hs"] << 4),
        )
    healthy = rec["health"] == 0.0 and eph["sisa_index"] != GAL_SISA_NAPA
    key = ("inav" if inav else "fnav", eph["iodnav"], eph["toe_sow_s"], clock["toc_sow_s"])
    return key, rec, healthy


def ephemeris_from_sfrbx(
    frames: Iterable[SfrbxWords],
    *,
    t_ref_gps_s: float | None = None,
    galileo_source: str = "fnav",
) -> tuple[BroadcastEphemeris, NavDecodeReport]:
    """``BroadcastEphemeris`` (healthy records only) and a report from RXM-SFRBX frames.

    Assembles GPS LNAV subframes 1-3 with IODC (low 8 bits) == IODE of subframes 2 and 3
    (IS-GPS-200 20.3.4.4), Galileo I/NAV word types 1-4 with one IODnav plus word type 5
    (Galileo OS SIS ICD 4.3.5) and F/NAV page types 1-4 with one IODnav (4.2.4); each distinct
    set becomes one record of ``io/nav.ephemeris_from_records``. Frames in receive order.
    ``galileo_source`` picks F/NAV or I/NAV per satellite when both were decoded, as in
    ``read_broadcast_ephemeris``. The 10-bit GPS week is resolved with the frames' receive
    time, else ``t_ref_gps_s``, else the 2019-2038 week era (counted in the report). Klobuchar
    alpha/beta come from GPS subframe 4 page 18 when received (else the module defaults).
    Frames failing preamble, parity or CRC are rejected with one warning per kind and counted.
    Raises ``ValueError`` when no complete healthy ephemeris was found.
    """
    rejected: dict[str, int] = {}
    skipped: dict[str, int] = {}
    unhealthy: dict[str, int] = {}
    sats: dict[str, _Sat] = {}
    records: dict[str, dict[tuple, dict | None]] = {}  # sat -> set key -> record (None: sick)
    alpha = beta = None
    n_read = 0
    n_week_assumed = 0

    for fr in frames:
        n_read += 1
        words = tuple(int(w) for w in fr.words)
        t_rx = float(fr.t_gps_s)
        gps = fr.gnss_id == UBX_GNSS_GPS and fr.sig_id == UBX_SIG_GPS_L1CA
        gal = fr.gnss_id == UBX_GNSS_GALILEO and fr.sig_id in (UBX_SIG_GAL_E1B, UBX_SIG_GAL_E5AI)
        if not (gps or gal):
            _count(skipped, f"gnss{fr.gnss_id}_sig{fr.sig_id}")
            continue
        inav = gal and fr.sig_id == UBX_SIG_GAL_E1B
        if gps:
            reason = _gps_reject_reason(words)
        else:
            reason = _inav_reject_reason(words) if inav else _fnav_reject_reason(words)
        if reason:
            _count(rejected, reason)
            continue
        name = f"{'G' if gps else 'E'}{fr.sv_id:02d}"
        st = sats.setdefault(name + ("_fnav" if gal and not inav else ""), _Sat())
        if math.isfinite(t_rx):
            st.t_hint_gps_s = t_rx
        if gps:
            d = decode_gps_lnav_subframe(words)
            kind = d["subframe_id"]
            if kind == 4 and "iono_alpha" in d:
                alpha, beta = d["iono_alpha"], d["iono_beta"]
            if kind not in (1, 2, 3):
                continue
        else:
            d = decode_galileo_inav_page(words) if inav else decode_galileo_fnav_page(words)
            if d.get("alert"):
                _count(skipped, "gal_inav_alert")
                continue
            kind = d["word_type"] if inav else d["page_type"]
            if "gst_week" in d:
                st.gst_gps_s = _gst_to_gps_s(d["gst_week"], d["gst_tow_s"], st.t_hint_gps_s)
                st.gst_at_rx_gps_s = t_rx
            if kind not in ((1, 2, 3, 4, 5) if inav else (1, 2, 3, 4)):
                continue
        st.parts[kind] = d
        found = _gps_set(st, t_ref_gps_s) if gps else _galileo_set(st, inav)
        if found is None or found[0] in records.setdefault(name, {}):
            continue
        key, rec, healthy = found[:3]
        records[name][key] = rec if healthy else None  # an unhealthy set is counted once
        if not healthy:
            _count(unhealthy, f"{name}:{key[0]}")
        if gps and found[3]:
            n_week_assumed += 1

    for kind, n in sorted(rejected.items()):
        warnings.warn(
            f"ephemeris_from_sfrbx: {n} RXM-SFRBX frame(s) rejected ({kind})", stacklevel=2
        )
    recs: dict[str, list[dict]] = {}
    n_eph: dict[str, int] = {}
    for name, got in sorted(records.items()):
        for key, rec in got.items():
            if rec is not None:
                recs.setdefault(name, []).append(rec)
                _count(n_eph, f"{name}:{key[0]}")
    report = NavDecodeReport(
        frames_read=n_read,
        rejected=rejected,
        skipped=skipped,
        ephemerides=n_eph,
        unhealthy=unhealthy,
        klobuchar_alpha=alpha,
        klobuchar_beta=beta,
        gps_week_assumed=n_week_assumed,
    )
    if not recs:
        raise ValueError(f"no complete healthy GPS/Galileo ephemeris in the frames: {report}")
    eph = ephemeris_from_records(
        recs,
        t_ref_gps_s=t_ref_gps_s,
        iono_alpha=alpha,
        iono_beta=beta,
        galileo_source=galileo_source,
    )
    return eph, report
