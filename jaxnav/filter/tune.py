"""Noise parameters by maximum likelihood of the innovations (issue 20).

A Kalman filter with the right model makes its innovations nu_k ~ N(0, S_k), independent over
the epochs, so the data's likelihood factorises (the prediction-error decomposition, Schweppe
1965) and

    NLL(theta) = 1/2 sum_k [ nu_k^T S_k^-1 nu_k + log det S_k + m_k log(2 pi) ]

over the epochs k and their used rows m_k (masked and gated rows excluded). Every filter of
jaxnav reports both terms per epoch (``EpochOutput.nis`` and ``.logdet``, from the update's own
Cholesky factor), and the filters are pure JAX functions of their parameters, so the NLL of a
whole run is differentiated through the scan by ``jax.value_and_grad``.

``fit`` minimises a user's NLL over positive parameters in log space (theta = exp(u): positive
by construction, and a factor-of-2 error is the same distance from both sides) with SciPy's
L-BFGS-B driving one compiled value-and-gradient of the run, from several starts, and reports
each value with the uncertainty of the inverse Hessian of the NLL in u (the Cramer-Rao bound of
the log-parameter: sigma of ln theta, i.e. a multiplicative 1-sigma factor exp(sigma)). A
parameter is *not identified* when that factor exceeds ``IDENTIFIED_FACTOR`` or the Hessian is
not positive definite in its direction: the data cannot tell its value, and it is reported as
such, not as if known.

Discrete decisions inside a filter (innovation gates, post-fit rejections, the standstill
detector) are piecewise constant in theta: they add nothing to the gradient, but a step that
changes one makes the NLL jump (a gated row leaves its terms). The callers here fit with
configurations whose decisions do not depend on theta (the car's loose filter has no gate and
its detector reads the IMU only; the simulation checks switch the gates off); ``fit`` reports
the NLL at the start and end so a jump shows.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike, Float, Int

#: A parameter counts as identified when its 1-sigma multiplicative uncertainty exp(sigma_u)
#: is below this (chosen: the data pins it within a factor of 1.5 at one sigma; a datasheet
#: figure is rarely better than that).
IDENTIFIED_FACTOR = 1.5


def innovation_nll(nis: Float[Array, "*T"], logdet: Float[Array, "*T"],
                   dof: Int[Array, "*T"]) -> Float[Array, ""]:
    """NLL = 1/2 sum (nis + logdet + dof log 2 pi) over every epoch (and run) given."""
    return 0.5 * jnp.sum(nis + logdet + dof * math.log(2.0 * math.pi))


@dataclasses.dataclass(frozen=True)
class FitResult:
    """A maximum-likelihood fit in log space (module docstring)."""

    names: tuple[str, ...]
    value: np.ndarray  # fitted parameters (natural units)
    start: np.ndarray  # the caller's starting values
    sigma_log: np.ndarray  # 1-sigma of ln(value) from the inverse Hessian (inf: not identified)
    identified: np.ndarray  # bool per parameter
    nll: float  # NLL at the fit
    nll_start: float  # NLL at the caller's start
    steps: int  # L-BFGS iterations of the best start
    evaluations: int  # filter runs (value and gradient) of the whole fit
    converged: bool
    starts: tuple[tuple[float, float], ...]  # (start factor, final NLL) per start
    hessian_eigvals: np.ndarray  # of the NLL in ln(theta), ascending

    def factor(self) -> np.ndarray:
        """Multiplicative 1-sigma uncertainty exp(sigma_log) of each value."""
        return np.exp(self.sigma_log)

    def table(self) -> str:
        """One line per parameter: name, start, fit, x/ factor, identified."""
        lines = [f"{'parameter':44s} {'start':>12s} {'fitted':>12s} {'1-sigma x/':>10s}"]
        for i, name in enumerate(self.names):
            f = self.factor()[i]
            # a flat direction's sigma overflows exp(): shown as "> 1e6", not 140 digits
            fac = f"{f:10.3f}" if f < 1e6 else f"{'> 1e6' if np.isfinite(f) else 'inf':>10s}"
            note = "" if self.identified[i] else "  not identified by these data"
            lines.append(f"{name:44s} {self.start[i]:12.5g} {self.value[i]:12.5g} {fac}{note}")
        return "\n".join(lines)


def _lbfgs(value_and_grad: Callable, u0: np.ndarray, max_steps: int, rtol: float):
    """Minimise from u0 with SciPy's L-BFGS-B (the host drives one compiled value-and-gradient
    of the whole filter run per evaluation); stop when an iteration lowers the NLL by less than
    ``rtol`` relative, or after ``max_steps`` iterations."""

    def fun(u):
        value, grad = value_and_grad(jnp.asarray(u))
        value = float(value)
        if not np.isfinite(value):  # a filter that diverged: tell the line search to back off
            return 1e300, np.zeros_like(u)
        return value, np.asarray(grad, np.float64)

    r = scipy.optimize.minimize(fun, u0, jac=True, method="L-BFGS-B",
                                options={"maxiter": max_steps, "ftol": rtol, "gtol": 1e-6})
    return r.x, float(r.fun), int(r.nit), bool(r.success), int(r.nfev)


def _hessian(value_and_grad: Callable, u: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """d^2 NLL / du^2 by central differences of the exact gradient (2p gradient evaluations,
    no second compilation). h = 1e-3 in ln theta: truncation O(h^2) ~ 1e-6 relative, while the
    filter's roundoff (~1e-7 of the NLL, tests/test_tune.py) stays far below the step."""
    p = u.size
    H = np.zeros((p, p))
    for i in range(p):
        e = np.zeros(p)
        e[i] = h
        gp = np.asarray(value_and_grad(jnp.asarray(u + e))[1])
        gm = np.asarray(value_and_grad(jnp.asarray(u - e))[1])
        H[:, i] = (gp - gm) / (2.0 * h)
    return 0.5 * (H + H.T)


def fit(
    nll: Callable[[Float[Array, " p"]], Float[Array, ""]],
    theta0: Float[ArrayLike, " p"],
    names: Sequence[str],
    *,
    start_factors: Sequence[float] = (1.0, 0.5, 2.0),
    max_steps: int = 60,
    rtol: float = 1e-8,
) -> FitResult:
    """Maximum-likelihood parameters: minimise ``nll(theta)`` over theta > 0 (module docstring).

    ``nll`` maps the natural parameter vector to the NLL (``innovation_nll`` of a filter run).
    L-BFGS runs in u = ln theta from theta0 * each of ``start_factors``; the best end point is
    the fit, its uncertainty Cov(u) = (d^2 NLL / du^2)^-1 (the Hessian by central differences
    of the gradient)."""
    theta0 = np.asarray(theta0, np.float64)
    if theta0.shape != (len(names),) or not np.all(theta0 > 0):
        raise ValueError(f"theta0 must hold one positive value per name, got {theta0}")

    def f(u):
        return nll(jnp.exp(u))

    value_and_grad = jax.jit(jax.value_and_grad(f))
    u_start = np.log(theta0)
    nll_start = float(value_and_grad(jnp.asarray(u_start))[0])
    runs = []
    for factor in start_factors:
        runs.append((factor, *_lbfgs(value_and_grad, u_start + math.log(factor), max_steps, rtol)))
    finite = [r for r in runs if r[2] < 1e299]
    if not finite:
        raise FloatingPointError("every start of the fit ended in a non-finite NLL")
    factor, u, value, steps, ok, _ = min(finite, key=lambda r: r[2])
    H = _hessian(value_and_grad, u)
    eig, vec = np.linalg.eigh(H)
    # Cov(u) on the positive-curvature subspace; a direction without curvature (eig <= a
    # roundoff floor) has no information: its parameters get an infinite sigma
    floor = 1e-9 * max(np.max(np.abs(eig)), 1.0)
    flat = eig <= floor
    cov = (vec[:, ~flat] / eig[~flat]) @ vec[:, ~flat].T
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    touches_flat = (np.any(np.abs(vec[:, flat]) > 1e-3, axis=1) if np.any(flat)
                    else np.zeros(len(names), bool))
    sigma = np.where(touches_flat, np.inf, sigma)
    return FitResult(
        names=tuple(names),
        value=np.exp(np.asarray(u)),
        start=theta0,
        sigma_log=sigma,
        identified=np.exp(sigma) < IDENTIFIED_FACTOR,
        nll=value,
        nll_start=nll_start,
        steps=steps,
        converged=ok,
        starts=tuple((r[0], r[2]) for r in runs),
        evaluations=sum(r[5] for r in runs) + 2 * len(names) + 1,
        hessian_eigvals=eig,
    )
