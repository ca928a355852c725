"""Truth trajectories for land vehicles (and aircraft) with exact IMU increments.

Model (documented assumptions):
- The motion is described by four smooth scalar channels of time: forward speed v(t) >= 0,
  azimuth rate w_A(t) = dA/dt (clockwise from north), pitch p(t) and a bank law for roll r(t).
  Each channel is piecewise constant joined by septic smoothstep ramps
  S(x) = 35x^4 - 84x^5 + 70x^6 - 20x^7, whose first three derivatives vanish at both ends, so
  acceleration, jerk, angular rate and angular acceleration are continuous (specific force and
  angular rate are C^2). The azimuth is the closed-form integral of w_A.
- No slip: the velocity is along the body forward axis, v^l = v [sA cp, cA cp, sp], so the
  odometer speed (forward body speed) is v and the lateral/vertical body velocities are zero.
- Roll follows a bank law r = atan(k v w_A / g0) with g0 = 9.80665 m/s^2. k = 1 is a coordinated
  turn (aircraft: lateral specific force ~ 0); a car leans out of the turn with k < 0
  (default k = -0.07 rad per g of lateral acceleration, i.e. a 4 deg/g roll gradient: chosen,
  typical of passenger cars). Pitch is the road grade (or the flight-path angle: no angle of
  attack).
- Position obeys d(lat, lon, h)/dt = D^-1 v^l (S002 eq 3.4), integrated with classical RK4 on a
  grid of dt/4 (the scan carries llh - llh0 so round-off stays at the nanometre level).
  Specific force and angular rate follow from the kinematics (SEED_SPEC 1.2):
  f^l = dv^l/dt + (2 w_ie^l + w_el^l) x v^l - g^l,  f^b = C_l^b f^l,
  w_ib^b = C_l^b (w_ie^l + w_el^l) + w_lb^b, with w_lb^b from the Euler-angle rates.
- IMU increments follow the shared contract: dtheta_b[k] and dv_b[k] are the integrals of
  w_ib^b and f^b over (t_{k-1}, t_k], computed with Boole's rule on the five RK4 nodes of the
  interval (error O(dt^7)). Sample 0 covers (-dt, 0], where the motion is the steady state at
  t = 0 (the channels are constant before their first ramp), so every sample is genuine.

The segment list is plain Python/numpy (built once per trajectory); the truth computation is
JAX (a ``lax.scan`` over IMU samples).
"""

from __future__ import annotations

import enum
import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import attitude, geodesy

G0_M_S2 = 9.80665  # standard gravity, used only to scale the bank law
#: Default bank gain for cars: roll [rad] = -0.07 x lateral acceleration [g] (4 deg/g, chosen).
CAR_BANK_GAIN = -0.07
#: Coordinated turn (aircraft): roll = atan(lateral acceleration / g0).
COORDINATED_BANK_GAIN = 1.0

#: Kingston, Ontario (seed 000 / 002 ch5 / 004 test area), ellipsoidal height ~ 90 m.
KINGSTON_LLH = (math.radians(44.2312), math.radians(-76.4860), 90.0)
#: Guangzhou, China (seed 001 airborne test area), at 500 m.
GUANGZHOU_LLH = (math.radians(23.1291), math.radians(113.2644), 500.0)


# ----------------------------------------------------------------------------------------------
# Segments
# ----------------------------------------------------------------------------------------------
class Segment(NamedTuple):
    """One piece of a trajectory. Build with the helpers below rather than by hand.

    kind: 'speed' (change speed to ``value`` m/s over ``duration_s``), 'cruise', 'stop'
    (standstill; speed must already be 0), 'turn' (azimuth change ``value`` rad, positive to the
    right, at peak rate ``rate`` rad/s or, if ``radius`` > 0, at rate v / radius, with rate
    transitions of ``ramp_s``), 'pitch' (change pitch to ``value`` rad over ``duration_s``).
    """

    kind: str
    duration_s: float = 0.0
    value: float = 0.0
    rate: float = 0.0
    radius: float = 0.0
    ramp_s: float = 0.0


def speed_to(speed_mps: float, duration_s: float) -> Segment:
    """Accelerate or decelerate to ``speed_mps`` over ``duration_s`` (smoothstep profile)."""
    return Segment("speed", float(duration_s), float(speed_mps))


def speed_to_kmh(speed_kmh: float, duration_s: float) -> Segment:
    """``speed_to`` with the target in km/h."""
    return speed_to(speed_kmh / 3.6, duration_s)


def cruise(duration_s: float) -> Segment:
    """Keep speed, azimuth rate (zero) and pitch for ``duration_s``."""
    return Segment("cruise", float(duration_s))


def stop(duration_s: float) -> Segment:
    """Stand still for ``duration_s`` (the vehicle must already be at zero speed)."""
    return Segment("stop", float(duration_s))


def turn(
    angle_deg: float,
    *,
    radius_m: float | None = None,
    rate_deg_s: float | None = None,
    ramp_s: float = 2.0,
) -> Segment:
    """Turn by ``angle_deg`` (positive = right/clockwise) at a radius or an azimuth rate.

    The azimuth rate rises to its peak over ``ramp_s``, holds, and falls over ``ramp_s``; if the
    angle is too small to reach the peak, the peak is lowered so the ramps alone make the angle.
    """
    if (radius_m is None) == (rate_deg_s is None):
        raise ValueError("turn(): give exactly one of radius_m or rate_deg_s")
    if ramp_s <= 0.0:
        raise ValueError(f"turn(): ramp_s must be > 0, got {ramp_s}")
    return Segment(
        "turn",
        0.0,
        math.radians(angle_deg),
        0.0 if rate_deg_s is None else math.radians(abs(rate_deg_s)),
        0.0 if radius_m is None else float(radius_m),
        float(ramp_s),
    )


def banked_turn(angle_deg: float, bank_deg: float, speed_mps: float, ramp_s: float = 3.0):
    """Coordinated turn at bank ``bank_deg``: azimuth rate g0 tan(bank) / v."""
    rate = G0_M_S2 * math.tan(math.radians(abs(bank_deg))) / speed_mps
    return turn(angle_deg, rate_deg_s=math.degrees(rate), ramp_s=ramp_s)


def pitch_to(pitch_deg: float, duration_s: float) -> Segment:
    """Change pitch (road grade / flight-path angle) to ``pitch_deg`` over ``duration_s``."""
    return Segment("pitch", float(duration_s), math.radians(pitch_deg))


def grade_to(grade_percent: float, duration_s: float) -> Segment:
    """Change the road grade to ``grade_percent`` (rise/run x 100) over ``duration_s``."""
    return pitch_to(math.degrees(math.atan(grade_percent / 100.0)), duration_s)


# ----------------------------------------------------------------------------------------------
# Compiled profile (pytree of arrays)
# ----------------------------------------------------------------------------------------------
class Ramps(NamedTuple):
    """Non-overlapping smoothstep ramps of one channel; row 0 is a constant placeholder."""

    t0_s: jnp.ndarray  # ramp start times (sorted)
    dur_s: jnp.ndarray  # ramp durations (> 0)
    base: jnp.ndarray  # channel value before the ramp
    delta: jnp.ndarray  # change over the ramp
    integral_at_t0: jnp.ndarray  # integral of the channel from 0 to t0 (+ initial offset)


class Profile(NamedTuple):
    """A compiled trajectory: initial position and the three channel ramp tables."""

    llh0: jnp.ndarray  # (3,) lat [rad], lon [rad], h [m] at t = 0
    speed: Ramps  # forward speed [m/s]
    azimuth_rate: Ramps  # dA/dt [rad/s]; its integral (+ azimuth0) is the azimuth [rad]
    pitch: Ramps  # pitch [rad]
    bank_gain: jnp.ndarray  # k in roll = atan(k v w_A / g0)
    duration_s: float  # total length [s] of the segment list


_NEVER_S = 1e15  # start time of padding ramps (never reached)


def _ramps(events, initial: float) -> Ramps:
    """Ramp table from (t0, dur, new_value) events; ``integral_at_t0`` starts at 0."""
    t0, dur, base, delta = [-1.0], [1.0], [initial], [0.0]
    value = initial
    for start, length, new in events:
        t0.append(start)
        dur.append(length)
        base.append(value)
        delta.append(new - value)
        value = new
    t0a, dura, basea, deltaa = (np.asarray(x, dtype=np.float64) for x in (t0, dur, base, delta))
    # Integral of the channel from t = 0 to each ramp start, computed exactly as _ramp_integral
    # evaluates it, so the integral is continuous: after ramp i-1 has ended, its contribution over
    # a span s from its start is base s + delta (s - dur / 2). Row 0 (constant) counts from t = 0.
    integ = np.zeros_like(t0a)
    if len(t0a) > 1:
        integ[1] = basea[0] * t0a[1]
    for i in range(2, len(t0a)):
        span = t0a[i] - t0a[i - 1]
        integ[i] = integ[i - 1] + basea[i - 1] * span + deltaa[i - 1] * (span - 0.5 * dura[i - 1])
    # Pad to a power-of-two length (>= 16) with rows that start after any time of interest, so
    # profiles of similar size share one compiled generator (shapes are static under jit).
    n_pad = max(16, 1 << (len(t0a) - 1).bit_length()) - len(t0a)
    t0a = np.concatenate([t0a, np.full(n_pad, _NEVER_S)])
    dura = np.concatenate([dura, np.ones(n_pad)])
    basea = np.concatenate([basea, np.full(n_pad, value)])
    deltaa = np.concatenate([deltaa, np.zeros(n_pad)])
    integ = np.concatenate([integ, np.zeros(n_pad)])
    return Ramps(*(jnp.asarray(x) for x in (t0a, dura, basea, deltaa, integ)))


def compile_profile(
    segments,
    llh0=KINGSTON_LLH,
    azimuth0_deg: float = 0.0,
    speed0_mps: float = 0.0,
    pitch0_deg: float = 0.0,
    bank_gain: float = CAR_BANK_GAIN,
) -> Profile:
    """Turn a segment list into channel ramp tables (sequential segments; one channel moves at a
    time, so the ramps of each channel never overlap)."""
    t = 0.0
    v = float(speed0_mps)
    if v < 0.0:
        raise ValueError(f"speed0_mps must be >= 0, got {v}")
    speed_ev, rate_ev, pitch_ev = [], [], []
    for i, seg in enumerate(segments):
        where = f"segment {i} ({seg.kind})"
        if seg.kind == "speed":
            if seg.duration_s <= 0.0 or seg.value < 0.0:
                raise ValueError(f"{where}: need duration > 0 and speed >= 0, got {seg}")
            speed_ev.append((t, seg.duration_s, seg.value))
            v = seg.value
            t += seg.duration_s
        elif seg.kind == "cruise":
            t += seg.duration_s
        elif seg.kind == "stop":
            if v != 0.0:
                raise ValueError(f"{where}: stop needs zero speed (add speed_to(0, ...)); v = {v}")
            t += seg.duration_s
        elif seg.kind == "pitch":
            if seg.duration_s <= 0.0:
                raise ValueError(f"{where}: duration must be > 0")
            if abs(seg.value) >= math.radians(60.0):
                raise ValueError(f"{where}: |pitch| must stay below 60 deg")
            pitch_ev.append((t, seg.duration_s, seg.value))
            t += seg.duration_s
        elif seg.kind == "turn":
            if v <= 0.0:
                raise ValueError(f"{where}: cannot turn at zero speed")
            peak = v / seg.radius if seg.radius > 0.0 else seg.rate
            if not peak > 0.0 or seg.ramp_s <= 0.0:
                raise ValueError(f"{where}: need a radius or rate > 0 and ramp_s > 0, got {seg}")
            angle = abs(seg.value)
            if angle == 0.0:
                continue
            ramp = seg.ramp_s
            hold = angle / peak - ramp
            if hold < 0.0:
                peak, hold = angle / ramp, 0.0
            sign = math.copysign(1.0, seg.value)
            rate_ev.append((t, ramp, sign * peak))
            rate_ev.append((t + ramp + hold, ramp, 0.0))
            t += 2.0 * ramp + hold
        else:
            raise ValueError(f"{where}: unknown kind {seg.kind!r}")
    azimuth0 = math.radians(azimuth0_deg)
    rate = _ramps(rate_ev, 0.0)
    rate = rate._replace(integral_at_t0=rate.integral_at_t0 + azimuth0)
    return Profile(
        llh0=jnp.asarray(llh0, dtype=jnp.float64),
        speed=_ramps(speed_ev, float(speed0_mps)),
        azimuth_rate=rate,
        pitch=_ramps(pitch_ev, math.radians(pitch0_deg)),
        bank_gain=jnp.asarray(bank_gain, dtype=jnp.float64),
        duration_s=float(t),
    )


# ----------------------------------------------------------------------------------------------
# Channel evaluation (JAX)
# ----------------------------------------------------------------------------------------------
def _index(r: Ramps, t):
    return jnp.clip(jnp.searchsorted(r.t0_s, t, side="right") - 1, 0, r.t0_s.shape[0] - 1)


def _ramp_value(r: Ramps, t):
    """Channel value and its first two time derivatives at t (septic smoothstep ramps)."""
    i = _index(r, t)
    dur = r.dur_s[i]
    x = jnp.clip((t - r.t0_s[i]) / dur, 0.0, 1.0)
    x4 = x**4
    s = x4 * (35.0 + x * (-84.0 + x * (70.0 - 20.0 * x)))
    ds = 140.0 * (x * (1.0 - x)) ** 3
    dds = 420.0 * (x * (1.0 - x)) ** 2 * (1.0 - 2.0 * x)
    d = r.delta[i]
    return r.base[i] + d * s, d * ds / dur, d * dds / (dur * dur)


def _ramp_integral(r: Ramps, t):
    """Integral of the channel from 0 to t (plus the table's initial offset)."""
    i = _index(r, t)
    dur = r.dur_s[i]
    tau = (t - r.t0_s[i]) / dur
    x = jnp.clip(tau, 0.0, 1.0)
    # integral of S from 0 to x: 7 x^5 - 14 x^6 + 10 x^7 - 2.5 x^8; after the ramp S = 1.
    int_s = x**5 * (7.0 + x * (-14.0 + x * (10.0 - 2.5 * x))) + jnp.maximum(tau - 1.0, 0.0)
    t0 = jnp.where(i == 0, 0.0, r.t0_s[i])
    return r.integral_at_t0[i] + r.base[i] * (t - t0) + r.delta[i] * dur * int_s


class Kinematics(NamedTuple):
    """Closed-form motion at one time: speed, its rate, Euler angles and their rates."""

    speed: jnp.ndarray
    accel: jnp.ndarray  # dv/dt
    euler: jnp.ndarray  # (roll, pitch, azimuth unwrapped)
    euler_rate: jnp.ndarray  # d/dt of euler


def kinematics(profile: Profile, t) -> Kinematics:
    """Speed, Euler angles and their rates at time t (closed form, no position needed)."""
    v, dv, _ = _ramp_value(profile.speed, t)
    w, dw, _ = _ramp_value(profile.azimuth_rate, t)
    az = _ramp_integral(profile.azimuth_rate, t)
    p, dp, _ = _ramp_value(profile.pitch, t)
    k = profile.bank_gain / G0_M_S2
    lat_acc = v * w
    dlat_acc = dv * w + v * dw
    roll = jnp.arctan(k * lat_acc)
    droll = k * dlat_acc / (1.0 + (k * lat_acc) ** 2)
    return Kinematics(v, dv, jnp.stack([roll, p, az]), jnp.stack([droll, dp, w]))


def _forward_axis(pitch, azimuth):
    # Body forward axis in ENU (second column of C_b_l) and its partials.
    sp, cp = jnp.sin(pitch), jnp.cos(pitch)
    sa, ca = jnp.sin(azimuth), jnp.cos(azimuth)
    u = jnp.stack([sa * cp, ca * cp, sp])
    du_da = jnp.stack([ca * cp, -sa * cp, jnp.zeros_like(sp)])
    du_dp = jnp.stack([-sa * sp, -ca * sp, cp])
    return u, du_da, du_dp


def velocity_enu(profile: Profile, t):
    """No-slip ENU velocity v [sA cp, cA cp, sp] at time t."""
    kin = kinematics(profile, t)
    u, _, _ = _forward_axis(kin.euler[1], kin.euler[2])
    return kin.speed * u


def body_rate_from_euler_rates(euler, euler_rate):
    """w_lb^b for C_b_l = R3(-A) R1(p) R2(r) (attitude.py convention).

    w_lb^b = [cr dp + sr cp dA, dr - sp dA, sr dp - cr cp dA] (from C^T dC/dt = [w x]).
    """
    r, p = euler[0], euler[1]
    dr, dp, da = euler_rate[0], euler_rate[1], euler_rate[2]
    sr, cr, sp, cp = jnp.sin(r), jnp.cos(r), jnp.sin(p), jnp.cos(p)
    return jnp.stack([cr * dp + sr * cp * da, dr - sp * da, sr * dp - cr * cp * da])


def _sensor_truth(kin: Kinematics, llh):
    """Specific force f^b [m/s^2] and angular rate w_ib^b [rad/s] from kinematics and position."""
    roll, pitch, az = kin.euler[0], kin.euler[1], kin.euler[2]
    u, du_da, du_dp = _forward_axis(pitch, az)
    vel = kin.speed * u
    acc = kin.accel * u + kin.speed * (du_da * kin.euler_rate[2] + du_dp * kin.euler_rate[1])
    w_ie = geodesy.earth_rate_enu(llh[0])
    w_el = geodesy.transport_rate_enu(llh, vel)
    f_l = acc + jnp.cross(2.0 * w_ie + w_el, vel) - geodesy.gravity_enu(llh)
    C_l_b = attitude.dcm_from_euler(jnp.stack([roll, pitch, az])).T
    w_ib_b = C_l_b @ (w_ie + w_el) + body_rate_from_euler_rates(kin.euler, kin.euler_rate)
    return C_l_b @ f_l, w_ib_b


# ----------------------------------------------------------------------------------------------
# Event labels
# ----------------------------------------------------------------------------------------------
class Event(enum.IntEnum):
    """Per-sample motion label (priority STOP > TURN > SLOPE > SPEED_CHANGE > STRAIGHT)."""

    STRAIGHT = 0  # cruising on a level straight road
    TURN = 1  # |dA/dt| above the turn threshold
    STOP = 2  # speed below the stop threshold
    SLOPE = 3  # |pitch| above the slope threshold
    SPEED_CHANGE = 4  # |dv/dt| above the acceleration threshold


class LabelThresholds(NamedTuple):
    """Thresholds of the event labels (chosen: they separate the generators' manoeuvres)."""

    stop_speed_mps: float = 0.05
    turn_rate_rad_s: float = math.radians(0.5)  # a 2 km-radius curve at 100 km/h is 0.8 deg/s
    slope_pitch_rad: float = math.radians(1.0)  # 1.7 % grade
    accel_mps2: float = 0.2


DEFAULT_THRESHOLDS = LabelThresholds()


def label_events(speed, azimuth_rate, pitch, accel, th: LabelThresholds = DEFAULT_THRESHOLDS):
    """int8 Event code per sample from the kinematics (see ``Event`` for the priority)."""
    code = jnp.full(jnp.shape(speed), Event.STRAIGHT, dtype=jnp.int8)
    code = jnp.where(jnp.abs(accel) > th.accel_mps2, jnp.int8(Event.SPEED_CHANGE), code)
    code = jnp.where(jnp.abs(pitch) > th.slope_pitch_rad, jnp.int8(Event.SLOPE), code)
    code = jnp.where(jnp.abs(azimuth_rate) > th.turn_rate_rad_s, jnp.int8(Event.TURN), code)
    code = jnp.where(speed < th.stop_speed_mps, jnp.int8(Event.STOP), code)
    return code


# ----------------------------------------------------------------------------------------------
# Truth generation
# ----------------------------------------------------------------------------------------------
class Truth(NamedTuple):
    """Truth at the IMU rate; index k is the state at t_k = k dt, after IMU sample k.

    ``dtheta_b[k]`` / ``dv_b[k]`` integrate w_ib^b / f^b over (t_{k-1}, t_k] (shared contract);
    ``f_b`` / ``w_ib_b`` are the instantaneous values at t_k.
    """

    time_s: jnp.ndarray  # (N+1,)
    llh: jnp.ndarray  # (N+1, 3) lat [rad], lon [rad], h [m]
    vel_enu: jnp.ndarray  # (N+1, 3) [m/s]
    euler: jnp.ndarray  # (N+1, 3) roll, pitch, azimuth [rad]; azimuth in (-pi, pi]
    q_b_l: jnp.ndarray  # (N+1, 4) Hamilton scalar-first, body -> ENU
    f_b: jnp.ndarray  # (N+1, 3) specific force [m/s^2]
    w_ib_b: jnp.ndarray  # (N+1, 3) angular rate [rad/s]
    dtheta_b: jnp.ndarray  # (N+1, 3) [rad]
    dv_b: jnp.ndarray  # (N+1, 3) [m/s]
    odo_speed_mps: jnp.ndarray  # (N+1,) forward body speed (>= 0)
    odo_accel_mps2: jnp.ndarray  # (N+1,) its time derivative (RISS a_od)
    event: jnp.ndarray  # (N+1,) int8 Event code

    @property
    def dt(self) -> float:
        return float(self.time_s[1] - self.time_s[0])


# Boole's rule on 5 equally spaced nodes: integral = (dt / 90) (7, 32, 12, 32, 7) . f
_BOOLE = np.array([7.0, 32.0, 12.0, 32.0, 7.0]) / 90.0


def _llh_rate(llh, vel):
    return geodesy.llh_rate_matrix(llh) @ vel


def _rk4_interval(profile: Profile, dllh_start, t_start, h):
    """Four classical RK4 steps of d(llh)/dt = D^-1(llh) v(t) from t_start with step h.

    The state is the offset dllh = llh - llh0: small numbers keep the round-off of ~1e5 steps
    per drive far below a micrometre (adding 1e-9 rad steps to lon ~ 1 rad would not).
    Returns the five offsets at t_start + j h, j = 0..4, and the kinematics at the nine
    half-step times t_start + m h / 2 (the even ones are the nodes).
    """
    times = t_start + 0.5 * h * jnp.arange(9.0)
    kin = jax.vmap(partial(kinematics, profile))(times)
    u, _, _ = jax.vmap(_forward_axis)(kin.euler[:, 1], kin.euler[:, 2])
    vel = kin.speed[:, None] * u
    llh0 = profile.llh0
    nodes = [dllh_start]
    d = dllh_start
    for j in range(4):
        v0, vm, v1 = vel[2 * j], vel[2 * j + 1], vel[2 * j + 2]
        k1 = _llh_rate(llh0 + d, v0)
        k2 = _llh_rate(llh0 + (d + 0.5 * h * k1), vm)
        k3 = _llh_rate(llh0 + (d + 0.5 * h * k2), vm)
        k4 = _llh_rate(llh0 + (d + h * k3), v1)
        d = d + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        nodes.append(d)
    return jnp.stack(nodes), kin


@partial(jax.jit, static_argnames=("n_samples",))
def _generate(profile: Profile, dt, n_samples: int, thresholds: LabelThresholds):
    h = dt / 4.0
    # Position at t = -dt: integrate back from llh0 (sample 0 covers (-dt, 0]).
    d_m1 = _rk4_interval(profile, jnp.zeros(3), 0.0, -h)[0][-1]

    def step(d_prev, k):
        d_nodes, kin = _rk4_interval(profile, d_prev, (k - 1.0) * dt, h)
        kin_nodes = jax.tree_util.tree_map(lambda a: a[::2], kin)
        f_n, w_n = jax.vmap(_sensor_truth)(kin_nodes, profile.llh0 + d_nodes)
        dv = dt * (_BOOLE @ f_n)
        dth = dt * (_BOOLE @ w_n)
        return d_nodes[-1], (d_nodes[-1], f_n[-1], w_n[-1], dth, dv)

    ks = jnp.arange(n_samples + 1, dtype=jnp.float64)
    _, (dllh, f_b, w_b, dth, dv) = jax.lax.scan(step, d_m1, ks)
    # Exactly llh0 at t = 0 (the back-and-forth RK4 differs from it by round-off only).
    llh = profile.llh0 + dllh.at[0].set(0.0)
    time = ks * dt
    kin = jax.vmap(partial(kinematics, profile))(time)
    u, _, _ = jax.vmap(_forward_axis)(kin.euler[:, 1], kin.euler[:, 2])
    vel = kin.speed[:, None] * u
    euler = kin.euler.at[:, 2].set(attitude.wrap_angle(kin.euler[:, 2]))
    q = jax.vmap(attitude.quat_from_euler)(kin.euler)
    event = label_events(kin.speed, kin.euler_rate[:, 2], kin.euler[:, 1], kin.accel, thresholds)
    return Truth(time, llh, vel, euler, q, f_b, w_b, dth, dv, kin.speed, kin.accel, event)


def generate_truth(
    profile: Profile,
    rate_hz: float = 200.0,
    duration_s: float | None = None,
    thresholds: LabelThresholds = DEFAULT_THRESHOLDS,
) -> Truth:
    """Truth at ``rate_hz`` over [0, duration] (default: the profile's length).

    Position: RK4 on d(llh)/dt = D^-1 v (S002 eq 3.4) with step dt/4; increments: Boole's rule
    of f^b = C_l^b (dv^l/dt + (2 w_ie + w_el) x v - g^l) and w_ib^b = C_l^b w_il^l + w_lb^b.
    """
    if not 1.0 <= rate_hz <= 2000.0:
        raise ValueError(f"rate_hz must be in [1, 2000], got {rate_hz}")
    dur = profile.duration_s if duration_s is None else float(duration_s)
    n = int(round(dur * rate_hz))
    if n < 1:
        raise ValueError(f"trajectory too short: {dur} s at {rate_hz} Hz")
    return _generate(profile, 1.0 / rate_hz, n, LabelThresholds(*map(float, thresholds)))


# ----------------------------------------------------------------------------------------------
# Helpers: GNSS-epoch subsampling and event intervals
# ----------------------------------------------------------------------------------------------
def truth_at_epochs(truth: Truth, interval_s: float = 1.0) -> Truth:
    """Truth at the GNSS epochs (every ``interval_s``, default 1 Hz).

    States are subsampled; increments are summed over the samples of (t_{j-1}, t_j] (exact,
    since the increments are integrals). Epoch 0 has no preceding interval: its increments are 0.
    """
    step = int(round(interval_s / truth.dt))
    if step < 1 or abs(step * truth.dt - interval_s) > 1e-9 * interval_s:
        raise ValueError(f"interval {interval_s} s is not a multiple of dt = {truth.dt} s")
    n_ep = (truth.time_s.shape[0] - 1) // step
    idx = np.arange(n_ep + 1) * step
    sub = jax.tree_util.tree_map(lambda a: a[idx], truth)

    def summed(a):
        blocks = a[1 : n_ep * step + 1].reshape(n_ep, step, *a.shape[1:]).sum(axis=1)
        return jnp.concatenate([jnp.zeros_like(a[:1]), blocks])

    return sub._replace(dtheta_b=summed(truth.dtheta_b), dv_b=summed(truth.dv_b))


class EventInterval(NamedTuple):
    event: Event
    start_s: float
    end_s: float


def event_intervals(truth: Truth, min_duration_s: float = 0.0) -> list[EventInterval]:
    """Maximal runs of equal event label, as (event, start, end) with end - start >= minimum."""
    code = np.asarray(truth.event)
    t = np.asarray(truth.time_s)
    change = np.flatnonzero(np.diff(code)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [code.size]]) - 1
    out = []
    for s, e in zip(starts, ends, strict=True):
        if t[e] - t[s] >= min_duration_s:
            out.append(EventInterval(Event(int(code[s])), float(t[s]), float(t[e])))
    return out
