"""Random drives and flights (numpy, seeded): segment lists for ``sim/trajectory.py``.

A drive style (urban, suburban, highway, or "mixed", which changes style along the way) draws
cruise speeds, cruise times and the next manoeuvre (stop at a light, sharp intersection turn,
gentle curve, hill, speed change) from its ranges; a flight draws climbs, banked turns and
cruises. The same seed gives the same segments; ``trajectory.compile_profile`` turns them into
the smooth profile the truth is computed from.
"""

from __future__ import annotations

import math

import numpy as np

from jaxnav.sim.trajectory import (
    COORDINATED_BANK_GAIN,
    G0_M_S2,
    GUANGZHOU_LLH,
    KINGSTON_LLH,
    Profile,
    Segment,
    banked_turn,
    compile_profile,
    cruise,
    grade_to,
    pitch_to,
    speed_to,
    stop,
    turn,
)

_DRIVE_STYLES = {
    # cruise speed range [km/h], cruise time range [s], probabilities of the next manoeuvre
    # (stop at a light, sharp intersection turn, gentle curve, hill, speed change), max grade [%]
    "urban": dict(kmh=(30.0, 60.0), cruise=(5.0, 30.0), p=(0.3, 0.3, 0.1, 0.1, 0.2), grade=4.0),
    "suburban": dict(
        kmh=(50.0, 80.0), cruise=(10.0, 45.0), p=(0.12, 0.2, 0.3, 0.18, 0.2), grade=5.0
    ),
    "highway": dict(
        kmh=(80.0, 100.0), cruise=(20.0, 90.0), p=(0.0, 0.0, 0.5, 0.25, 0.25), grade=3.0
    ),
}


def _accel_time(v_from, v_to, accel_mps2):
    # The septic smoothstep peaks at 2.1875 x its mean rate: size the duration on the peak.
    return max(1.0, 2.1875 * abs(v_to - v_from) / accel_mps2)


def random_drive_segments(
    rng: np.random.Generator, style: str, duration_s: float, static_start_s: float = 60.0
) -> list[Segment]:
    """Seeded random land drive (segments) of roughly ``duration_s`` in one style or 'mixed'.

    Urban: 30-60 km/h, stop-and-go (traffic lights 10-45 s), sharp ~90 deg turns at 15-25 km/h
    (radius 10-25 m); suburban: 50-80 km/h; highway: 80-100 km/h, gentle curves (radius
    0.5-2 km). Hills: grade up to 3-5 % over 100-500 m, then level again, the sign chosen to
    steer back to the start height. 'mixed' goes urban -> suburban -> highway -> suburban ->
    urban (the seeds' Kingston drives: seed 000 trajectories 1-2, 30-55 min, 60-100 km/h). The
    drive starts and ends at standstill. The length is met to within one manoeuvre (~1 min).
    """
    if style == "mixed":
        shares = [
            ("urban", 0.2),
            ("suburban", 0.2),
            ("highway", 0.3),
            ("suburban", 0.15),
            ("urban", 0.15),
        ]
    elif style in _DRIVE_STYLES:
        shares = [(style, 1.0)]
    else:
        raise ValueError(f"unknown drive style {style!r}; use urban, suburban, highway or mixed")
    segs: list[Segment] = [stop(static_start_s)]
    v, height, t = 0.0, 0.0, static_start_s
    phase_end = static_start_s
    for name, share in shares:
        st = _DRIVE_STYLES[name]
        probs = np.asarray(st["p"]) / np.sum(st["p"])
        phase_end += share * (duration_s - static_start_s)
        while t < phase_end - 20.0:
            if v == 0.0 or rng.random() < probs[4]:
                target = rng.uniform(*st["kmh"]) / 3.6
                d = _accel_time(v, target, rng.uniform(0.8, 2.0))
                segs.append(speed_to(target, d))
                t += d
                v = target
            c = rng.uniform(*st["cruise"])
            segs.append(cruise(c))
            t += c
            kind = rng.choice(5, p=probs)
            if kind == 0:  # stop at a light
                d = _accel_time(v, 0.0, rng.uniform(1.5, 3.0))
                w = rng.uniform(10.0, 45.0)
                segs += [speed_to(0.0, d), stop(w)]
                t += d + w
                v = 0.0
            elif kind == 1:  # sharp turn at an intersection
                slow = rng.uniform(15.0, 25.0) / 3.6
                if slow < v:
                    d = _accel_time(v, slow, rng.uniform(1.5, 3.0))
                    segs.append(speed_to(slow, d))
                    t += d
                    v = slow
                ang = rng.choice([-90.0, 90.0]) * rng.uniform(0.8, 1.1)
                radius = rng.uniform(10.0, 25.0)
                segs.append(turn(ang, radius_m=radius, ramp_s=1.5))
                t += abs(math.radians(ang)) * radius / v + 1.5
            elif kind == 2:  # gentle curve at speed
                if name == "highway":
                    radius = rng.uniform(500.0, 2000.0)
                else:
                    radius = rng.uniform(150.0, 400.0)
                ang = rng.uniform(10.0, 45.0) * rng.choice([-1.0, 1.0])
                segs.append(turn(ang, radius_m=radius, ramp_s=3.0))
                t += abs(math.radians(ang)) * radius / v + 3.0
            elif kind == 3:  # hill: grade in, hold over 100-500 m, level out
                g = rng.uniform(1.0, st["grade"])
                g = -math.copysign(g, height) if abs(height) > 5.0 else g * rng.choice([-1, 1])
                ramp = rng.uniform(4.0, 8.0)
                hold = rng.uniform(100.0, 500.0) / v
                segs += [grade_to(g, ramp), cruise(hold), grade_to(0.0, ramp)]
                height += v * (hold + ramp) * g / 100.0
                t += hold + 2.0 * ramp
    if v > 0.0:
        segs.append(speed_to(0.0, _accel_time(v, 0.0, 2.0)))
    segs.append(stop(30.0))
    return segs


def random_drive(
    seed: int,
    style: str = "mixed",
    duration_s: float = 1800.0,
    llh0=KINGSTON_LLH,
    static_start_s: float = 60.0,
) -> Profile:
    """Compiled random land drive from an integer seed (see ``random_drive_segments``)."""
    rng = np.random.default_rng(seed)
    segs = random_drive_segments(rng, style, duration_s, static_start_s)
    return compile_profile(segs, llh0=llh0, azimuth0_deg=float(rng.uniform(0.0, 360.0)))


def random_airborne_segments(rng: np.random.Generator, duration_s: float, speed0_mps: float):
    """Seeded random flight (seed 001): 45-50 m/s, coordinated turns banked 10-20 deg, climbs
    and descents (flight-path angle 1.5-3.5 deg, ~ +-3 m/s vertical)."""
    v = speed0_mps
    segs: list[Segment] = [cruise(30.0)]
    t = 30.0
    alt = 0.0
    while t < duration_s - 60.0:
        c = rng.uniform(20.0, 120.0)
        segs.append(cruise(c))
        t += c
        kind = rng.choice(3, p=[0.5, 0.3, 0.2])
        if kind == 0:
            bank = rng.uniform(10.0, 20.0)
            ang = rng.uniform(45.0, 180.0) * rng.choice([-1.0, 1.0])
            rate = G0_M_S2 * math.tan(math.radians(bank)) / v
            segs.append(banked_turn(ang, bank, v, ramp_s=3.0))
            t += abs(math.radians(ang)) / rate + 3.0
        elif kind == 1:
            sign = -1.0 if alt > 100.0 else (1.0 if alt < -100.0 else rng.choice([-1.0, 1.0]))
            fpa = rng.uniform(1.5, 3.5) * sign
            dur = rng.uniform(20.0, 60.0)
            segs += [pitch_to(fpa, 4.0), cruise(dur), pitch_to(0.0, 4.0)]
            alt += v * math.sin(math.radians(fpa)) * (dur + 4.0)
            t += dur + 8.0
        else:
            new = rng.uniform(45.0, 50.0)
            d = _accel_time(v, new, 0.5)
            segs.append(speed_to(new, d))
            v = new
            t += d
    return segs


def random_airborne(seed: int, duration_s: float = 1800.0, llh0=GUANGZHOU_LLH) -> Profile:
    """Compiled random flight from an integer seed (coordinated bank law, k = 1)."""
    rng = np.random.default_rng(seed)
    speed0 = float(rng.uniform(45.0, 50.0))
    segs = random_airborne_segments(rng, duration_s, speed0)
    return compile_profile(
        segs,
        llh0=llh0,
        azimuth0_deg=float(rng.uniform(0.0, 360.0)),
        speed0_mps=speed0,
        bank_gain=COORDINATED_BANK_GAIN,
    )



def _straight(rng: np.random.Generator, length_m: float, v_in: float, v_out: float):
    """Segments of one circuit side: from ``v_in`` up to a cruise speed, optionally a stop in
    the middle, down to ``v_out``; the side covers exactly ``length_m``.

    A smoothstep speed ramp is point-symmetric about its middle, so it covers its mean speed
    times its duration; the cruise at speed v_c fills the rest of the side. Where the ramps
    alone would overshoot the side, the cruise speed is lowered until they fit.
    """
    v_c = rng.uniform(30.0, 50.0) / 3.6
    rates = rng.uniform(0.8, 2.0), rng.uniform(1.5, 3.0), rng.uniform(1.5, 3.0)
    stop_s = rng.uniform(10.0, 40.0) if rng.random() < 0.3 else 0.0
    while True:
        legs = [(v_in, v_c, rates[0])]
        if stop_s:
            legs += [(v_c, 0.0, rates[1]), (0.0, v_c, rates[0])]
        legs.append((v_c, v_out, rates[2]))
        ramps = [(b, _accel_time(a, b, r), 0.5 * (a + b)) for a, b, r in legs]
        ramp_m = sum(d * v for _, d, v in ramps)
        if ramp_m <= 0.9 * length_m:
            break
        v_c *= 0.9
    hold_s = (length_m - ramp_m) / v_c / (2 if stop_s else 1)
    segs = [speed_to(ramps[0][0], ramps[0][1]), cruise(hold_s)]
    if stop_s:
        segs += [speed_to(0.0, ramps[1][1]), stop(stop_s), speed_to(v_c, ramps[2][1]),
                 cruise(hold_s)]
    segs.append(speed_to(v_out, ramps[-1][1]))
    return segs, sum(d for _, d, _ in ramps) + hold_s * (2 if stop_s else 1) + stop_s


def circuit_drive_segments(
    rng: np.random.Generator,
    duration_s: float,
    side_m: tuple[float, float] = (400.0, 200.0),
    static_start_s: float = 60.0,
) -> list[Segment]:
    """Laps of a closed rectangular circuit (sides ``side_m``, left 90 deg corners).

    Each side accelerates to a cruise speed drawn from 30-50 km/h, holds it and slows to the
    corner speed (20 km/h, radius 15 m); with probability 0.3 it stops for 10-40 s in the
    middle. Every side covers exactly its length and every corner is the same manoeuvre at the
    same speed, so the track closes lap after lap: the replay source (``study/replay.py``)
    keeps the vehicle within a few hundred metres of the station whose observations it moves.
    """
    v_turn, radius, ramp_s = 20.0 / 3.6, 15.0, 1.5
    segs: list[Segment] = [stop(static_start_s)]
    t, v, side = static_start_s, 0.0, 0
    while t < duration_s - 60.0:
        straight, dt = _straight(rng, side_m[side % 2], v, v_turn)
        segs += straight
        segs.append(turn(-90.0, radius_m=radius, ramp_s=ramp_s))
        t += dt + math.radians(90.0) * radius / v_turn + ramp_s
        v, side = v_turn, side + 1
    segs += [speed_to(0.0, _accel_time(v, 0.0, 2.0)), stop(30.0)]
    return segs


def circuit_drive(seed: int, duration_s: float = 1800.0, llh0=KINGSTON_LLH) -> Profile:
    """Compiled circuit drive from an integer seed (see ``circuit_drive_segments``)."""
    rng = np.random.default_rng(seed)
    segs = circuit_drive_segments(rng, duration_s)
    return compile_profile(segs, llh0=llh0, azimuth0_deg=float(rng.uniform(0.0, 360.0)))
