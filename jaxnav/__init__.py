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
