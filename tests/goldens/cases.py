"""Golden filter runs: every PPP mode and variant on one short simulated drive (issue 15).

Each case runs the tight filter over a 3-minute simulated drive (60 s static start, then
moving), one noise realisation, and keeps its per-epoch solution and diagnostics. The arrays were
recorded from main before the PPP-mode refactor (``python tests/goldens/cases.py`` rewrites
``ppp_modes.npz``); ``tests/test_goldens.py`` checks that the code still gives them. Rewrite the
file only for a change meant to alter the numbers, and say by how much and why in the commit.

Rewritten once (2026-12-02) when the test session switched XLA:CPU to its older fusion
emitters (tests/conftest.py, benchmarks/xla_emitters.py; running this file as a script does
the same): the same computations compiled another way differ by rounding only. Positions moved
by at most 26 nm; velocities by 3e-10, attitude 8e-10 and NIS 2.4e-8 of their largest values
(above the 1e-9 criterion, hence the rewrite); integer fields not at all. The arrays before
that were bit-identical through the PPP-mode refactor.

Rewritten again (2026-12-02, issue 16) for changes meant to alter the numbers: Gauss-Markov
sensor estimates decay with their tau (defect 4) and the RISS output covariance is J P J^T
(the re-derived velocity). Positions moved by at most 2.0 cm (sdf_code/riss9), velocities
5e-4, attitude 3e-4, NIS 1.3e-2 and the final P_nav 2.9e-2 of their largest values; integer
fields (satellites used and gated) not at all.

Rewritten (2026-12-02 evening, issue 16) for the stochastic model of time-correlated errors
(white-equivalent multipath weights, products as ambiguity random walks, sf_code's ionosphere
residual state, sdf_code weighted as raw code): positions moved by at most 3.3 cm
(sdf_code/riss9), velocities 3e-3 and attitude 1e-2 of their largest values, NIS up to 0.35,
the position sigmas up to 1.4x (per-epoch diagonal) and 9.7x (final P, sdf_code: its smoothed
code is no longer weighted below the raw code's variance); integer fields not at all.

Rewritten (2026-12-04, issue 16), the INS15 case only (the others' arrays kept byte for byte):
INS15's unmodelled scale factors drive its bias states (``ins.errors.unmodelled_scale_psd``).
float_ppp/ins15 moved by at most 2.0 cm in height, 1.8 cm/s in velocity, 7.4 mrad in
attitude, 1.2 in NIS and 3.7e-5 of the largest value in P_nav (per-epoch diagonal);
satellites used and gated not at all.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

# the test session's code generation (tests/conftest.py), also when this file runs as a script
os.environ.setdefault("JAXNAV_XLA_FUSION_EMITTERS", "0")

import jaxnav  # noqa: E402, F401  (float64)
from jaxnav.filter import tight
from jaxnav.study.factory import SimFactory

GOLDEN = Path(__file__).with_name("ppp_modes.npz")
DRIVE = {"duration_s": 180.0, "drive_style": "mixed", "drive_seed": 3}
SEED = 5

#: case -> (scenario additions, mode, system, PppConfig replacements)
CASES = {
    "sf_code/riss9": ({}, "sf_code", "riss9", {}),
    "df_code/riss9": ({}, "df_code", "riss9", {}),
    "sdf_code/riss9": ({}, "sdf_code", "riss9", {}),
    "float_ppp/riss9": ({}, "float_ppp", "riss9", {}),
    "ic_ppp/riss9": ({}, "ic_ppp", "riss9", {}),
    "ic_ppp-epoch/riss9": ({}, "ic_ppp", "riss9", {"iono_constraint": "epoch"}),
    "float_ppp/riss": ({}, "float_ppp", "riss", {}),
    "float_ppp/ins15": ({}, "float_ppp", "ins15", {}),
    "float_ppp-bssd/riss9": ({"bssd": True}, "float_ppp", "riss9", {}),
    "df_code-bssd/riss9": ({"bssd": True}, "df_code", "riss9", {}),
    "float_ppp-gre/riss9": ({"constellations": ["gps", "glonass", "galileo"]}, "float_ppp",
                            "riss9", {}),
    # Added with the mode (recorded from its first version, 2026-12-02), for later refactors.
    "sf_ppp/riss9": ({}, "sf_ppp", "riss9", {}),
}
FIELDS = ("llh", "vel_enu", "euler", "P_nav_diag", "P_nav_final", "nis", "dof", "used_by_kind",
          "gated_by_kind", "clock_bias_m")

_FACTORIES: dict[str, SimFactory] = {}
_RUN = eqx.filter_jit(tight.run)


def run_case(name: str) -> dict[str, np.ndarray]:
    """The per-epoch outputs of one case, as numpy arrays named by ``FIELDS``."""
    extra, mode, system, replace = CASES[name]
    key = repr(sorted(extra.items()))
    if key not in _FACTORIES:
        _FACTORIES[key] = SimFactory({**DRIVE, **extra})
    prob = _FACTORIES[key].build(None, mode, system, SEED)
    tf = prob.tf
    if replace:
        tf = eqx.tree_at(lambda f: f.cfg, tf, dataclasses.replace(tf.cfg, **replace))
    _, out = _RUN(tf, prob.carry0, prob.inputs)
    out = jax.device_get(out)
    arrays = {f: np.asarray(getattr(out, f)) for f in FIELDS if hasattr(out, f)}
    P = np.asarray(out.P_nav)  # the diagonal per epoch and the whole matrix at the end
    arrays["P_nav_diag"], arrays["P_nav_final"] = np.diagonal(P, axis1=1, axis2=2), P[-1]
    return arrays


def main() -> int:
    arrays = {}
    for name in CASES:
        for field, value in run_case(name).items():
            arrays[f"{name}:{field}"] = value
        print(name, "final llh", arrays[f"{name}:llh"][-1])
    np.savez_compressed(GOLDEN, **arrays)
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
