"""GNSS-only "navigation systems" for stand-alone PPP through the tight filter's epoch step.

They implement the system interface of ``filter/systems.py`` (layout, propagate, dynamics,
antenna, feedback, initial_std, zero_sensors, idle_inputs, llh, vel_enu, euler), so
``filter/tight.py`` runs PPP without an IMU: the same measurement models, resets, gating and
outputs as the integrated filters (issue 6: "the same measurement models as the tight filter").

Motion models (``GnssOnlySystem.model``):

- ``"static"``: position is a random constant (S002 §5.2.2: "the three position parameters were
  modeled as random constants"); layout ``pos``.
- ``"random_walk"``: kinematic PPP with the position a random walk of large PSD, S002 §5.2.3:
  "(100 m/sqrt(s))" -- at 30 s epochs a 550 m 1-sigma step, i.e. an essentially new position
  every epoch; layout ``pos``. This is the model ``jaxnav ppp --mode kinematic`` uses.
- ``"constant_velocity"``: position driven by an ENU velocity that is a random walk
  (white acceleration of PSD ``accel_psd_m2_s3``); layout ``pos, vel``; Doppler rows then
  observe the velocity. Offered for vehicles; not used for the reference-station validation.

States follow core/states.py: position errors geodetic (d_lat, d_lon, d_h), velocity errors
ENU, dx = estimate - truth, closed-loop feedback x <- x - dx. The position PSD is given in
metres and converted per axis with the radii of curvature.

The per-epoch "samples" the tight filter hands to ``propagate`` are a dummy array [K] (use
``dummy_samples``): K * dt is the epoch interval, nothing else is read from them.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxnav import geodesy
from jaxnav.core.states import StateLayout
from jaxnav.filter.systems import AbstractNavSystem, NavSigmas
from jaxnav.gnss.ppp import Receiver

MODELS = ("static", "random_walk", "constant_velocity")

#: Position-only layout (static and random-walk kinematic PPP).
POS_LAYOUT = StateLayout((("pos", 3),))
#: Position + ENU velocity (constant-velocity kinematic PPP).
POS_VEL_LAYOUT = StateLayout((("pos", 3), ("vel", 3)))


class GnssNav(NamedTuple):
    """Navigation state of a GNSS-only receiver."""

    llh: Float[Array, "3"]  # lat rad, lon rad, h m
    vel_enu: Float[Array, "3"]  # m/s (zero and unused for the position-only models)


def dummy_samples(n_epochs: int, per_epoch: int = 1) -> Float[Array, "T K"]:
    """Per-epoch placeholder "samples" ([T, per_epoch] zeros) for ``EpochInput.samples``."""
    return jnp.zeros((n_epochs, per_epoch))


class GnssOnlySystem(AbstractNavSystem):
    """Receiver-only motion model for PPP (static, random-walk or constant-velocity kinematic)."""

    model: str = eqx.field(static=True, default="static")
    pos_psd_m2_s: float = 100.0**2  # S002 §5.2.3: random walk "(100 m/sqrt(s))"
    accel_psd_m2_s3: float = 1.0  # chosen: 1 m/s^2/sqrt(Hz) white acceleration (land vehicle)
    static_psd_m2_s: float = 0.0  # S002 §5.2.2: random constant (no process noise)

    def __check_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown GNSS-only model {self.model!r}; expected one of {MODELS}")

    @property
    def layout(self) -> StateLayout:
        return POS_VEL_LAYOUT if self.model == "constant_velocity" else POS_LAYOUT

    def propagate(
        self, nav: GnssNav, sensors, samples, dt: Float[ArrayLike, ""]
    ) -> tuple[GnssNav, Float[Array, "3"]]:
        """Static / random walk: the position is kept. Constant velocity: llh += D^-1 v T."""
        if self.model != "constant_velocity":
            return nav, jnp.zeros(3)
        span = dt * samples.shape[0]
        llh = nav.llh + geodesy.llh_rate_matrix(nav.llh) @ nav.vel_enu * span
        return GnssNav(llh, nav.vel_enu), jnp.zeros(3)

    def dynamics(
        self, nav: GnssNav, mean_inputs, sensors
    ) -> tuple[Float[Array, "n n"], Float[Array, "n q"], Float[Array, "q q"]]:
        """Continuous (F, G, Qc). Position PSD q [m^2/s] -> (q / R_M^2, q / (R_N cos lat)^2, q).

        Constant velocity: d(dllh)/dt = D^-1 dv (the small d(D^-1 v)/dllh term neglected),
        d(dv)/dt = w_a with PSD ``accel_psd_m2_s3`` per ENU axis.
        """
        n = self.layout.size
        scale = geodesy.metres_per_radian(nav.llh)
        F = jnp.zeros((n, n))
        if self.model == "constant_velocity":
            F = F.at[self.layout.sl("pos"), self.layout.sl("vel")].set(
                geodesy.llh_rate_matrix(nav.llh)
            )
            G = jnp.zeros((n, 3)).at[self.layout.sl("vel"), :].set(jnp.eye(3))
            Qc = jnp.eye(3) * self.accel_psd_m2_s3
            return F, G, Qc
        q = self.pos_psd_m2_s if self.model == "random_walk" else self.static_psd_m2_s
        G = jnp.eye(n)
        Qc = jnp.diag(q / scale**2)
        return F, G, Qc

    def antenna(self, nav: GnssNav, mean_inputs, sensors, layout_full: StateLayout) -> Receiver:
        """Antenna = the estimated point; J_pos = d(ECEF)/d(llh) (S000 eq 4.66), J_vel = C_l^e."""
        n = layout_full.size
        C_l_e = geodesy.C_l_e(nav.llh[0], nav.llh[1])
        J_pos = (
            jnp.zeros((3, n))
            .at[:, layout_full.sl("pos")]
            .set(geodesy.llh_to_ecef_jacobian(nav.llh))
        )
        J_vel = jnp.zeros((3, n))
        if layout_full.has("vel"):
            J_vel = J_vel.at[:, layout_full.sl("vel")].set(C_l_e)
        return Receiver(geodesy.llh_to_ecef(nav.llh), C_l_e @ nav.vel_enu, nav.llh, J_pos, J_vel)

    def feedback(self, nav: GnssNav, sensors, dx: Float[Array, " n"], layout_full: StateLayout):
        """Closed loop: llh <- llh - dx_pos, vel <- vel - dx_vel."""
        llh = nav.llh - dx[layout_full.sl("pos")]
        vel = nav.vel_enu
        if layout_full.has("vel"):
            vel = vel - dx[layout_full.sl("vel")]
        return GnssNav(llh, vel), sensors

    def predict_sensors(self, sensors, dt):
        return sensors  # no sensors

    def initial_std(self, nav: GnssNav, sig: NavSigmas) -> Float[Array, " n"]:
        std = jnp.zeros(self.layout.size)
        std = std.at[self.layout.sl("pos")].set(sig.pos_m / geodesy.metres_per_radian(nav.llh))
        if self.layout.has("vel"):
            std = std.at[self.layout.sl("vel")].set(sig.vel_m_s)
        return std

    def zero_sensors(self):
        return jnp.zeros(0)

    def idle_inputs(self, nav):
        return jnp.zeros(3)

    def llh(self, nav: GnssNav):
        return nav.llh

    def vel_enu(self, nav: GnssNav):
        return nav.vel_enu

    def euler(self, nav: GnssNav):
        return jnp.zeros(3)


def initial_nav(
    pos_ecef: Float[ArrayLike, "3"], vel_enu: Float[ArrayLike, "3"] | None = None
) -> GnssNav:
    """A GnssNav at an ECEF position (e.g. a least-squares SPP solution)."""
    llh = geodesy.ecef_to_llh(jnp.asarray(pos_ecef, dtype=jnp.float64))
    vel = jnp.zeros(3) if vel_enu is None else jnp.asarray(vel_enu, dtype=jnp.float64)
    return GnssNav(llh, vel)
