"""Filter consistency in the realistic simulator (every default error source on), issue 16.

``tests/test_consistency.py`` checks the filters' algebra in a world that matches their white
models. This file checks the stochastic model against the simulator's correlated errors: the
30-s code and carrier multipath, the hour-long product residuals and the half-hour ionosphere
model residual. Three cells of ``benchmarks/consistency.py`` (16 runs x 420 s, epochs after
300 s), each of whose position ANEES must lie in the two-sided 95 % band of chi2(16 x 3) / 16
(1.92-4.31):

- float_ppp / RISS, dominated by the carrier's multipath and products (31.3 before the
  white-equivalent multipath weights and the ambiguities' random walk, 3.0 after);
- sf_code / INS15, dominated by the Klobuchar residual (21.3 before sf_code's ionosphere
  residual state, 2.0 after);
- float_ppp / lc_ins15 with ``lc_fix_errors = "correlated"``, loose coupling: the PPP
  solution's correlated error (16.9 while the LC filter weighted each fix as independent, the
  factory's default, 2.8 with its fix-error states).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from jaxnav.study.factory import SimFactory

_PATH = Path(__file__).resolve().parent.parent / "benchmarks" / "consistency.py"
_spec = importlib.util.spec_from_file_location("consistency_bench", _PATH)
cons = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = cons
_spec.loader.exec_module(cons)

N_RUNS = 16
DURATION_S = 420.0
SETTLE_S = 300.0


@pytest.mark.slow
@pytest.mark.parametrize(("mode", "system"), [("float_ppp", "riss"), ("sf_code", "ins15"),
                                             ("float_ppp", "lc_ins15")])
def test_position_anees_in_band_with_every_error_source(mode, system):
    factory = SimFactory({"duration_s": DURATION_S, "lc_fix_errors": "correlated"})
    fig = cons.cell(factory, mode, system, N_RUNS, SETTLE_S)
    print(f"\n{mode}/{system}: ANEES position {fig['anees_pos']:.2f} "
          f"(band {fig['lo']:.2f}-{fig['hi']:.2f}), velocity {fig['anees_vel']:.2f}")
    assert fig["runs"] == N_RUNS
    assert fig["lo"] <= fig["anees_pos"] <= fig["hi"]
