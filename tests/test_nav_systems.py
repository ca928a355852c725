"""The navigation-system interface: every system implements ``AbstractNavSystem``; one that
leaves a method out fails when its class is defined."""

import jax.numpy as jnp
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav.core.states import StateLayout
from jaxnav.filter import ppp_only, systems

SYSTEMS = [systems.RissSystem(), systems.InsSystem(), ppp_only.GnssOnlySystem()]
INTERFACE = sorted(k for k in dir(systems.AbstractNavSystem)
                   if getattr(getattr(systems.AbstractNavSystem, k), "__isabstractmethod__",
                              False))


def test_the_interface_is_what_the_filters_call():
    assert INTERFACE == ["antenna", "dynamics", "euler", "feedback", "idle_inputs",
                         "initial_std", "layout", "llh", "propagate", "vel_enu", "zero_sensors"]


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: type(s).__name__)
def test_every_system_implements_the_interface(system):
    assert isinstance(system, systems.AbstractNavSystem)
    assert isinstance(system.layout, StateLayout) and system.layout.has("pos")


def test_a_system_missing_a_method_fails_at_class_definition():
    with pytest.raises(TypeError, match="HalfSystem does not implement euler"):

        class HalfSystem(systems.AbstractNavSystem):
            layout = StateLayout((("pos", 3),))

            def propagate(self, nav, sensors, samples, dt):
                return nav, None

            def dynamics(self, nav, mean_inputs, sensors):
                return None

            def antenna(self, nav, mean_inputs, sensors, layout_full):
                return None

            def feedback(self, nav, sensors, dx, layout_full):
                return nav, sensors

            def initial_std(self, nav, sig):
                return jnp.ones(3)

            def zero_sensors(self):
                return None

            def idle_inputs(self, nav):
                return None

            def llh(self, nav):
                return nav

            def vel_enu(self, nav):
                return jnp.zeros(3)


def test_a_system_without_sensors_refuses_a_static_calibration():
    g = ppp_only.GnssOnlySystem()
    with pytest.raises(TypeError, match="GnssOnlySystem has no sensors"):
        g.calibrate_static(None, None, 1.0)
