"""jaxnav: JAX-vectorised GNSS PPP / INS / RISS integration for Monte-Carlo outage studies."""

import os

# Single-threaded Eigen inside XLA:CPU. Our kernels are small matrices inside long scans, which
# gain nothing from Eigen's intra-op thread pool; with it, runs on this 2-core machine stalled
# intermittently (every thread parked on a futex, the caller waiting for a result that never
# came). Appended to any user XLA_FLAGS; must precede the CPU backend's creation.
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false"
    ).strip()


def _jaxlib_minor() -> tuple[int, int] | None:
    from importlib import metadata

    try:
        major, minor = metadata.version("jaxlib").split(".")[:2]
        return int(major), int(minor)
    except (metadata.PackageNotFoundError, ValueError):
        return None


# JAXNAV_XLA_FUSION_EMITTERS=0: XLA:CPU's older (LLVM IR) fusion emitters instead of the MLIR
# ones. They compile our filters and the simulator in 0.65-0.72x the time; run times are mixed
# (RISS filter 1.11x, INS15 0.98x, simulator 0.87x; benchmarks/xla_emitters.py, RESULTS.md), so
# XLA's default stays the default and compile-bound work opts in (the test suite does, in
# tests/conftest.py). Only on the jaxlib release where this was measured: the switch is being
# removed from XLA, and an unknown flag in XLA_FLAGS is a fatal error. A user's own setting of
# the flag in XLA_FLAGS wins.
OLDER_EMITTERS_FLAG = "--xla_cpu_use_fusion_emitters=false"
if (
    os.environ.get("JAXNAV_XLA_FUSION_EMITTERS") == "0"
    and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", "")
):
    if _jaxlib_minor() == (0, 10):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + OLDER_EMITTERS_FLAG
                                   ).strip()
    else:
        import warnings

        warnings.warn("JAXNAV_XLA_FUSION_EMITTERS=0 ignored: measured on jaxlib 0.10 only "
                      "(benchmarks/xla_emitters.py); XLA's default emitters are used",
                      stacklevel=2)

# Single-threaded OpenBLAS: jaxlib's CPU Cholesky / triangular solves call scipy's OpenBLAS,
# which splits each small per-scenario call over all cores. On a busy machine every call then
# waits for the descheduled helper thread: measured 44-53 s vs 0.13-0.18 s for 16 scenarios x 40
# epochs at load 15 (benchmarks/README.md). Must precede the first load of OpenBLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _single_thread_loaded_openblas():
    """If scipy (whose OpenBLAS jaxlib uses) was imported before jaxnav, the variable above
    came too late: set the loaded library's thread count directly (at load 0 a test that
    imported scipy first deadlocked with every thread parked)."""
    import sys

    if "scipy" not in sys.modules or os.environ["OPENBLAS_NUM_THREADS"] != "1":
        return
    import ctypes
    import glob

    libs = os.path.join(os.path.dirname(os.path.dirname(sys.modules["scipy"].__file__)),
                        "scipy.libs", "libscipy_openblas*.so")
    for path in glob.glob(libs):
        try:
            ctypes.CDLL(path).scipy_openblas_set_num_threads(1)
        except (OSError, AttributeError):
            pass


_single_thread_loaded_openblas()

import jax  # noqa: E402

# GNSS ranges are ~2e7 m and cm-level work needs float64: enable it before any array is made.
jax.config.update("jax_enable_x64", True)
# Synchronous dispatch on the CPU: with asynchronous dispatch, sweeps on this 2-core machine
# stalled intermittently (about 1 run in 10) in a result transfer with no CPU in use, waiting on
# a computation that never completed. The computations are large jitted scans, so running them
# one at a time costs nothing measurable.
if os.environ.get("JAXNAV_CPU_ASYNC") != "1":
    jax.config.update("jax_cpu_enable_async_dispatch", False)

__version__ = "0.1.0"
