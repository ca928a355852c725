"""Navigation systems the integration filters drive: the full-IMU INS and the RISS.

A system knows its mechanization, its error model, where its GNSS antenna is, and how to feed
estimated errors back. The filters (tight.py, loose.py) only talk to this interface,
``AbstractNavSystem`` (equinox's abstract / final pattern; the GNSS-only receiver of
``ppp_only.py`` is the third implementation; docs/extending.md "Add a navigation system"):

- ``layout``: the navigation + sensor error-state layout (a prefix of the filter's layout);
- ``propagate(nav, sensors, samples, dt)`` -> (nav, mean corrected inputs over the epoch);
- ``dynamics(nav, mean_inputs, sensors)`` -> continuous (F, G, Qc) of ``layout``;
- ``antenna(nav, mean_inputs, sensors, layout_full)`` -> ppp.Receiver with Jacobians;
- ``feedback(nav, sensors, dx, layout_full)`` -> corrected (nav, sensors);
- ``initial_std(...)``, ``llh(nav)``, ``vel_enu(nav)``, ``euler(nav)`` for outputs.
"""

from __future__ import annotations

import abc
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxnav import attitude, geodesy
from jaxnav.core.states import INS15, RISS16, StateLayout
from jaxnav.gnss.ppp import Receiver
from jaxnav.ins import errors as ins_errors
from jaxnav.ins import riss, riss_errors, strapdown


class NavSigmas(eqx.Module):
    """Initial 1-sigma of the navigation states (chosen: what a GNSS initialisation gives)."""

    pos_m: float = 3.0
    vel_m_s: float = 0.3
    roll_pitch_rad: float = 0.01  # ~0.6 deg from levelling
    azimuth_rad: float = 0.05  # ~3 deg from GNSS course over ground
    odo_speed_m_s: float = 0.3  # odometer scale error ~1 % of a 30 m/s top speed
    #: Length [s] of a standstill gyro calibration behind ``sensors0`` (None: none). Full-IMU
    #: systems then start the gyro bias at in-run sigma (+) ARW / sqrt(T) instead of turn-on:
    #: the uncalibrated prior lets a MEMS filter learn a wrong bias while heading is unobservable
    #: at rest. (The RISS model's gyro-bias sigma is the in-run one already.)
    gyro_calibration_s: float | None = None


def nav_block_size(layout: StateLayout) -> int:
    """Size of the leading navigation block (pos, vel and attitude / azimuth) for outputs."""
    names = [n for n in ("pos", "vel", "att", "azimuth") if layout.has(n)]
    return max(layout.sl(n).stop for n in names)


def _pos_std_llh(llh, sigma_m):
    """Geodetic 1-sigma (rad, rad, m) of an isotropic sigma_m [m] at ``llh``."""
    return sigma_m / geodesy.metres_per_radian(llh)


def _place(std, layout: StateLayout, name, value):
    return std.at[layout.sl(name)].set(value) if layout.has(name) else std


class AbstractNavSystem(eqx.Module):
    """The navigation-system interface of the tight and loose filters (module docstring).

    ``nav`` is the system's own typed navigation state (``riss.RissState``,
    ``strapdown.InsNav``, ``ppp_only.GnssNav``), ``sensors`` its sensor-error estimates. A
    concrete system that leaves an abstract method out is a TypeError when its class is
    defined, not when a filter first calls it.
    """

    @property
    @abc.abstractmethod
    def layout(self) -> StateLayout:
        """The navigation + sensor error-state layout (a prefix of the filter's layout)."""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.__name__.startswith("Abstract"):
            return
        # ABCMeta sets __abstractmethods__ only after __init_subclass__ returns: look directly.
        abstract = sorted(k for k in dir(cls) if getattr(getattr(cls, k, None),
                                                          "__isabstractmethod__", False))
        if abstract:
            raise TypeError(f"navigation system {cls.__name__} does not implement "
                            f"{', '.join(abstract)}")

    @abc.abstractmethod
    def propagate(self, nav, sensors, samples, dt):
        """(nav at the epoch's end, mean corrected inputs) after the epoch's samples [K, ...]."""

    @abc.abstractmethod
    def dynamics(self, nav, mean_inputs, sensors):
        """Continuous error dynamics (F, G, Qc) of ``layout``: d(dx)/dt = F dx + G w, E[w w^T] =
        Qc delta(t)."""

    @abc.abstractmethod
    def antenna(self, nav, mean_inputs, sensors, layout_full: StateLayout) -> Receiver:
        """The antenna's ECEF position / velocity and their Jacobians w.r.t. the full dx."""

    @abc.abstractmethod
    def feedback(self, nav, sensors, dx, layout_full: StateLayout):
        """Closed loop: (nav, sensors) corrected by the estimated errors, x <- x_hat - dx_hat."""

    @abc.abstractmethod
    def predict_sensors(self, sensors, dt):
        """Sensor-error estimates dt later, as the error model predicts them (x_hat <- Phi x_hat:
        Gauss-Markov shares decay with their tau, constants stay)."""

    @abc.abstractmethod
    def initial_std(self, nav, sig: NavSigmas):
        """[layout.size] initial standard deviations of the error states."""

    @abc.abstractmethod
    def zero_sensors(self):
        """Sensor-error estimates of a system that has learnt nothing yet."""

    @abc.abstractmethod
    def idle_inputs(self, nav):
        """Mean inputs before any propagation (for the antenna at the start)."""

    @abc.abstractmethod
    def llh(self, nav):
        """[3] geodetic position (lat rad, lon rad, h m) of the navigation point."""

    @abc.abstractmethod
    def vel_enu(self, nav):
        """[3] ENU velocity [m/s]."""

    @abc.abstractmethod
    def euler(self, nav):
        """[3] (roll, pitch, azimuth) [rad]."""

    def nav_covariance(self, nav, P, layout_full: StateLayout):
        """Covariance of the output (pos, vel, attitude) over the leading navigation block:
        T P T^T with T the outputs' Jacobian w.r.t. the error state (here the block itself)."""
        k = nav_block_size(layout_full)
        return P[:k, :k]

    def calibrate_static(self, nav, samples, dt):
        """Sensor-error estimates from a standstill with known attitude (systems with sensors)."""
        raise TypeError(f"{type(self).__name__} has no sensors to calibrate at a standstill")


class RissSystem(AbstractNavSystem):
    """3D RISS (seeds 000/002) with its 16-state (S000) or 9-state (S002) error model.

    Beyond the seeds' models (whose position, velocity and azimuth rows have no direct process
    noise, S000 eq 4.32ff), two white-noise inputs keep the filter consistent with real sensors:
    the vertical gyro's angle random walk drives the azimuth, and the odometer's white noise and
    quantisation (a reading error of ``speed_noise_m_s`` every ``input_interval_s``) drive the
    along-track velocity and position. Both default to 0 (the seeds' form).

    The velocity error is algebraic (``riss_errors.algebraic_velocity_dynamics``): the
    mechanization re-derives v = v_od u(A, p) at every input, so the GNSS velocity rows and the
    position rows see dx[vel] + M dx, with M = dv/dA (cross-track, v dA) and dv/d(odo speed)
    (along-track). The seeds' integrated velocity state, whose only link to the heading is
    F[vel, A] = a_od, let braking drive the azimuth the wrong way under Doppler updates
    (a -25 deg heading error within 15 s of a 24 -> 6 m/s stop, tests/test_riss_braking.py).
    For RISS16, M also carries the pitch error of the accelerometer-bias and a_od states (the
    vertical velocity, hence the height), and the odometer-speed error is a scale-factor error,
    F[odo_speed, odo_speed] = ln(v_k / v_{k-1}) / dt, instead of S000's integral of the a_od
    error: at constant speed the speed error cannot drift, so slowly varying code errors of a
    2-3 satellite partial outage no longer pull the speed (tests/test_tight.py).
    """

    layout: StateLayout = eqx.field(static=True, default=RISS16)
    params: riss_errors.RissNoiseParams = eqx.field(default_factory=riss_errors.RissNoiseParams)
    lever_b: jax.Array = eqx.field(default_factory=lambda: jnp.zeros(3))
    gyro_arw_rad_sqrt_s: float = 0.0
    speed_noise_m_s: float = 0.0
    input_interval_s: float = 1.0
    epoch_interval_s: float = 1.0

    @classmethod
    def for_sensors(cls, grade, odometer, lever_b, input_interval_s, epoch_interval_s=1.0,
                    layout: StateLayout = RISS16, typical_turn_rate_rad_s=0.1,
                    typical_accel_m_s2=1.0):
        """A RISS whose stochastic model follows simulated / datasheet sensor figures.

        Gyro bias: GM with the grade's in-run sigma, widened in quadrature by the scale-factor
        error at a typical turn rate (the RISS model has no scale-factor state); accelerometer
        bias: the grade's in-run GM; odometer acceleration: the scale factor times a typical
        acceleration (at least the default 0.005 m/s^2); speed noise: white noise plus the
        quantisation's q / sqrt(12).
        """
        base = riss_errors.RissNoiseParams()
        gyro_sigma = jnp.hypot(
            grade.gyro_bias_gm_sigma_rad_s, grade.gyro_scale_turn_on * typical_turn_rate_rad_s
        )
        params = riss_errors.RissNoiseParams(
            gyro_bias_beta_1_s=1.0 / grade.gyro_bias_gm_tau_s,
            gyro_bias_sigma_rad_s=float(gyro_sigma),
            accel_bias_beta_1_s=1.0 / grade.accel_bias_gm_tau_s,
            accel_bias_sigma_m_s2=float(grade.accel_bias_gm_sigma_m_s2),
            odo_accel_sigma_m_s2=max(
                base.odo_accel_sigma_m_s2, odometer.scale_turn_on * typical_accel_m_s2
            ),
        )
        speed = float(jnp.hypot(odometer.noise_std_m_s, odometer.quantum_m_s / jnp.sqrt(12.0)))
        return cls(layout, params, jnp.asarray(lever_b, jnp.float64),
                   float(grade.gyro_arw_rad_sqrt_s), speed, input_interval_s, epoch_interval_s)

    def propagate(self, nav: riss.RissState, sensors: riss.RissSensorErrors, samples, dt):
        """Mechanize the epoch's raw ``RissInput`` samples [K] with the current sensor estimates."""
        nav, _ = riss.riss_run(nav, samples, dt, sensors)
        mean = riss.RissInput(
            samples.f_x.mean(),
            samples.f_y.mean(),
            samples.w_z.mean(),
            samples.v_od[-1],
            samples.a_od.mean(),
        )
        return nav, mean

    def dynamics(self, nav, mean_inputs, sensors):
        """Seed F, G, Qc recast with the algebraic velocity error, plus white-noise columns.

        Azimuth: PSD ARW^2. Odometer reading noise sigma_s every dt_in and the pitch noise it
        causes (below), both white from one reading to the next:
        - RISS16: the ``vel`` states are that reading error, a GM of correlation time dt_in
          with steady sigma (sigma_s along track, v sigma_p up); the position integrates it
          through F[pos, vel] (PSD 2 sigma^2 dt_in, the white-noise limit s^2 dt_in within 2x);
        - RISS9 (velocity = the seeds' integrated along-track error): along-track position PSD
          sigma_s^2 dt_in (a random walk of the integrated speed error) and velocity PSD
          sigma_s^2 / dt_epoch (variance grows by sigma_s^2 per epoch until Doppler/position
          updates pull it back); the same for the vertical pitch noise.
        """
        fn = riss_errors.riss16_dynamics if self.layout == RISS16 else riss_errors.riss9_dynamics
        F, G, Qc = fn(nav, mean_inputs, self.params, sensors)
        dt_in, dt_ep = self.input_interval_s, self.epoch_interval_s
        read_beta = 1.0 / dt_in
        scale_rate = 0.0
        if self.layout.has("odo_speed"):
            scale_rate = riss_errors.odometer_scale_rate(nav, mean_inputs, dt_ep, sensors)
        F = riss_errors.algebraic_velocity_dynamics(F, self.layout, nav, read_beta, scale_rate)
        forward = riss_errors.along_track_unit(nav.azimuth, nav.pitch)
        n = self.layout.size
        pos, vel = self.layout.sl("pos"), self.layout.sl("vel")
        up = jnp.array([0.0, 0.0, 1.0])
        G_extra = jnp.zeros((n, 5))
        G_extra = G_extra.at[self.layout.i("azimuth"), 0].set(1.0)
        G_extra = G_extra.at[pos, 1].set(geodesy.llh_rate_matrix(nav.llh) @ forward)
        G_extra = G_extra.at[vel, 2].set(forward)
        G_extra = G_extra.at[pos, 3].set(up)
        G_extra = G_extra.at[vel, 4].set(up)
        # The pitch is re-derived every input from (f_y - a_od) / g, and a_od differences two
        # noisy speed readings: pitch noise sqrt(2) sigma_s / (dt_in g) tilts the velocity,
        # v_u error = v sigma_p (white, like the speed error itself).
        s2 = self.speed_noise_m_s**2
        g = geodesy.normal_gravity(nav.llh[0], nav.llh[2])
        sigma_pitch = jnp.sqrt(2.0) * self.speed_noise_m_s / (dt_in * g)
        vu2 = (jnp.linalg.norm(nav.vel_enu) * sigma_pitch) ** 2
        if self.layout.has("odo_speed"):
            zero = jnp.zeros(())
            gm = 2.0 * read_beta  # GM PSD 2 beta sigma^2
            q_extra = jnp.stack([self.gyro_arw_rad_sqrt_s**2, zero, gm * s2, zero, gm * vu2])
        else:
            q_extra = jnp.stack(
                [self.gyro_arw_rad_sqrt_s**2, s2 * dt_in, s2 / dt_ep, vu2 * dt_in, vu2 / dt_ep]
            )
        G = jnp.concatenate([G, G_extra], axis=1)
        m = Qc.shape[0]
        Qc = jnp.zeros((m + 5, m + 5)).at[:m, :m].set(Qc).at[m:, m:].set(jnp.diag(q_extra))
        return F, G, Qc

    def _velocity_jacobian(self, nav: riss.RissState, layout_full: StateLayout):
        """d(velocity)/d(error state) over ``layout_full``: the vel states plus M (class doc)."""
        M = riss_errors.mechanized_velocity_jacobian(self.layout, nav)
        J = jnp.zeros((3, layout_full.size)).at[:, : self.layout.size].set(M)
        return J.at[:, layout_full.sl("vel")].add(jnp.eye(3))

    def nav_covariance(self, nav: riss.RissState, P, layout_full: StateLayout):
        """The output velocity is v_od u(A, p) re-derived at every input, so its error is
        dx[vel] + M dx (class doc), not dx[vel] alone: T P T^T with T's velocity rows the
        ``_velocity_jacobian`` (P[vel, vel] alone was ~1e6 x too small, issue 16)."""
        k = nav_block_size(layout_full)
        T = jnp.eye(layout_full.size)[:k]
        T = T.at[layout_full.sl("vel")].set(self._velocity_jacobian(nav, layout_full))
        return T @ P @ T.T

    def C_b_l(self, nav: riss.RissState):
        return attitude.dcm_from_euler(jnp.stack([nav.roll, nav.pitch, nav.azimuth]))

    def antenna(self, nav: riss.RissState, mean_inputs, sensors, layout_full: StateLayout):
        """Antenna at llh + D^-1 C l, with the lever arm's roll, pitch and azimuth columns.

        The RISS velocity is the odometer's; the lever-arm rotation term w x l (< 1 cm/s for a
        roof antenna in a 0.1 rad/s turn) is neglected.
        """
        euler = jnp.stack([nav.roll, nav.pitch, nav.azimuth])
        lever_l = attitude.dcm_from_euler(euler) @ self.lever_b
        llh_ant = nav.llh + geodesy.llh_rate_matrix(nav.llh) @ lever_l
        C_l_e = geodesy.C_l_e(llh_ant[0], llh_ant[1])
        n = layout_full.size
        J_pos = jnp.zeros((3, n))
        J_pos = J_pos.at[:, layout_full.sl("pos")].set(geodesy.llh_to_ecef_jacobian(llh_ant))
        # Attitude columns d(C l)/d(angle) (for the azimuth: [u_N, -u_E, 0] in ENU).
        partials = attitude.dcm_euler_partials(euler)
        for name, dC in zip(("roll", "pitch", "azimuth"), partials, strict=True):
            if layout_full.has(name):
                J_pos = J_pos.at[:, layout_full.i(name)].set(C_l_e @ (dC @ self.lever_b))
        J_vel = C_l_e @ self._velocity_jacobian(nav, layout_full)
        return Receiver(geodesy.llh_to_ecef(llh_ant), C_l_e @ nav.vel_enu, llh_ant, J_pos, J_vel)

    def feedback(self, nav, sensors, dx, layout_full: StateLayout):
        """``riss_errors.riss_feedback``; the output velocity also drops the M dx part of its
        error (the next input re-derives it from the corrected azimuth and speed anyway)."""
        new_nav, new_sensors = riss_errors.riss_feedback(nav, dx, layout_full, sensors)
        M = self._velocity_jacobian(nav, layout_full).at[:, layout_full.sl("vel")].set(0.0)
        return new_nav._replace(vel_enu=new_nav.vel_enu - M @ dx), new_sensors

    def predict_sensors(self, sensors: riss.RissSensorErrors, dt):
        return riss_errors.decay_sensor_errors(sensors, self.params, self.layout, dt)

    def initial_std(self, nav: riss.RissState, sig: NavSigmas):
        p = self.params
        std = jnp.zeros(self.layout.size)
        std = std.at[self.layout.sl("pos")].set(_pos_std_llh(nav.llh, sig.pos_m))
        std = std.at[self.layout.sl("vel")].set(sig.vel_m_s)
        std = std.at[self.layout.i("azimuth")].set(sig.azimuth_rad)
        std = _place(std, self.layout, "odo_accel", p.odo_accel_sigma_m_s2)
        std = _place(std, self.layout, "gyro_bias_z", p.gyro_bias_sigma_rad_s)
        std = _place(std, self.layout, "roll", p.roll_sigma_rad)
        std = _place(std, self.layout, "pitch", p.pitch_sigma_rad)
        std = _place(std, self.layout, "accel_bias_x", p.accel_bias_sigma_m_s2)
        std = _place(std, self.layout, "accel_bias_y", p.accel_bias_sigma_m_s2)
        std = _place(std, self.layout, "odo_speed", sig.odo_speed_m_s)
        return std

    def zero_sensors(self):
        return riss.zero_sensor_errors()

    def calibrate_static(self, nav: riss.RissState, samples: riss.RissInput, dt):
        """Sensor estimates from a standstill: b_z = mean(w_z) - w_e sin(lat) (vertical gyro),
        b_xy = mean(f_xy) - gravity projection of the start attitude.

        The turn-on bias of a MEMS gyro (2 deg/s for the IMU300CC) dwarfs the in-run model, so
        the filter starts from this standstill estimate, as S000 does before driving off.
        """
        bias = samples.w_z.mean() - geodesy.OMEGA_E * jnp.sin(nav.llh[0])
        # Horizontal accelerometers: static specific force minus the gravity projection of the
        # start attitude (riss_pitch_roll at rest: f_y = g sin p, f_x = -g cos p sin r). This
        # assumes the start attitude is known (a levelled / surveyed parking spot): at rest a
        # bias cannot otherwise be told from a tilt, and S000's F leaves both unobservable.
        g = geodesy.normal_gravity(nav.llh[0], nav.llh[2])
        f_expected = jnp.stack(
            [-g * jnp.cos(nav.pitch) * jnp.sin(nav.roll), g * jnp.sin(nav.pitch)]
        )
        accel = jnp.stack([samples.f_x.mean(), samples.f_y.mean()]) - f_expected
        return self.zero_sensors()._replace(gyro_bias_z_rad_s=bias, accel_bias_xy_m_s2=accel)

    def idle_inputs(self, nav):
        """Mean inputs before any propagation: level, unaccelerated, at the state's speed."""
        z = jnp.zeros(())
        return riss.RissInput(z, z, z, jnp.linalg.norm(nav.vel_enu), z)

    def llh(self, nav):
        return nav.llh

    def vel_enu(self, nav):
        return nav.vel_enu

    def euler(self, nav):
        return jnp.stack([nav.roll, nav.pitch, nav.azimuth])


class InsInputs(NamedTuple):
    """The full INS's mean inputs over a propagation step (``InsSystem.propagate``)."""

    f_b: jax.Array  # mean compensated specific force [m/s^2], body
    w_ib_b: jax.Array  # mean compensated angular rate [rad/s], body
    rates: ins_errors.InputRates  # their squared rates of change (unmodelled scale factors)


class InsSystem(AbstractNavSystem):
    """Full strapdown INS (ENU, quaternion) with the 15/21/27-state error model."""

    layout: StateLayout = eqx.field(static=True, default=INS15)
    model: ins_errors.ImuErrorModel | None = None
    lever_b: jax.Array = eqx.field(default_factory=lambda: jnp.zeros(3))
    # seconds of the standstill gyro calibration the run starts with (None: none); sets the
    # turn-on prior that splits a lumped bias correction (``ins_errors.gm_share``), as
    # ``NavSigmas.gyro_calibration_s`` sets it for the initial covariance
    gyro_calibration_s: float | None = eqx.field(static=True, default=None)

    def propagate(self, nav, sensors: ins_errors.SensorErrors, samples, dt):
        """``nav`` an ``InsNav``; ``samples`` raw ImuIncrements [K]. Mean inputs: the mean
        specific force and rate, and their rates of change (``_input_rates``)."""
        corrected = ins_errors.correct_imu(samples, sensors, dt)
        state, _ = strapdown.mechanize(nav.state, corrected, dt, nav.prev)
        last = strapdown.ImuIncrements(corrected.dtheta_b[-1], corrected.dv_b[-1])
        span = dt * samples.dv_b.shape[0]
        mean = InsInputs(corrected.dv_b.sum(0) / span, corrected.dtheta_b.sum(0) / span,
                         self._input_rates(corrected, dt))
        return strapdown.InsNav(state, last), mean

    def _input_rates(self, corrected: strapdown.ImuIncrements, dt) -> ins_errors.InputRates:
        """Least-squares slopes s of f_b and w_ib_b over the samples, squared, minus the slope
        variance their white noise gives, (PSD / dt) / sum(t_i^2) with t_i the sample times
        about the middle (VRW / ARW of the model), floored at 0."""
        K = corrected.dv_b.shape[0]
        t = (jnp.arange(K) - (K - 1) / 2.0) * dt
        stt = jnp.maximum(jnp.sum(t * t), dt * dt)  # K = 1: no slope (0 below)

        def rate2(x, psd):
            slope = (t @ (x / dt)) / stt
            return jnp.maximum(slope**2 - psd / dt / stt, 0.0)

        m = self.model
        if m is None:
            z = jnp.zeros(3)
            return ins_errors.InputRates(z, z, jnp.asarray(K * dt))
        return ins_errors.InputRates(
            rate2(corrected.dv_b, jnp.broadcast_to(m.accel_vrw_m_s_sqrt_s, (3,)) ** 2),
            rate2(corrected.dtheta_b, jnp.broadcast_to(m.gyro_arw_rad_sqrt_s, (3,)) ** 2),
            jnp.asarray(K * dt),
        )

    def dynamics(self, nav, mean_inputs, sensors):
        state = nav.state
        return ins_errors.error_dynamics(
            self.layout, state.llh, state.vel_enu, state.C_b_l, mean_inputs.f_b,
            mean_inputs.w_ib_b, self.model, mean_inputs.rates,
        )

    def antenna(self, nav, mean_inputs, sensors, layout_full: StateLayout):
        state = nav.state
        w_ib_b = mean_inputs.w_ib_b
        C = state.C_b_l
        llh_ant = strapdown.antenna_llh(state.llh, C, self.lever_b)
        vel_ant = strapdown.antenna_vel_enu(state.llh, state.vel_enu, C, w_ib_b, self.lever_b)
        C_l_e = geodesy.C_l_e(llh_ant[0], llh_ant[1])
        J_llh = ins_errors.antenna_llh_jacobian(layout_full, state.llh, C, self.lever_b)
        J_vel = ins_errors.antenna_vel_jacobian(
            layout_full, state.llh, state.vel_enu, C, w_ib_b, self.lever_b
        )
        return Receiver(
            geodesy.llh_to_ecef(llh_ant),
            C_l_e @ vel_ant,
            llh_ant,
            geodesy.llh_to_ecef_jacobian(llh_ant) @ J_llh,
            C_l_e @ J_vel,
        )

    def feedback(self, nav, sensors, dx, layout_full: StateLayout):
        state = ins_errors.feedback(nav.state, dx, layout_full)
        share = ((1.0, 1.0) if self.model is None
                 else ins_errors.gm_share(self.model, self.layout, self.gyro_calibration_s))
        sensors = ins_errors.feedback_sensors(sensors, dx, layout_full, share)
        return strapdown.InsNav(state, nav.prev), sensors

    def predict_sensors(self, sensors: ins_errors.SensorErrors, dt):
        if self.model is None:  # no stochastic model: the estimates are constants
            return sensors
        return ins_errors.decay(sensors, self.model, self.layout, dt)

    def initial_std(self, nav, sig: NavSigmas):
        state = nav.state
        std = ins_errors.sensor_initial_std(self.layout, self.model, sig.gyro_calibration_s)
        std = std.at[self.layout.sl("pos")].set(_pos_std_llh(state.llh, sig.pos_m))
        std = std.at[self.layout.sl("vel")].set(sig.vel_m_s)
        att = jnp.stack([sig.roll_pitch_rad, sig.roll_pitch_rad, sig.azimuth_rad])
        return std.at[self.layout.sl("att")].set(att)

    def zero_sensors(self):
        return ins_errors.SensorErrors.zeros()

    def calibrate_static(self, nav, samples: strapdown.ImuIncrements, dt):
        """Gyro biases from a standstill with known attitude: b_g = mean(w_b) - C_l^b w_ie^l.

        Accelerometer biases stay zero: at rest they cannot be told from a tilt.
        """
        state = nav.state
        w_mean = samples.dtheta_b.mean(0) / dt
        w_ie_b = state.C_b_l.T @ geodesy.earth_rate_enu(state.llh[0])
        return self.zero_sensors()._replace(gyro_bias_rad_s=w_mean - w_ie_b)

    def idle_inputs(self, nav):
        """Mean inputs before any propagation (only the lever-arm terms read them)."""
        z = jnp.zeros(3)
        return InsInputs(z, z, ins_errors.InputRates(z, z, jnp.zeros(())))

    def llh(self, nav):
        return nav.state.llh

    def vel_enu(self, nav):
        return nav.state.vel_enu

    def euler(self, nav):
        return attitude.euler_from_quat(nav.state.q_b_l)
