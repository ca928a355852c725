"""The readers under seeded fuzzing (tests/fuzz/harness.py): no foreign exception, no hang, no
silent change of a checkable kind. Quick form here (a few hundred cases in all); the full form,
200 cases per reader, is ``python -m pytest -m full tests/fuzz`` or
``python tests/fuzz/harness.py --cases 200`` (counts in docs/reliability.md)."""

import importlib.util
from pathlib import Path

import pytest

_HARNESS = Path(__file__).with_name("harness.py")
_spec = importlib.util.spec_from_file_location("fuzz_harness", _HARNESS)
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)

QUICK = {"sp3": 40, "clk": 40, "nav": 30, "pos": 40, "imu": 40, "ubx": 15, "obs": 30,
         "study": 30}


def _run(name, n, tmp_path, seed):
    if name != "study" and not harness.DATA.is_dir():  # the study TOML is the harness's own
        pytest.skip(f"the shared data folder {harness.DATA} is absent")
    cases = harness.run_reader(harness.READERS[name], n, tmp_path, seed=seed)
    defects = [c for c in cases if c.outcome in harness.DEFECTS]
    assert not defects, "\n".join(f"#{c.index} {c.mutation}: {c.outcome}: {c.detail}"
                                  for c in defects)
    # the harness can fail: most damage must be seen (refused or warned), not pass as unchanged
    seen = sum(c.outcome in ("refused", "warned") for c in cases)
    assert seen >= n // 2, harness.table(cases)


@pytest.mark.parametrize("name", list(QUICK))
def test_fuzz_quick(name, tmp_path):
    _run(name, QUICK[name], tmp_path, seed=1)


@pytest.mark.full
@pytest.mark.parametrize("name", list(QUICK))
def test_fuzz_full(name, tmp_path):
    _run(name, 200, tmp_path, seed=2)
