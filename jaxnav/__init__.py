"""jaxnav: JAX-vectorised GNSS PPP / INS / RISS integration for Monte-Carlo outage studies."""

import jax

# GNSS ranges are ~2e7 m and cm-level work needs float64: enable it before any array is made.
jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
