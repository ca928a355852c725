"""GNSS constellations, carrier frequencies, wavelengths, combination coefficients and slots.

Systems are small integers (``SYS_GPS``, ``SYS_GLO``, ``SYS_GAL``) so that per-slot tables are
plain integer arrays that ``jit``/``vmap`` can carry. Every satellite signal is addressed by
(system, band, GLONASS channel):

- band 0 is the first PPP frequency (GPS L1, GLONASS G1, Galileo E1),
- band 1 is the second PPP frequency (GPS L2, GLONASS G2, Galileo E5a),
- band 2 is a third frequency (GPS L5, GLONASS G3 (CDMA), Galileo E5b).

The dual-frequency PPP pair of every system is bands (0, 1) (S002 ch. 5 uses GPS L1/L2 and
GLONASS G1/G2; S004 uses Galileo E1/E5a).

Code observables carry a *code type*: ``CODE_C1`` (civil code on band 0: GPS C/A, GLONASS C/A,
Galileo E1), ``CODE_P1`` (precise code on band 0: GPS P(Y)/C1W, GLONASS P, Galileo E1 second
tracked component) and ``CODE_P2`` (code on band 1: GPS P2/C2W, GLONASS P2, Galileo E5a).

Fixed slots (DESIGN.md invariant 2)
-----------------------------------
A scenario has a fixed number of slots per constellation, GPS slots first, then GLONASS, then
Galileo (S002 eq 5.22 stacks GPS rows first). :func:`assign_slots` fills them with the satellites
that are above the elevation mask at any epoch of the scenario, in PRN order; unused slots are
padded with ``occupied = False`` and are always masked. A satellite keeps its slot for the whole
scenario; when it sets and rises again its observations restart in the same slot (with a new
ambiguity arc). If more satellites of a system are visible than it has slots, assign_slots raises.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxnav.geodesy import C_LIGHT

SYS_GPS = 0
SYS_GLO = 1
SYS_GAL = 2
N_SYSTEMS = 3
SYSTEM_NAMES = ("GPS", "GLONASS", "Galileo")
SYSTEM_LETTERS = ("G", "R", "E")  # RINEX system identifiers

N_BANDS = 3
BAND_NAMES = (("L1", "L2", "L5"), ("G1", "G2", "G3"), ("E1", "E5a", "E5b"))

# Carrier frequency f = BASE + k * STEP [Hz], k = GLONASS FDMA channel (0 for CDMA signals).
# GPS: IS-GPS-200 (L1 = 154 f0, L2 = 120 f0) and IS-GPS-705 (L5 = 115 f0), f0 = 10.23 MHz.
# GLONASS: ICD L1/L2 FDMA: G1 = 1602 + k 0.5625 MHz, G2 = 1246 + k 0.4375 MHz; G3 CDMA 1202.025
# MHz (ICD L3OC). Galileo: OS SIS ICD (E1 = 154 f0, E5a = 115 f0, E5b = 118 f0).
_F0 = 10.23e6
BAND_BASE_HZ = np.array(
    [
        [154 * _F0, 120 * _F0, 115 * _F0],
        [1602.0e6, 1246.0e6, 1202.025e6],
        [154 * _F0, 115 * _F0, 118 * _F0],
    ]
)
BAND_STEP_HZ = np.array(
    [
        [0.0, 0.0, 0.0],
        [0.5625e6, 0.4375e6, 0.0],
        [0.0, 0.0, 0.0],
    ]
)
# Integer multipliers n_b of a per-signal fundamental (f_b = n_b f_fund) used for the integer
# nature of the ionosphere-free ambiguity: GPS/Galileo f_fund = 10.23 MHz; GLONASS FDMA
# f_fund = (2848 + k) 0.0625 MHz so G1 = 9 f_fund and G2 = 7 f_fund for every channel. G3 is not
# commensurate with G1/G2 (0 = undefined).
BAND_MULTIPLIER = np.array(
    [
        [154, 120, 115],
        [9, 7, 0],
        [154, 115, 118],
    ],
    dtype=np.int64,
)
GPS_L1_HZ = float(BAND_BASE_HZ[SYS_GPS, 0])  # reference frequency of Klobuchar / "L1" delays

GLO_CHANNEL_MIN, GLO_CHANNEL_MAX = -7, 6  # ICD: channels k = -7..+6 since 2005

CODE_C1, CODE_P1, CODE_P2 = 0, 1, 2
N_CODES = 3
CODE_NAMES = ("C1", "P1", "P2")
CODE_BAND = (0, 0, 1)  # band carried by each code type
PPP_BANDS = (0, 1)  # the dual-frequency PPP pair of every system

# Default number of satellite slots per system (GPS, GLONASS, Galileo). Chosen from counts of
# the satellites ever above 10 deg in a window (latitudes 0-60 deg, nominal constellations and
# the real 2020-06-25 broadcast constellation): any 2 h window needs at most 16 / 13 / 12,
# a 4 h window up to 21 / 17 / 15. Pass larger numbers for longer scenarios (assign_slots
# raises if a system overflows).
DEFAULT_SLOTS_PER_SYSTEM = (16, 14, 14)


def carrier_frequency_hz(
    system: Int[ArrayLike, "*#S"],
    band: Int[ArrayLike, "*#S"],
    glo_channel: Int[ArrayLike, "*#S"] = 0,
) -> Float[Array, "*#S"]:
    """Carrier frequency f = base(system, band) + k step(system, band) [Hz] (k: GLONASS channel)."""
    base = jnp.asarray(BAND_BASE_HZ)[system, band]
    step = jnp.asarray(BAND_STEP_HZ)[system, band]
    return base + jnp.asarray(glo_channel, dtype=jnp.float64) * step


def wavelength_m(freq_hz):
    """Carrier wavelength lambda = c / f [m]."""
    return C_LIGHT / freq_hz


def iono_scale(f_ref_hz, f_hz):
    """First-order ionosphere scale I_j = (f_ref / f_j)^2 I_ref (S002 eq 2.25)."""
    return (f_ref_hz / f_hz) ** 2


def if_coefficients(f1_hz, f2_hz):
    """Ionosphere-free weights alpha = f1^2/(f1^2 - f2^2), beta = -f2^2/(f1^2 - f2^2) (S002 2.3).

    GPS L1/L2: alpha = 2.546, beta = -1.546 (SEED_SPEC 4, S000 item 10: 2.546, not 2.54).
    """
    d = f1_hz**2 - f2_hz**2
    return f1_hz**2 / d, -(f2_hz**2) / d


def gf_coefficients(f1_hz, f2_hz):
    """Geometry-free weights (alpha, beta) = (1, -1) (S002 2.27); the arguments set the shape."""
    one = jnp.ones_like(jnp.asarray(f1_hz + f2_hz, dtype=jnp.float64))
    return one, -one


def wl_coefficients(f1_hz, f2_hz):
    """Wide-lane weights alpha = f1/(f1 - f2), beta = -f2/(f1 - f2) (S002 2.28)."""
    d = f1_hz - f2_hz
    return f1_hz / d, -f2_hz / d


def nl_coefficients(f1_hz, f2_hz):
    """Narrow-lane weights alpha = f1/(f1 + f2), beta = f2/(f1 + f2) (S002 2.29)."""
    s = f1_hz + f2_hz
    return f1_hz / s, f2_hz / s


def wl_wavelength_m(f1_hz, f2_hz):
    """Wide-lane wavelength c / (f1 - f2) (GPS: 86.2 cm)."""
    return C_LIGHT / (f1_hz - f2_hz)


def nl_wavelength_m(f1_hz, f2_hz):
    """Narrow-lane wavelength c / (f1 + f2) (GPS: 10.7 cm; also the IF wind-up wavelength)."""
    return C_LIGHT / (f1_hz + f2_hz)


def combination_noise_factor(alpha, beta):
    """Noise amplification sqrt(alpha^2 + beta^2) of a two-frequency combination (S002 2.27)."""
    return jnp.sqrt(alpha**2 + beta**2)


def if_integers(n1, n2) -> tuple[int, int]:
    """Coprime integers (i1, i2) with f1/f2 = i1/i2, from the band multipliers (numpy, static)."""
    g = math.gcd(int(n1), int(n2))
    return int(n1) // g, int(n2) // g


def if_wavelength_m(f1_hz, f2_hz, i1, i2):
    """Ionosphere-free ambiguity wavelength lambda_IF = c / (i1 f1 - i2 f2) (S002 2.3).

    With f1 = i1 f, f2 = i2 f (i1, i2 coprime) the IF carrier ambiguity is
    alpha lambda1 N1 + beta lambda2 N2 = lambda_IF (i1 N1 - i2 N2), an integer multiple of
    lambda_IF = lambda1 lambda2 / (i1 lambda2 - i2 lambda1). GPS L1/L2 (77, 60): 6.3 mm;
    GLONASS G1/G2 (9, 7), channel 0: 5.3 cm; Galileo E1/E5a (154, 115): 2.8 mm.
    """
    return C_LIGHT / (i1 * f1_hz - i2 * f2_hz)


def if_combination(x1, x2, f1_hz, f2_hz):
    """Ionosphere-free combination alpha x1 + beta x2 of two observables in metres."""
    a, b = if_coefficients(f1_hz, f2_hz)
    return a * x1 + b * x2


def gf_combination(x1, x2):
    """Geometry-free combination x1 - x2 [m]: phase gives -I1 + I2 + ambiguities (S002 2.27)."""
    return x1 - x2


def melbourne_wubbena_m(phase1_m, phase2_m, code1_m, code2_m, f1_hz, f2_hz):
    """Melbourne-Wuebbena A_MW = Phi_WL - P_NL [m] (S002 2.29): geometry- and iono-free.

    Phi_WL = (f1 Phi1 - f2 Phi2)/(f1 - f2), P_NL = (f1 P1 + f2 P2)/(f1 + f2); A_MW / lambda_WL is
    the wide-lane ambiguity plus biases and code noise.
    """
    a_wl, b_wl = wl_coefficients(f1_hz, f2_hz)
    a_nl, b_nl = nl_coefficients(f1_hz, f2_hz)
    return a_wl * phase1_m + b_wl * phase2_m - (a_nl * code1_m + b_nl * code2_m)


class SlotTable(NamedTuple):
    """Fixed satellite slots of a scenario (all arrays [n_slots]).

    ``sat_index`` indexes the satellite list of the orbit source the table was built from
    (constellation.NominalOrbits or constellation.BroadcastEphemeris); empty slots hold 0 there
    and ``occupied = False``.
    """

    system: Int[Array, " S"]  # SYS_*
    prn: Int[Array, " S"]  # PRN / slot number (0 = empty)
    glo_channel: Int[Array, " S"]  # FDMA channel k (0 for CDMA systems and empty slots)
    occupied: Bool[Array, " S"]
    sat_index: Int[Array, " S"]  # index into the orbit source

    @property
    def n_slots(self) -> int:
        return int(self.system.shape[0])


def assign_slots(
    system: Int[ArrayLike, " n"],
    prn: Int[ArrayLike, " n"],
    glo_channel: Int[ArrayLike, " n"],
    ever_visible: Bool[ArrayLike, " n"],
    slots_per_system=DEFAULT_SLOTS_PER_SYSTEM,
) -> SlotTable:
    """Build a :class:`SlotTable`: per system, the ever-visible satellites in PRN order, padded.

    ``system``, ``prn``, ``glo_channel``, ``ever_visible`` are per-satellite arrays of the orbit
    source (host numpy; this is scenario set-up, not a hot path). Raises ValueError if a system
    has more visible satellites than slots.
    """
    system = np.asarray(system)
    prn = np.asarray(prn)
    glo_channel = np.asarray(glo_channel)
    ever_visible = np.asarray(ever_visible, dtype=bool)
    out_sys, out_prn, out_k, out_occ, out_idx = [], [], [], [], []
    for s in range(N_SYSTEMS):
        n = int(slots_per_system[s])
        idx = np.flatnonzero((system == s) & ever_visible)
        idx = idx[np.argsort(prn[idx], kind="stable")]
        if idx.size > n:
            raise ValueError(
                f"{idx.size} {SYSTEM_NAMES[s]} satellites are visible during the scenario but only "
                f"{n} slots are configured: increase slots_per_system[{s}]"
            )
        pad = n - idx.size
        out_sys.append(np.full(n, s))
        out_prn.append(np.concatenate([prn[idx], np.zeros(pad, dtype=prn.dtype)]))
        out_k.append(np.concatenate([glo_channel[idx], np.zeros(pad, dtype=glo_channel.dtype)]))
        out_occ.append(np.concatenate([np.ones(idx.size, bool), np.zeros(pad, bool)]))
        out_idx.append(np.concatenate([idx, np.zeros(pad, dtype=idx.dtype)]))
    return SlotTable(
        system=jnp.asarray(np.concatenate(out_sys), dtype=jnp.int32),
        prn=jnp.asarray(np.concatenate(out_prn), dtype=jnp.int32),
        glo_channel=jnp.asarray(np.concatenate(out_k), dtype=jnp.int32),
        occupied=jnp.asarray(np.concatenate(out_occ)),
        sat_index=jnp.asarray(np.concatenate(out_idx), dtype=jnp.int32),
    )


def slot_frequencies_hz(slots: SlotTable, bands=PPP_BANDS) -> Float[Array, "S b"]:
    """Carrier frequencies [n_slots, len(bands)] of every slot (empty slots get their system's)."""
    return jnp.stack(
        [carrier_frequency_hz(slots.system, b, slots.glo_channel) for b in bands], axis=-1
    )


def slot_if_wavelength_m(slots: SlotTable) -> Float[Array, " S"]:
    """lambda_IF [n_slots] of the PPP pair (bands 0, 1) per slot (per satellite for GLONASS)."""
    pairs = np.array([if_integers(*BAND_MULTIPLIER[s, :2]) for s in range(N_SYSTEMS)])
    i1 = jnp.asarray(pairs[:, 0], dtype=jnp.float64)[slots.system]
    i2 = jnp.asarray(pairs[:, 1], dtype=jnp.float64)[slots.system]
    f = slot_frequencies_hz(slots)
    return if_wavelength_m(f[:, 0], f[:, 1], i1, i2)


def slot_labels(slots: SlotTable) -> list[str]:
    """Human-readable satellite ids per slot ("G05", "R12", "E24"; "---" for empty slots)."""
    out = []
    for s, p, occ in zip(
        np.asarray(slots.system), np.asarray(slots.prn), np.asarray(slots.occupied), strict=True
    ):
        out.append(f"{SYSTEM_LETTERS[s]}{int(p):02d}" if occ else "---")
    return out
