"""Rauch-Tung-Striebel fixed-interval smoothing for the closed-loop error-state filters.

Linear-Gaussian form (Rauch, Tung and Striebel 1965; Särkkä 2013, sec. 8.2), epoch k from the
last one backwards, with Phi_{k+1} the transition from epoch k's posterior to epoch k+1's prior:

    A_k = P_k+ Phi_{k+1}^T (P_{k+1}-)^-1
    x_k^s = x_k+ + A_k (x_{k+1}^s - x_{k+1}-)
    P_k^s = P_k+ + A_k (P_{k+1}^s - P_{k+1}-) A_k^T

Error-state form. The filters feed every correction back (``x_hat <- x_hat - dx_hat``), so after
epoch k's update the error estimate relative to the nominal x_hat_k+ is 0, and relative to the
same nominal the prior's mean was -dx_hat_k (the correction the update found). With
x_k+ = 0 and x_k- = -dx_hat_k the recursion above gives the smoothed error dx_k^s of the forward
nominal x_hat_k+, and the smoothed solution is that nominal with dx_k^s fed back (``feedback`` of
the navigation system, to first order as the forward filter's own feedback).

Phi_{k+1} is the product of every linear map the forward epoch applied to P between the two
(covariance substeps, the loose filter's fix-bias scaling, the rotation of the tilt errors at
an in-motion alignment) with the rows of re-initialised states set to zero (``reset_rows``):
a state restarted without correlations (an ambiguity after a slip, a re-aligned heading) carries
nothing back across its restart. A state the filter "forgets" after its update (the loose
filter's heading before the in-motion alignment: variance back to the prior, correlations
cleared) is such a restart at the start of the next epoch: the record keeps the update's own
posterior (P+ and the part of the correction not fed back, ``x_post``) and the next epoch's Phi
has the forgotten rows zero. Recording the inflated P+ instead would break P^s <= P+ (a reset
that clears correlations does not shrink P, so P+_{k+1} <= P-_{k+1} fails and the backward
pass inflates the variances before it, measured x1e4 on the simulated car start).

What the backward pass needs is stored by the forward pass (``Record``): per epoch Phi, P- and
P+ (3 n^2 float64) plus dx_hat and the nominal state, i.e. 3 n^2 x 8 bytes + O(n): 17.5 kB
for the 27 states of the car's INS27 (38 MB for its 2182 epochs), 27.7 kB for INS15 + float PPP
(n = 34; 25 MB for a 900-epoch scenario). Stored rather than recomputed: a sweep chunk of 64
such scenarios holds 1.6 GB, within the 24 GB of the CI machine, and recomputation would double
the forward cost; the backward pass is one ``lax.scan``, vmappable.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


class Record(NamedTuple):
    """What the backward pass needs from forward epoch k (stacked over epochs: leading T)."""

    Phi: Float[Array, "n n"]  # error transition from epoch k-1's posterior to epoch k's prior
    P_prior: Float[Array, "n n"]  # P_k-, the covariance the update started from
    P_post: Float[Array, "n n"]  # P_k+
    dx: Float[Array, " n"]  # the correction fed back at epoch k (0 without an update)
    nav: Any  # the system's navigation state after the feedback (the nominal x_hat_k+)
    sensors: Any  # the system's sensor-error estimates after the feedback
    # posterior mean of the error of the nominal after the feedback: 0 when the whole update
    # was fed back; what was held back otherwise (the loose filter's unknown heading)
    x_post: Float[Array, " n"]


def reset_rows(Phi: Float[Array, "n n"], reset: Bool[Array, " n"]) -> Float[Array, "n n"]:
    """Transition through a re-initialisation of the ``reset`` states (``ekf.reset_states``):
    their rows of Phi are zero (the new error is independent of the old)."""
    return jnp.where(jnp.asarray(reset, bool)[:, None], 0.0, Phi)


def _gain(P_post, Phi_next, P_prior_next):
    """A = P+ Phi^T (P-)^-1, solved on P- scaled to unit diagonal (the error states mix
    radians of latitude, ~1e-7 per metre, with metres: unscaled, P- spans 1e-14 .. 1e2). A
    state with zero prior variance (none in practice) gets a unit diagonal and zero gain."""
    d = jnp.sqrt(jnp.diagonal(P_prior_next))
    zero = d == 0.0
    d = jnp.where(zero, 1.0, d)
    S = P_prior_next / (d[:, None] * d[None, :]) + jnp.diag(jnp.where(zero, 1.0, 0.0))
    B = (Phi_next @ P_post) / d[:, None]  # (P-)^-1 Phi P+ = A^T, scaled
    return (jnp.linalg.solve(S, B) / d[:, None]).T


def rts(
    x_post: Float[Array, "T n"],
    P_post: Float[Array, "T n n"],
    x_prior: Float[Array, "T n"],
    P_prior: Float[Array, "T n n"],
    Phi: Float[Array, "T n n"],
) -> tuple[Float[Array, "T n"], Float[Array, "T n n"]]:
    """The RTS recursion of the module docstring over stacked epochs (index 0 of ``x_prior``,
    ``P_prior`` and ``Phi`` is not read: the first epoch has no predecessor). Returns the
    smoothed means and covariances; the last epoch's equal its filtered ones."""

    def back(carry, k_inputs):
        x_s_next, P_s_next = carry
        x_p, P_p, x_pr_next, P_pr_next, Phi_next = k_inputs
        A = _gain(P_p, Phi_next, P_pr_next)
        x_s = x_p + A @ (x_s_next - x_pr_next)
        P_s = P_p + A @ (P_s_next - P_pr_next) @ A.T
        P_s = 0.5 * (P_s + P_s.T)
        return (x_s, P_s), (x_s, P_s)

    inputs = (x_post[:-1], P_post[:-1], x_prior[1:], P_prior[1:], Phi[1:])
    _, (xs, Ps) = jax.lax.scan(back, (x_post[-1], P_post[-1]), inputs, reverse=True)
    return (jnp.concatenate([xs, x_post[-1:]]), jnp.concatenate([Ps, P_post[-1:]]))


def cut_after(Phi: Float[Array, "T n n"], n_valid) -> Float[Array, "T n n"]:
    """Phi with the transitions into epochs >= ``n_valid`` (traced) zero: the backward pass
    then starts afresh at epoch n_valid - 1 and nothing after it reaches the epochs before
    (a sweep window's padding or data beyond its recovery period)."""
    k = jnp.arange(Phi.shape[0])
    return jnp.where((k >= n_valid)[:, None, None], 0.0, Phi)


def error_state(rec: Record, n_valid=None) -> tuple[Float[Array, "T n"], Float[Array, "T n n"]]:
    """Smoothed error dx_k^s of each forward nominal x_hat_k+ and its covariance (module
    docstring: x_k+ = 0, or ``x_post``, and x_k- = -dx_hat_k); ``n_valid``: smooth the first
    n_valid epochs only (``cut_after``), the rest are smoothed on their own."""
    Phi = rec.Phi if n_valid is None else cut_after(rec.Phi, n_valid)
    return rts(rec.x_post, rec.P_post, -rec.dx, rec.P_prior, Phi)
