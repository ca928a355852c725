"""IMU and odometer error models with grade presets (full IMU; the RISS uses a subset).

IMU measurement model per sample k (S001 eq 12, applied to the increments of the shared data
contract, each axis independently):

    dtheta_meas_k = (1 + s_g,k) dtheta_k + b_g,k dt + n_g,k      (then optional quantisation)
    dv_meas_k     = (1 + s_a,k) dv_k     + b_a,k dt + n_a,k

- Bias b = turn-on bias (random constant per run, N(0, sigma_to^2)) + in-run first-order
  Gauss-Markov bias in the exact discrete form x_k = x_{k-1} e^{-dt/tau} + w_k,
  Var(w_k) = sigma^2 (1 - e^{-2 dt/tau}) (S001 eq 13, SEED_SPEC 1.6), started from its
  stationary distribution so its standard deviation is sigma at every sample.
- Scale factor s = random constant per run + optional Gauss-Markov part (same form).
- White noise: angle random walk on dtheta (std ARW sqrt(dt)), velocity random walk on dv
  (std VRW sqrt(dt)).
- Quantisation (optional, quantum q > 0): an integrating IMU outputs whole quanta and carries
  the remainder, y_k = q round((x_k + r_{k-1}) / q), r_k = x_k + r_{k-1} - y_k, so the sum of
  outputs differs from the sum of inputs by the final residual only (|r| <= q / 2).
The RISS (one vertical gyro, two horizontal accelerometers) uses the z gyro and x/y
accelerometer channels of the same model (``riss_subset``).

Odometer: speed_meas = (1 + s_od) v + n with a constant (+ optional GM) scale factor and white
noise, optionally rounded to a quantum (OBD-II reports integer km/h: SAE J1979 PID 0x0D). A
wheel at rest gives no pulses, so a zero true speed reads exactly zero; readings are >= 0.

Units inside are SI (rad, m, s); datasheet units are converted at construction
(``ImuGrade.from_datasheet`` and the ``*_to_*`` helpers).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

# ---- unit conversions -------------------------------------------------------------------------
G_STD = 9.80665  # standard gravity [m/s^2], the "g" of mg and ug datasheet units
DEG = math.pi / 180.0


def deg_h_to_rad_s(x):
    """deg/h -> rad/s."""
    return x * DEG / 3600.0


def deg_s_to_rad_s(x):
    """deg/s -> rad/s."""
    return x * DEG


def deg_sqrt_h_to_rad_sqrt_s(x):
    """Angle random walk deg/sqrt(h) -> rad/sqrt(s) (divide by sqrt(3600) = 60)."""
    return x * DEG / 60.0


def deg_s_sqrt_hz_to_rad_sqrt_s(x):
    """Rate noise density deg/s/sqrt(Hz) -> rad/sqrt(s) (same quantity as ARW)."""
    return x * DEG


def mg_to_m_s2(x):
    """milli-g -> m/s^2."""
    return x * 1e-3 * G_STD


def mgal_to_m_s2(x):
    """milligal -> m/s^2 (1 Gal = 1 cm/s^2)."""
    return x * 1e-5


def m_s_sqrt_h_to_m_s_sqrt_s(x):
    """Velocity random walk m/s/sqrt(h) -> m/s/sqrt(s)."""
    return x / 60.0


def ug_sqrt_hz_to_m_s_sqrt_s(x):
    """Acceleration noise density ug/sqrt(Hz) -> m/s/sqrt(s) (same quantity as VRW)."""
    return x * 1e-6 * G_STD


def ppm_to_unitless(x):
    """parts per million -> dimensionless."""
    return x * 1e-6


# ---- parameter objects ------------------------------------------------------------------------
class ImuGrade(eqx.Module):
    """Error parameters of one IMU grade (SI units; 1-sigma values; every axis the same).

    A GM correlation time of ``inf`` makes that GM part a random constant; a sigma of 0 turns
    it off; a quantum of 0 turns quantisation off.
    """

    name: str = eqx.field(static=True)
    source: str = eqx.field(static=True)
    rate_hz: float = eqx.field(static=True)  # nominal output rate (informational)
    gyro_bias_turn_on_rad_s: float
    gyro_bias_gm_sigma_rad_s: float
    gyro_bias_gm_tau_s: float
    gyro_arw_rad_sqrt_s: float
    gyro_scale_turn_on: float
    gyro_scale_gm_sigma: float
    gyro_scale_gm_tau_s: float
    gyro_quantum_rad: float
    accel_bias_turn_on_m_s2: float
    accel_bias_gm_sigma_m_s2: float
    accel_bias_gm_tau_s: float
    accel_vrw_m_s_sqrt_s: float
    accel_scale_turn_on: float
    accel_scale_gm_sigma: float
    accel_scale_gm_tau_s: float
    accel_quantum_m_s: float

    @classmethod
    def from_datasheet(
        cls,
        name: str,
        source: str,
        rate_hz: float,
        *,
        gyro_bias_turn_on_deg_h: float = 0.0,
        gyro_bias_instability_deg_h: float = 0.0,
        gyro_bias_tau_s: float = math.inf,
        gyro_arw_deg_sqrt_h: float = 0.0,
        gyro_scale_ppm: float = 0.0,
        gyro_scale_instability_ppm: float = 0.0,
        gyro_scale_tau_s: float = math.inf,
        gyro_quantum_rad: float = 0.0,
        accel_bias_turn_on_mg: float = 0.0,
        accel_bias_instability_mg: float = 0.0,
        accel_bias_tau_s: float = math.inf,
        accel_vrw_m_s_sqrt_h: float = 0.0,
        accel_scale_ppm: float = 0.0,
        accel_scale_instability_ppm: float = 0.0,
        accel_scale_tau_s: float = math.inf,
        accel_quantum_m_s: float = 0.0,
    ) -> ImuGrade:
        """Build from datasheet units (deg/h, deg/sqrt(h), mg, m/s/sqrt(h), ppm).

        The datasheet in-run bias (in)stability is used as the GM steady-state sigma, as S001
        eq 13 does ("sigma^2 set from the sensor bias/SF instability").
        """
        return cls(
            name=name,
            source=source,
            rate_hz=float(rate_hz),
            gyro_bias_turn_on_rad_s=deg_h_to_rad_s(gyro_bias_turn_on_deg_h),
            gyro_bias_gm_sigma_rad_s=deg_h_to_rad_s(gyro_bias_instability_deg_h),
            gyro_bias_gm_tau_s=float(gyro_bias_tau_s),
            gyro_arw_rad_sqrt_s=deg_sqrt_h_to_rad_sqrt_s(gyro_arw_deg_sqrt_h),
            gyro_scale_turn_on=ppm_to_unitless(gyro_scale_ppm),
            gyro_scale_gm_sigma=ppm_to_unitless(gyro_scale_instability_ppm),
            gyro_scale_gm_tau_s=float(gyro_scale_tau_s),
            gyro_quantum_rad=float(gyro_quantum_rad),
            accel_bias_turn_on_m_s2=mg_to_m_s2(accel_bias_turn_on_mg),
            accel_bias_gm_sigma_m_s2=mg_to_m_s2(accel_bias_instability_mg),
            accel_bias_gm_tau_s=float(accel_bias_tau_s),
            accel_vrw_m_s_sqrt_s=m_s_sqrt_h_to_m_s_sqrt_s(accel_vrw_m_s_sqrt_h),
            accel_scale_turn_on=ppm_to_unitless(accel_scale_ppm),
            accel_scale_gm_sigma=ppm_to_unitless(accel_scale_instability_ppm),
            accel_scale_gm_tau_s=float(accel_scale_tau_s),
            accel_quantum_m_s=float(accel_quantum_m_s),
        )


# Correlation times: no seed reports any (SEED_SPEC 1.6). Chosen: 300 s for MEMS in-run biases
# (minutes-scale thermal drift; matches the 250-400 s bias convergence of S000 ch5) and 3600 s
# for tactical FOG/RLG units (bias stability quoted over hours).
_TAU_MEMS_S = 300.0
_TAU_TACTICAL_S = 3600.0


def crossbow_imu300cc() -> ImuGrade:
    """Crossbow IMU300CC (MEMS; seed 000's RISS sensor), 200 Hz.

    S000 Tab B.1: gyro bias 2 deg/s (the table's "20 deg/s" is a typo: S000 text, SEED_SPEC 4
    S000 item 18), ARW 2.25 deg/sqrt(h), gyro SF 1 %; accel bias 30 mg, VRW 0.15 m/s/sqrt(h),
    accel SF 1 %. The table's bounds are used as 1-sigma (conservative). In-run GM sigmas
    (gyro 0.05 deg/s = 180 deg/h, accel 1 mg) and tau 300 s: chosen (not in the seeds; a few
    percent of the turn-on values, the order of in-run drift of that MEMS generation, cf. the
    Crista's > 1000 deg/h in S003).
    """
    return ImuGrade.from_datasheet(
        "Crossbow IMU300CC",
        "S000 Tab B.1 (+ chosen GM)",
        200.0,
        gyro_bias_turn_on_deg_h=2.0 * 3600.0,
        gyro_bias_instability_deg_h=180.0,
        gyro_bias_tau_s=_TAU_MEMS_S,
        gyro_arw_deg_sqrt_h=2.25,
        gyro_scale_ppm=1e4,
        accel_bias_turn_on_mg=30.0,
        accel_bias_instability_mg=1.0,
        accel_bias_tau_s=_TAU_MEMS_S,
        accel_vrw_m_s_sqrt_h=0.15,
        accel_scale_ppm=1e4,
    )


def lsm6dsl() -> ImuGrade:
    """Consumer MEMS IMU of the ST LSM6DSL class (seed 002 ch. 4), 100 Hz (chosen).

    Datasheet (ST DS11889, typical values): zero-rate level 2 deg/s, rate noise density
    4 mdps/sqrt(Hz) (= 0.24 deg/sqrt(h)), zero-g level 40 mg, acceleration noise density
    80 ug/sqrt(Hz). Chosen (not in the seeds or the datasheet): in-run GM gyro 36 deg/h and accel
    0.5 mg with tau 300 s (thermal drift of consumer parts), scale factors 1 %.
    """
    return ImuGrade.from_datasheet(
        "LSM6DSL-class consumer MEMS",
        "ST DS11889 typ. (+ chosen GM, SF)",
        100.0,
        gyro_bias_turn_on_deg_h=2.0 * 3600.0,
        gyro_bias_instability_deg_h=36.0,
        gyro_bias_tau_s=_TAU_MEMS_S,
        gyro_arw_deg_sqrt_h=4e-3 * 60.0,
        gyro_scale_ppm=1e4,
        accel_bias_turn_on_mg=40.0,
        accel_bias_instability_mg=0.5,
        accel_bias_tau_s=_TAU_MEMS_S,
        accel_vrw_m_s_sqrt_h=80e-6 * G_STD * 60.0,
        accel_scale_ppm=1e4,
    )


def crista() -> ImuGrade:
    """Cloud Cap Crista (MEMS; seed 003), 100 Hz (S003).

    S003: gyro turn-on bias about 5400 deg/h, in-run bias drift > 1000 deg/h (used as the GM
    sigma). Chosen (S003 gives nothing else): tau 300 s, and the IMU300CC figures of S000 Tab B.1
    (same MEMS generation) for ARW 2.25 deg/sqrt(h), accel turn-on 30 mg, VRW 0.15 m/s/sqrt(h),
    SF 1 %; accel in-run 1 mg.
    """
    return ImuGrade.from_datasheet(
        "Crista",
        "S003 (+ chosen)",
        100.0,
        gyro_bias_turn_on_deg_h=5400.0,
        gyro_bias_instability_deg_h=1000.0,
        gyro_bias_tau_s=_TAU_MEMS_S,
        gyro_arw_deg_sqrt_h=2.25,
        gyro_scale_ppm=1e4,
        accel_bias_turn_on_mg=30.0,
        accel_bias_instability_mg=1.0,
        accel_bias_tau_s=_TAU_MEMS_S,
        accel_vrw_m_s_sqrt_h=0.15,
        accel_scale_ppm=1e4,
    )


def span_cpt() -> ImuGrade:
    """NovAtel SPAN-CPT / IMU-CPT (FOG gyros, MEMS accels; seeds 000, 002 ch5, 004), 100 Hz.

    S000 Tab B.2: gyro bias 20 deg/h, ARW 0.0667 deg/sqrt(h), gyro SF 1500 ppm; accel bias 50 mg,
    accel bias stability 0.75 mg (GM sigma), accel SF 4000 ppm. S002 5.3.4.2: gyro bias stability
    1 deg/h (GM sigma). Chosen: VRW 0.1 m/s/sqrt(h) (Tab B.2 says N/A; the tactical value of
    S001 Tab 1), tau 3600 s.
    """
    return ImuGrade.from_datasheet(
        "NovAtel SPAN-CPT",
        "S000 Tab B.2, S002 5.3.4.2 (+ chosen VRW, tau)",
        100.0,
        gyro_bias_turn_on_deg_h=20.0,
        gyro_bias_instability_deg_h=1.0,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.0667,
        gyro_scale_ppm=1500.0,
        accel_bias_turn_on_mg=50.0,
        accel_bias_instability_mg=0.75,
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.1,
        accel_scale_ppm=4000.0,
    )


def span_cpt_in_run() -> ImuGrade:
    """SPAN-CPT's in-run errors only: GM bias drifts and white noise, no turn-on bias, scale
    factor or quantisation. INS15 models exactly this, so filter-consistency (NEES) studies use
    it: any inconsistency left is the filter's, not a model mismatch."""
    return ImuGrade.from_datasheet(
        "NovAtel SPAN-CPT (in-run errors only)",
        "S002 5.3.4.2 bias stability, S000 Tab B.2 ARW (+ chosen VRW, tau), as span_cpt",
        100.0,
        gyro_bias_instability_deg_h=1.0,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.0667,
        accel_bias_instability_mg=0.75,
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.1,
    )


def kvh1750() -> ImuGrade:
    """KVH 1750 (FOG gyros, MEMS accels; seed 002 ch5 Calgary drives), 200 Hz (S002).

    S002 5.3.4.2: gyro bias offset 2 deg/h (the unit is missing in the text, SEED_SPEC 4 S002
    item 4), bias stability 0.05 deg/h (GM sigma). Chosen (not in the seeds; orders of magnitude
    of the maker's datasheet): ARW 0.012 deg/sqrt(h), gyro SF 50 ppm, accel turn-on 1 mg,
    in-run 0.05 mg, VRW 0.12 mg/sqrt(Hz) (= 0.07 m/s/sqrt(h)), accel SF 500 ppm, tau 3600 s.
    """
    return ImuGrade.from_datasheet(
        "KVH 1750",
        "S002 5.3.4.2 (+ chosen)",
        200.0,
        gyro_bias_turn_on_deg_h=2.0,
        gyro_bias_instability_deg_h=0.05,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.012,
        gyro_scale_ppm=50.0,
        accel_bias_turn_on_mg=1.0,
        accel_bias_instability_mg=0.05,
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.12e-3 * G_STD * 60.0,
        accel_scale_ppm=500.0,
    )


def hg1700() -> ImuGrade:
    """Honeywell HG1700 (RLG; reference IMU of seeds 000 and 003), 100 Hz.

    S000 Tab B.3: gyro bias 1.0 deg/h, ARW 0.125 deg/sqrt(h), gyro SF 150 ppm; accel bias 1 mg,
    bias stability 0.75 mg (GM sigma), VRW 0.198 m/s/sqrt(h) (as printed), accel SF 300 ppm.
    Chosen: gyro in-run GM sigma 0.5 deg/h (half the bias spec), tau 3600 s.
    """
    return ImuGrade.from_datasheet(
        "Honeywell HG1700",
        "S000 Tab B.3 (+ chosen gyro GM, tau)",
        100.0,
        gyro_bias_turn_on_deg_h=1.0,
        gyro_bias_instability_deg_h=0.5,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.125,
        gyro_scale_ppm=150.0,
        accel_bias_turn_on_mg=1.0,
        accel_bias_instability_mg=0.75,
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.198,
        accel_scale_ppm=300.0,
    )


def pos310() -> ImuGrade:
    """POS310 (tactical; seed 001 airborne test), 200 Hz (S001).

    S001 Tab 1: gyro bias 0.5 deg/h, accel bias 300 mGal, ARW 0.05 deg/sqrt(h), VRW
    0.1 m/s/sqrt(h). S001 models biases as GM only (eq 13), so the table biases are the GM
    sigmas and there is no separate turn-on bias (the stationary start gives each run its own
    offset). Chosen: tau 3600 s; scale factors 300 ppm (random constant, HG1700-like).
    """
    return ImuGrade.from_datasheet(
        "POS310",
        "S001 Tab 1 (+ chosen tau, SF)",
        200.0,
        gyro_bias_instability_deg_h=0.5,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.05,
        gyro_scale_ppm=300.0,
        accel_bias_instability_mg=mgal_to_m_s2(300.0) / (1e-3 * G_STD),
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.1,
        accel_scale_ppm=300.0,
    )


def span_fsas() -> ImuGrade:
    """NovAtel SPAN with iMAR FSAS (tactical FOG; seed 001 vehicle test), 200 Hz (S001).

    S001 Tab 1: gyro bias 0.75 deg/h, accel bias 1000 mGal, ARW 0.03 deg/sqrt(h), VRW
    0.1 m/s/sqrt(h); biases as GM sigmas (S001 eq 13). Chosen: tau 3600 s; SF 300 ppm.
    """
    return ImuGrade.from_datasheet(
        "SPAN-FSAS",
        "S001 Tab 1 (+ chosen tau, SF)",
        200.0,
        gyro_bias_instability_deg_h=0.75,
        gyro_bias_tau_s=_TAU_TACTICAL_S,
        gyro_arw_deg_sqrt_h=0.03,
        gyro_scale_ppm=300.0,
        accel_bias_instability_mg=mgal_to_m_s2(1000.0) / (1e-3 * G_STD),
        accel_bias_tau_s=_TAU_TACTICAL_S,
        accel_vrw_m_s_sqrt_h=0.1,
        accel_scale_ppm=300.0,
    )


#: IMU presets by the name a scenario uses (``imu_grade``, ``ins_grade``).
IMU_GRADES = {
    "crossbow_imu300cc": crossbow_imu300cc,
    "lsm6dsl": lsm6dsl,
    "crista": crista,
    "span_cpt": span_cpt,
    "span_cpt_in_run": span_cpt_in_run,
    "kvh1750": kvh1750,
    "hg1700": hg1700,
    "pos310": pos310,
    "span_fsas": span_fsas,
}


class OdometerParams(eqx.Module):
    """Odometer (wheel speed) error parameters: scale factor, white noise, quantisation."""

    name: str = eqx.field(static=True)
    source: str = eqx.field(static=True)
    scale_turn_on: float  # 1-sigma random-constant scale-factor error (dimensionless)
    scale_gm_sigma: float  # optional GM scale-factor part (0 = off)
    scale_gm_tau_s: float
    noise_std_m_s: float  # white noise per sample [m/s]
    quantum_m_s: float  # reading rounded to this step (0 = off)


def obd2_odometer() -> OdometerParams:
    """Vehicle speed from OBD-II (seeds 000 and 002; S000 logs it with a "CarChip").

    SAE J1979 PID 0x0D reports integer km/h, so the reading is rounded to 1 km/h. Chosen (no seed
    gives figures): scale factor 1 % (tyre radius, pressure and wear), white noise 0.05 m/s.
    """
    return OdometerParams(
        name="OBD-II speed",
        source="SAE J1979 quantum (+ chosen SF, noise)",
        scale_turn_on=0.01,
        scale_gm_sigma=0.0,
        scale_gm_tau_s=math.inf,
        noise_std_m_s=0.05,
        quantum_m_s=1.0 / 3.6,
    )


def wheel_odometer() -> OdometerParams:
    """Wheel-speed sensor without quantisation. Chosen: SF 0.5 %, white noise 0.02 m/s."""
    return OdometerParams(
        name="wheel odometer",
        source="chosen",
        scale_turn_on=0.005,
        scale_gm_sigma=0.0,
        scale_gm_tau_s=math.inf,
        noise_std_m_s=0.02,
        quantum_m_s=0.0,
    )


#: Odometer presets by the name a scenario uses (``odometer``).
ODOMETERS = {"obd2_odometer": obd2_odometer, "wheel_odometer": wheel_odometer}


def imu_grade(name: str) -> ImuGrade:
    """The IMU preset ``name``; ValueError naming the allowed ones otherwise."""
    if name not in IMU_GRADES:
        raise ValueError(f"unknown IMU preset {name!r}; allowed: {', '.join(IMU_GRADES)}")
    return IMU_GRADES[name]()


def odometer(name: str) -> OdometerParams:
    """The odometer preset ``name``; ValueError naming the allowed ones otherwise."""
    if name not in ODOMETERS:
        raise ValueError(f"unknown odometer preset {name!r}; allowed: {', '.join(ODOMETERS)}")
    return ODOMETERS[name]()


# ---- simulation --------------------------------------------------------------------------------
class ImuErrors(NamedTuple):
    """The true errors of one simulated run (per sample k unless noted)."""

    gyro_bias_rad_s: jax.Array  # (N, 3) total bias = turn-on + GM
    gyro_bias_turn_on_rad_s: jax.Array  # (3,)
    gyro_bias_gm_rad_s: jax.Array  # (N, 3)
    gyro_scale: jax.Array  # (N, 3) total scale-factor error
    gyro_noise_rad: jax.Array  # (N, 3) white noise on dtheta
    gyro_quant_residual_rad: jax.Array  # (N, 3) carry r_k after sample k
    accel_bias_m_s2: jax.Array
    accel_bias_turn_on_m_s2: jax.Array
    accel_bias_gm_m_s2: jax.Array
    accel_scale: jax.Array
    accel_noise_m_s: jax.Array
    accel_quant_residual_m_s: jax.Array


def gm_phi_and_std(sigma, tau_s, dt):
    """Exact discrete first-order GM: phi = e^{-dt/tau}, std(w) = sigma sqrt(1 - phi^2)."""
    phi = jnp.exp(-dt / jnp.asarray(tau_s, jnp.float64))
    return phi, sigma * jnp.sqrt(1.0 - phi * phi)


def gauss_markov(z, x0, phi, w_std):
    """GM sequence x_0 = x0, x_k = phi x_{k-1} + w_std z_k (k >= 1) via ``lax.scan``.

    ``z``: (N, ...) standard normal drivers (z[0] unused); returns (N, ...).
    """

    def step(x, zk):
        x = phi * x + w_std * zk
        return x, x

    _, xs = jax.lax.scan(step, x0, z[1:])
    return jnp.concatenate([x0[None], xs], axis=0)


def _quantize(x, residual, q):
    """Whole quanta of x + residual and the new residual (identity when q == 0)."""
    total = x + residual
    qs = jnp.where(q > 0.0, q, 1.0)
    out = jnp.where(q > 0.0, qs * jnp.round(total / qs), total)
    return out, total - out


def simulate_imu(key, dtheta_b, dv_b, dt, grade: ImuGrade):
    """Corrupt perfect increments (N, 3) with ``grade``'s errors (S001 eq 12, module docstring).

    Returns ``(dtheta_meas, dv_meas, ImuErrors)``. Pure JAX from ``key``: jit- and vmap-able over
    keys. ``dt`` is the (constant) sample interval [s].
    """
    dtheta_b = jnp.asarray(dtheta_b, jnp.float64)
    dv_b = jnp.asarray(dv_b, jnp.float64)
    n = dtheta_b.shape[0]
    dt = jnp.asarray(dt, jnp.float64)
    # One draw for everything (a single threefry call compiles much faster than several):
    # row 0 turn-on values, row 1 GM initial values, rows 2.. GM drivers (first unused) and noise.
    z_all = jax.random.normal(key, (n + 2, 6, 3), jnp.float64)

    # Rows: gyro bias, gyro scale, accel bias, accel scale.
    sig_to = jnp.array(
        [
            grade.gyro_bias_turn_on_rad_s,
            grade.gyro_scale_turn_on,
            grade.accel_bias_turn_on_m_s2,
            grade.accel_scale_turn_on,
        ]
    )
    sig_gm = jnp.array(
        [
            grade.gyro_bias_gm_sigma_rad_s,
            grade.gyro_scale_gm_sigma,
            grade.accel_bias_gm_sigma_m_s2,
            grade.accel_scale_gm_sigma,
        ]
    )
    tau = jnp.array(
        [
            grade.gyro_bias_gm_tau_s,
            grade.gyro_scale_gm_tau_s,
            grade.accel_bias_gm_tau_s,
            grade.accel_scale_gm_tau_s,
        ]
    )
    turn_on = sig_to[:, None] * z_all[0, :4]
    phi, w_std = gm_phi_and_std(sig_gm, tau, dt)
    gm0 = sig_gm[:, None] * z_all[1, :4]
    gm = gauss_markov(z_all[2:, :4], gm0, phi[:, None], w_std[:, None])  # (N, 4, 3)
    total = turn_on[None] + gm

    white = jnp.array([grade.gyro_arw_rad_sqrt_s, grade.accel_vrw_m_s_sqrt_s]) * jnp.sqrt(dt)
    noise = white[None, :, None] * z_all[2:, 4:]

    ideal_g = (1.0 + total[:, 1]) * dtheta_b + total[:, 0] * dt + noise[:, 0]
    ideal_a = (1.0 + total[:, 3]) * dv_b + total[:, 2] * dt + noise[:, 1]

    quanta = jnp.array([grade.gyro_quantum_rad, grade.accel_quantum_m_s])

    def q_step(res, x):
        out, res = _quantize(x, res, quanta[:, None])
        return res, (out, res)

    x = jnp.stack([ideal_g, ideal_a], axis=1)  # (N, 2, 3)
    _, (meas, resid) = jax.lax.scan(q_step, jnp.zeros((2, 3), jnp.float64), x)

    errors = ImuErrors(
        gyro_bias_rad_s=total[:, 0],
        gyro_bias_turn_on_rad_s=turn_on[0],
        gyro_bias_gm_rad_s=gm[:, 0],
        gyro_scale=total[:, 1],
        gyro_noise_rad=noise[:, 0],
        gyro_quant_residual_rad=resid[:, 0],
        accel_bias_m_s2=total[:, 2],
        accel_bias_turn_on_m_s2=turn_on[2],
        accel_bias_gm_m_s2=gm[:, 2],
        accel_scale=total[:, 3],
        accel_noise_m_s=noise[:, 1],
        accel_quant_residual_m_s=resid[:, 1],
    )
    return meas[:, 0], meas[:, 1], errors


class OdometerErrors(NamedTuple):
    scale: jax.Array  # (N,) total scale-factor error
    noise_m_s: jax.Array  # (N,) white noise


def simulate_odometer(key, speed_mps, dt, params: OdometerParams):
    """Odometer reading (N,) from the true forward speed: max(0, (1 + s_k) v_k + n_k), rounded
    to ``quantum_m_s`` when set; exactly 0 when v_k == 0 (no wheel pulses at rest).

    Returns ``(speed_meas, OdometerErrors)``; vmap-able over keys.
    """
    speed = jnp.asarray(speed_mps, jnp.float64)
    n = speed.shape[0]
    # One draw: row 0 (turn-on, GM initial value), rows 1.. (GM drivers, noise).
    z = jax.random.normal(key, (n + 1, 2), jnp.float64)
    phi, w_std = gm_phi_and_std(params.scale_gm_sigma, params.scale_gm_tau_s, dt)
    gm = gauss_markov(z[1:, 0], params.scale_gm_sigma * z[0, 1], phi, w_std)
    scale = params.scale_turn_on * z[0, 0] + gm
    noise = params.noise_std_m_s * z[1:, 1]
    reading = jnp.maximum((1.0 + scale) * speed + noise, 0.0)
    q = jnp.asarray(params.quantum_m_s, jnp.float64)
    qs = jnp.where(q > 0.0, q, 1.0)
    reading = jnp.where(q > 0.0, qs * jnp.round(reading / qs), reading)
    reading = jnp.where(speed == 0.0, 0.0, reading)
    return reading, OdometerErrors(scale, noise)


def riss_subset(dtheta_b, dv_b, dt):
    """RISS channels from (N, 3) increments: vertical gyro rate w_z [rad/s] and transverse /
    forward specific forces f_x, f_y [m/s^2], each the mean over its sample interval."""
    return dtheta_b[..., 2] / dt, dv_b[..., 0] / dt, dv_b[..., 1] / dt
