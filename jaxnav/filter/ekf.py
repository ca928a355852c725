"""Kalman-filter kernel: discretisation, predict, masked update with gating. No navigation here.

The measurement model is y = H x + v, v ~ N(0, R). Navigation code passes the error state x
(zero after each closed-loop feedback) and the residual y = h(x_hat) - z (states.py).

Masks: every measurement row has a boolean; a false row contributes nothing, and an update in
which no row is used returns x and P bit-for-bit unchanged. Shapes never depend on the mask, so
the same compiled step serves every satellite-availability level under ``vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, ArrayLike, Bool, Float, Int

#: chi-square 1-dof quantiles used for per-row innovation gating.
CHI2_1DOF_99 = 6.634896601021214
CHI2_1DOF_999 = 10.827566170662733


def discretize_van_loan(
    F: Float[ArrayLike, "n n"],
    G: Float[ArrayLike, "n q"],
    Qc: Float[ArrayLike, "q q"],
    dt: Float[ArrayLike, ""],
) -> tuple[Float[Array, "n n"], Float[Array, "n n"]]:
    """Exact discretisation of x' = F x + G w, E[w w^T] = Qc delta(t), over dt (Van Loan 1978).

    With M = [[-F, G Qc G^T], [0, F^T]] dt and E = expm(M): Phi = E22^T and Qd = Phi E12.
    Exact for constant F over dt; used as the reference and for large F dt.
    """
    n = F.shape[0]
    Qg = G @ Qc @ G.T
    M = jnp.block([[-F, Qg], [jnp.zeros_like(F), F.T]]) * dt
    E = jsl.expm(M)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    return Phi, 0.5 * (Qd + Qd.T)


def discretize_taylor(
    F: Float[ArrayLike, "n n"],
    G: Float[ArrayLike, "n q"],
    Qc: Float[ArrayLike, "q q"],
    dt: Float[ArrayLike, ""],
) -> tuple[Float[Array, "n n"], Float[Array, "n n"]]:
    """Second-order transition and trapezoidal noise: Phi = I + F dt + (F dt)^2 / 2,
    Qd = (Phi G Qc G^T Phi^T + G Qc G^T) dt / 2.

    The filters' step until issue 16, kept as the reference the tests compare against: it
    assumes ||F dt|| << 1, which RISS16's Gauss-Markov velocity terms (beta dt = 1 at 1 Hz)
    break, and its trapezoidal Qd gives an integrated random walk dt^3 / 2 instead of dt^3 / 3.
    The filters use ``discretize``.
    """
    n = F.shape[0]
    Fdt = F * dt
    Phi = jnp.eye(n) + Fdt + 0.5 * Fdt @ Fdt
    Qg = G @ Qc @ G.T
    Qd = 0.5 * (Phi @ Qg @ Phi.T + Qg) * dt
    return Phi, 0.5 * (Qd + Qd.T)


#: Halvings of the epoch in ``discretize``: 2^3 substeps keep a Gauss-Markov state with
#: beta dt = 1 (RISS16's velocity terms at 1 Hz) within 1e-4 of exp(-beta dt) and its noise
#: within 1e-3 of the exact (1 - exp(-2 beta dt)) sigma^2 (tests/test_ekf.py).
SQUARINGS = 3


def discretize(
    F: Float[ArrayLike, "n n"],
    G: Float[ArrayLike, "n q"],
    Qc: Float[ArrayLike, "q q"],
    dt: Float[ArrayLike, ""],
    squarings: int = SQUARINGS,
) -> tuple[Float[Array, "n n"], Float[Array, "n n"]]:
    """Phi = exp(F dt), Qd = int_0^dt exp(F s) G Qc G^T exp(F^T s) ds by scaling and squaring.

    Over h = dt / 2^k: Phi_h = I + A + A^2/2 + A^3/6 (A = F h) and the third-order series
    Qd_h = Q h + (F Q + Q F^T) h^2/2 + (F^2 Q + 2 F Q F^T + Q F^T^2) h^3/6 (Q = G Qc G^T),
    exact for nilpotent F such as the clock's bias' = drift (bias variance q_d dt^3 / 3); then
    k doublings Qd_2h = Phi_h Qd_h Phi_h^T + Qd_h, Phi_2h = Phi_h^2. The default filters' step:
    stiff first-order Gauss-Markov blocks (beta dt ~ 1) stay right where a single Taylor step
    gives Phi = 0.5 for exp(-1) = 0.37.
    """
    n = F.shape[0]
    h = dt / 2**squarings
    A = F * h
    Q = G @ Qc @ G.T
    A2 = A @ A
    Phi = jnp.eye(n) + A + A2 / 2.0 + A2 @ A / 6.0
    AQ = A @ Q
    AAQ = A @ AQ
    Qd = h * (Q + 0.5 * (AQ + AQ.T) + (AAQ + AAQ.T + 2.0 * AQ @ A.T) / 6.0)
    for _ in range(squarings):
        Qd = Phi @ Qd @ Phi.T + Qd
        Phi = Phi @ Phi
    return Phi, 0.5 * (Qd + Qd.T)


def predict(
    x: Float[ArrayLike, " n"],
    P: Float[ArrayLike, "n n"],
    Phi: Float[ArrayLike, "n n"],
    Qd: Float[ArrayLike, "n n"],
) -> tuple[Float[ArrayLike, " n"], Float[ArrayLike, "n n"]]:
    """Time update: x <- Phi x, P <- Phi P Phi^T + Qd (symmetrised)."""
    P_new = Phi @ P @ Phi.T + Qd
    return Phi @ x, 0.5 * (P_new + P_new.T)


class UpdateResult(NamedTuple):
    """Outcome of a masked update. Row-wise arrays have the measurement's length."""

    x: Float[Array, " n"]
    P: Float[Array, "n n"]
    innovation: Float[Array, " m"]  # y - H x_prior (all rows, used or not)
    innovation_var: Float[Array, " m"]  # diag(H P H^T + R) (all rows)
    used: Bool[Array, " m"]  # rows that entered the update (mask and not gated)
    gated: Bool[Array, " m"]  # rows that were offered (mask true) but rejected by the gate
    nis: Float[Array, ""]  # normalised innovation squared of the used rows
    dof: Int[Array, ""]  # number of used rows
    logdet: Float[Array, ""]  # log det S_u of the used rows (0 with none): jaxnav.filter.tune


class Innovations(NamedTuple):
    """The prior's part of an update, computed once (O(n^2 m)) and shared by every solve that
    follows with a different set of used rows (the post-fit tests, ``apply_update``)."""

    nu: Float[Array, " m"]  # y - H x
    HP: Float[Array, "m n"]  # H P
    S: Float[Array, "m m"]  # H P H^T + R
    gated: Bool[Array, " m"]  # offered rows rejected by the chi-square gate
    offered: Bool[Array, " m"]  # mask and not gated: the rows a first update uses


def innovations(
    x: Float[Array, " n"],
    P: Float[Array, "n n"],
    y: Float[Array, " m"],
    H: Float[Array, "m n"],
    R: Float[Array, "m m"],
    mask: Bool[Array, " m"],
    gate: Float[ArrayLike, ""] | Float[Array, " m"] = jnp.inf,
) -> Innovations:
    """nu = y - H x, S = H P H^T + R; row i is gated when nu_i^2 > gate * S_ii (``gate`` one
    value or one per row; ``inf`` disables it)."""
    mask = jnp.asarray(mask, dtype=bool)
    nu = y - H @ x
    HP = H @ P
    S = HP @ H.T + R
    gated = mask & (nu * nu > gate * jnp.diag(S))
    return Innovations(nu=nu, HP=HP, S=S, gated=gated, offered=mask & ~gated)


def _used_system(inn: Innovations, R: Float[Array, "m m"], used: Bool[Array, " m"]):
    """Cholesky factor of S_u (the used rows' block of S, unit diagonal elsewhere), nu_u and
    R_u (used rows' block of R, zero elsewhere).

    Unused rows are decoupled with a unit diagonal, which gives them zero gain without
    changing shapes; S_u equals H_u P H_u^T + R_u with the unused rows of H, R zeroed."""
    pair = used[:, None] & used[None, :]
    S_u = jnp.where(pair, inn.S, 0.0) + jnp.diag(jnp.where(used, 0.0, 1.0))
    return (jsl.cho_factor(S_u, lower=True), jnp.where(used, inn.nu, 0.0),
            jnp.where(pair, R, 0.0))


def postfit_normalized(
    inn: Innovations, R: Float[Array, "m m"], used: Bool[Array, " m"]
) -> Float[Array, " m"]:
    """Normalised post-fit residuals r_i / sqrt(C_ii) of the rows ``used`` in an update, without
    forming its P+: for used rows r = y - H x+ = R_u S_u^-1 nu_u and C = R - H P+ H^T =
    R_u S_u^-1 R_u (Teunissen's w-test; R may be correlated, as BSSD's). A row whose own
    observation the update absorbs entirely (redundancy C_ii / R_ii < 1e-6, e.g. the phase of a
    satellite whose ambiguity just restarted) cannot be tested and gets 0, as do unused rows."""
    chol, nu_u, R_u = _used_system(inn, R, used)
    r = R_u @ jsl.cho_solve(chol, nu_u)
    W = jsl.solve_triangular(chol[0], R_u, lower=True)  # L^-1 R_u: C = W^T W
    c = jnp.sum(W * W, axis=0)
    testable = used & (c > 1e-6 * jnp.diag(R))
    return jnp.where(testable, r / jnp.sqrt(jnp.where(testable, c, 1.0)), 0.0)


def apply_update(
    x: Float[Array, " n"],
    P: Float[Array, "n n"],
    inn: Innovations,
    H: Float[Array, "m n"],
    R: Float[Array, "m m"],
    used: Bool[Array, " m"],
) -> UpdateResult:
    """Joseph-form update with the rows ``used`` (a subset of ``inn.offered``):
    K = P H_u^T S_u^-1, x+ = x + K nu_u, P+ = (I - K H_u) P (I - K H_u)^T + K R_u K^T
    (unused rows zeroed in H, nu and R). No used row: x and P are returned bit-for-bit."""
    chol, nu_u, R_u = _used_system(inn, R, used)
    # [K^T | a] = S_u^-1 [H_u P | nu_u]: one solve for the gain and the NIS nu_u^T a
    X = jsl.cho_solve(chol, jnp.concatenate([jnp.where(used[:, None], inn.HP, 0.0),
                                             nu_u[:, None]], axis=1))
    K, a = X[:, :-1].T, X[:, -1]
    H_u = jnp.where(used[:, None], H, 0.0)
    IKH = jnp.eye(x.shape[0]) - K @ H_u
    P_new = IKH @ P @ IKH.T + K @ R_u @ K.T
    P_new = 0.5 * (P_new + P_new.T)
    any_used = jnp.any(used)
    return UpdateResult(
        x=jnp.where(any_used, x + K @ nu_u, x),
        P=jnp.where(any_used, P_new, P),
        innovation=inn.nu,
        innovation_var=jnp.diag(inn.S),
        used=used,
        gated=inn.gated,
        nis=nu_u @ a,
        dof=jnp.sum(used),
        # unused rows have a unit diagonal in the factor: log 1 = 0
        logdet=2.0 * jnp.sum(jnp.log(jnp.diagonal(chol[0]))),
    )


# Functions called on host arrays (tests, post-processing) are jitted: one compiled kernel per
# argument shape instead of one per primitive (inside another jit they are inlined).
@jax.jit
def masked_update(
    x: Float[Array, " n"],
    P: Float[Array, "n n"],
    y: Float[Array, " m"],
    H: Float[Array, "m n"],
    R: Float[Array, "m m"],
    mask: Bool[Array, " m"],
    gate: Float[ArrayLike, ""] | Float[Array, " m"] = jnp.inf,
) -> UpdateResult:
    """Joseph-form update with masked, chi-square-gated rows: ``innovations`` (gating
    nu_i^2 > gate * S_ii) then ``apply_update`` with the rows that passed. ``gate=inf``
    disables gating."""
    inn = innovations(x, P, y, H, R, mask, gate)
    return apply_update(x, P, inn, H, R, inn.offered)


@jax.jit
def normalized_residuals(
    x: Float[Array, " n"],
    P: Float[Array, "n n"],
    y: Float[Array, " m"],
    H: Float[Array, "m n"],
    R: Float[Array, "m m"],
) -> Float[Array, " m"]:
    """Normalised post-fit residuals r_i / sqrt(C_ii) of an update's rows, r = y - H x+, with
    the post-fit covariance C = R - H P+ H^T (x+, P+ the update's result; for rows that were in
    the update). A row whose own observation the update absorbs entirely (redundancy
    C_ii / R_ii < 1e-6, e.g. the phase of a satellite whose ambiguity just restarted) cannot be
    tested and gets 0. The filters use ``postfit_normalized``, which needs no P+; this direct
    form is its reference (tests/test_postfit_update.py)."""
    nu = y - H @ x
    c = jnp.diag(R) - jnp.einsum("ij,jk,ik->i", H, P, H)
    r_ii = jnp.diag(R)
    testable = c > 1e-6 * r_ii
    return jnp.where(testable, nu / jnp.sqrt(jnp.where(testable, c, 1.0)), 0.0)


@jax.jit
def reset_states(
    x: Float[Array, " n"],
    P: Float[Array, "n n"],
    reset: Bool[Array, " n"],
    variance: Float[Array, " n"],
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """Re-initialise the states flagged in ``reset``: x_i = 0, row/column i of P cleared and
    P_ii = variance_i. Used for per-slot ambiguities/ionosphere when a satellite rises or slips.
    """
    reset = jnp.asarray(reset, dtype=bool)
    keep = ~reset
    P_new = jnp.where(keep[:, None] & keep[None, :], P, 0.0)
    P_new = P_new + jnp.diag(jnp.where(reset, variance, 0.0))
    return jnp.where(reset, 0.0, x), P_new
