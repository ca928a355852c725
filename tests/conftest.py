"""Test-session set-up: thread counts, JAX's persistent compilation cache, xdist work units.

The suite runs on two xdist workers (pyproject's addopts: ``-n 2 --dist loadgroup``). Each test
module is one work unit (its module-scoped fixtures, e.g. a simulated drive, are built once), except
the tests marked ``heavy`` (they start subprocesses or measure time or memory), which form one
unit of their own, so that no two of them ever run at the same time. Units start longest first.
"""

import importlib
import os
import sys
import tempfile
from pathlib import Path

import pytest

# Before any test module loads scipy's OpenBLAS (jaxlib's LAPACK): see jaxnav/__init__.py.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# JAX's persistent compilation cache, shared by both xdist workers and every subprocess a test
# starts (they inherit the environment). It lives outside the project (.ci/run deletes .venv, a
# clean checkout has no build products) and is only a cache: a cold one, as on a new machine,
# gives the same results, only slower. JAX_COMPILATION_CACHE_DIR chooses another folder.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "jaxnav" / "jax-compilation-cache")
)
# Cache every compilation of 0.5 s or more (JAX's default of 1 s misses many of the medium-size
# scans the tests compile). Caching every one, however small, so that a cold run's two workers
# share more, was measured no faster (22.9 vs 21.5 min, within the machine's drift).
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

# XLA:CPU's older fusion emitters for the whole session and its subprocesses: they compile our
# kernels in 0.65-0.72x the time (benchmarks/xla_emitters.py) and compilation is most of the
# suite's time; results differ from XLA's default emitters by rounding only (the goldens were
# recorded with this setting). jaxnav applies it only on the jaxlib it was measured on.
os.environ.setdefault("JAXNAV_XLA_FUSION_EMITTERS", "0")

# jaxtyping shape annotations of jaxnav.filter, .gnss and .ins checked with beartype on every call
# (installed before anything imports jaxnav; tests/test_shapes.py); JAXNAV_TYPECHECK=0 skips it.
TYPECHECKED_PACKAGES = ("jaxnav.filter", "jaxnav.gnss", "jaxnav.ins")
if os.environ.get("JAXNAV_TYPECHECK", "1") != "0":
    import jaxtyping

    if any(m.startswith(TYPECHECKED_PACKAGES) for m in sys.modules):
        raise RuntimeError("jaxnav was imported before tests/conftest.py installed the type checks")
    jaxtyping.install_import_hook(list(TYPECHECKED_PACKAGES), "beartype.beartype")

# The CLI's sweeps in this process (default --workers: every core). The suite already runs on
# two xdist workers, so Dask worker processes would only oversubscribe the cores; the Dask path
# is tested on its own in tests/test_parallel.py.
os.environ.setdefault("JAXNAV_WORKERS", "1")
# The prepared-observation cache of `jaxnav ppp` (apps/prep_cache.py) in a folder of this run,
# not the user's ~/.cache: a test never reads an entry another run (other code) wrote.
os.environ["JAXNAV_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxnav-test-cache-")

HEAVY_GROUP = "heavy"
# Work units that take longest (docs/testing.md, measured on 2 cores), started first so that
# neither worker is left with a long unit at the end; the rest keep their collection order.
LONGEST_FIRST = (
    HEAVY_GROUP,
    "test_exp_seed001_002",
    "test_tight",
    "test_cascade",
    "test_consistency",
    "test_exp_seed000_004",
    "test_lc_real",
    "test_replay",
    "test_factory",
    "test_scenario",
    "test_report",
    "test_tight_vs_loose",
    "test_ppp_rows",
    "test_tutorial",
    "test_loose",
    "test_ppp_real",
)


def _group(item) -> str:
    return HEAVY_GROUP if item.get_closest_marker("heavy") else item.path.stem


def pytest_itemcollected(item):
    """Each test's xdist group: its module, or ``heavy`` (set as it is collected, before any
    ``pytest_collection_modifyitems``, where xdist turns the groups into work units)."""
    item.add_marker(pytest.mark.xdist_group(_group(item)))


def pytest_collection_modifyitems(session, config, items):
    """The longest groups first (a stable sort: each module keeps its order)."""
    rank = {g: i for i, g in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(_group(item), len(rank)))


@pytest.hookimpl(optionalhook=True)  # an xdist hook: the controller sees each worker's ids
def pytest_xdist_node_collection_finished(node, ids):
    """Stop if the groups were lost: pytest 9.2 with xdist 3.8 drops them without a word, and
    every module fixture is then built on both workers (see pyproject's pytest pin)."""
    if node.config.getoption("dist") == "loadgroup" and ids and not any("@" in i for i in ids):
        pytest.exit("xdist --dist loadgroup did not group the tests (a pytest / pytest-xdist "
                    "incompatibility, see pyproject's pytest pin); use pytest < 9.2 or -n 0",
                    returncode=pytest.ExitCode.USAGE_ERROR)


EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


@pytest.fixture(scope="session")
def run_quick_experiment():
    """``experiments/<name>.py --quick --out DIR`` in this process, through the script's
    ``main(argv)``: its compiled functions stay in this worker, the import costs nothing. Returns
    the text of ``DIR/report.md``."""

    def run(name: str, out: Path) -> str:
        if str(EXPERIMENTS) not in sys.path:
            sys.path.insert(0, str(EXPERIMENTS))
        module = importlib.import_module(name)
        assert module.main(["--quick", "--out", str(out)]) == 0, name
        report = out / "report.md"
        assert report.is_file(), name
        return report.read_text()

    return run


sys.path.insert(0, str(Path(__file__).with_name("goldens")))
import outputs as _golden_outputs  # noqa: E402  (tests/goldens/outputs.py)


@pytest.fixture(scope="session")
def goldens():
    """``tests/goldens/outputs.py``: ``goldens.check(name, goldens.numbers_in(folder))``."""
    return _golden_outputs
