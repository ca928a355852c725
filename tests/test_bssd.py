"""Between-satellite single differences (S004) through the tight filter (issue 16, defect 1).

Theory: differencing every row against a reference satellite eliminates exactly the receiver
clock (code, phase) and its drift (Doppler). For a code-only mode with one clock and one drift,
BSSD is therefore the undifferenced (UD) filter with an unconstrained clock: same positions.
For float PPP the UD filter is slightly stronger (one clock ties its code and phase; the
differences drop the phase-minus-code level of the reference), so the two agree closely but
not exactly; what must hold there is that the reference satellite's ambiguity is carried like
every other (it used to restart every epoch: its phase has no row of its own).
The simulator has no receiver code or phase biases.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401  (float64)
from jaxnav import geodesy
from jaxnav.filter import tight
from jaxnav.study.factory import SimFactory

DRIVE = {"duration_s": 240.0, "drive_style": "urban", "drive_seed": 1}
SEED = 2
# Clock "unconstrained" in UD: variance and random-walk PSD of 1e6 m^2 (1 km); its prior then
# moves a metre-level solution by ~ 0.25 m^2 / 1e6 m^2 relative, i.e. < 1e-5 m.
FREE_CLOCK = {"clock_bias": 1e6, "clock_drift": 1e4}
_RUN = eqx.filter_jit(tight.run)


@pytest.fixture(scope="module")
def factories():
    return {b: SimFactory({**DRIVE, "bssd": b}) for b in (False, True)}


def _run(factory, mode, bssd):
    prob = factory.build(None, mode, "riss9", SEED)
    tf, carry0 = prob.tf, prob.carry0
    # the same filter logic for both: no gate, pre-fit or post-fit test deciding differently
    rep = dict(postfit_sigma=None, gate_chi2=float("inf"), prefit_code_m=1e9)
    if not bssd:
        rep.update(clock_bias_psd_m2_s=FREE_CLOCK["clock_bias"],
                   clock_drift_psd_m2_s3=FREE_CLOCK["clock_drift"])
        P = carry0.P
        for name, var in FREE_CLOCK.items():
            i = tf.layout.i(name)
            P = P.at[i, :].set(0.0).at[:, i].set(0.0).at[i, i].set(var)
        carry0 = carry0._replace(P=P)
    tf = eqx.tree_at(lambda t: t.cfg, tf, dataclasses.replace(tf.cfg, **rep))
    return _RUN(tf, carry0, prob.inputs)


def _enu_diff_m(a, b):
    m = np.asarray(geodesy.metres_per_radian(jnp.asarray(b[0])))
    return (a - b) * np.array([m[0], m[1], 1.0])


def test_code_bssd_is_ud_with_a_free_clock(factories):
    (_, ud), (_, sd) = (_run(factories[b], "df_code", b) for b in (False, True))
    d = _enu_diff_m(np.asarray(sd.llh), np.asarray(ud.llh))
    print(f"\nmax |BSSD - UD| df_code: {np.abs(d).max(axis=0)} m")
    assert np.abs(d).max() < 1e-4  # 10x the clock prior's effect above
    np.testing.assert_array_equal(np.asarray(sd.n_sat), np.asarray(ud.n_sat))
    # one clock and one drift eliminated: 2 rows fewer (code, Doppler) at every epoch
    np.testing.assert_array_equal(np.asarray(sd.dof), np.asarray(ud.dof) - 2)


def test_float_ppp_bssd_carries_the_reference_ambiguity(factories):
    (c_ud, ud), (c_sd, sd) = (_run(factories[b], "float_ppp", b) for b in (False, True))
    # the reference satellite counts as used and its ambiguity as tracked, as in UD
    np.testing.assert_array_equal(np.asarray(sd.n_sat), np.asarray(ud.n_sat))
    np.testing.assert_array_equal(np.asarray(c_sd.tracked), np.asarray(c_ud.tracked))
    d = _enu_diff_m(np.asarray(sd.llh), np.asarray(ud.llh))
    print(f"\nmax |BSSD - UD| float_ppp: {np.abs(d).max(axis=0)} m (not 0: module docstring)")
