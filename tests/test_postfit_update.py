"""The tight filter's post-fit test in m-space (issue 19) agrees with redoing the update.

``tight._update_with_postfit`` forms H P and S once, tests the post-fit residuals of each
candidate set of rows with ``ekf.postfit_normalized`` (R S^-1 nu over sqrt(diag(R S^-1 R)))
and applies only the final set to P. The reference below is the former algorithm: a full
``ekf.masked_update`` per pass and ``ekf.normalized_residuals`` from its P+. Both must choose
the same rows and give the same x and P to 1e-9 (relative to sqrt(P_ii P_jj)), over random
epochs with outliers that the test rejects, diagonal and correlated (BSSD-like) R, and the
wide variance range of freshly restarted ambiguities.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav  # noqa: F401
from jaxnav.core import rows as core_rows
from jaxnav.filter import ekf, tight
from jaxnav.gnss import ppp

N_SLOTS, N_NAV = 8, 12
KINDS = (core_rows.KIND_CODE, core_rows.KIND_PHASE, core_rows.KIND_DOPPLER)


def _reference(cfg, P, rows, mask):
    """The pre-issue-19 algorithm: every pass redoes the update from the prior."""
    x0 = jnp.zeros(P.shape[0])
    gnss = rows.kind != core_rows.KIND_CONSTRAINT
    gate = jnp.where(gnss, cfg.gate_chi2, jnp.inf)
    res = ekf.masked_update(x0, P, rows.dz, rows.H, rows.R, mask, gate)
    dropped = jnp.zeros(cfg.n_slots, bool)
    is_code = rows.kind == ppp.KIND_CODE
    for _ in range(cfg.postfit_passes):
        resid = ekf.normalized_residuals(res.x, res.P, rows.dz, rows.H, rows.R)
        score = jnp.where(res.used & gnss, jnp.abs(resid), 0.0)
        worst = jnp.argmax(score)
        reject = score[worst] > cfg.postfit_sigma
        drop = jnp.where(is_code[worst], rows.slot == rows.slot[worst],
                         jnp.arange(rows.dz.shape[0]) == worst) & gnss
        again = ekf.masked_update(x0, P, rows.dz, rows.H, rows.R, res.used & ~(drop & reject),
                                  gate)
        res = jax.tree.map(lambda a, b, r=reject: jnp.where(r, b, a), res, again)
        dropped = dropped.at[rows.slot[worst]].max(reject & is_code[worst])
    return res, dropped


def _epoch(rng, correlated: bool):
    """Random P (navigation block + clock + one ambiguity per slot, some just restarted with
    a 100 m sigma) and rows: code / phase / Doppler per slot plus two constraint rows, with
    a few 4-30 sigma outliers."""
    n = N_NAV + N_SLOTS
    A = rng.normal(size=(n, n))
    amb_std = np.where(rng.random(N_SLOTS) < 0.3, 100.0, 10.0 ** rng.uniform(-2, 0, N_SLOTS))
    std = np.concatenate([10.0 ** rng.uniform(-2, 0.5, N_NAV), amb_std])
    corr = np.corrcoef(A @ A.T + n * np.eye(n))
    P = corr * np.outer(std, std)
    H, slot, kind, sig = [], [], [], []
    for s in range(N_SLOTS):
        los = np.zeros(N_NAV)
        los[:3] = rng.normal(size=3)
        los[:3] /= np.linalg.norm(los[:3])
        los[N_NAV - 1] = 1.0  # clock
        for k, sigma in zip(KINDS, (0.5, 0.005, 0.05), strict=True):
            h = np.zeros(n)
            h[:N_NAV] = los if k != core_rows.KIND_DOPPLER else np.roll(los, 3)
            if k == core_rows.KIND_PHASE:
                h[N_NAV + s] = 1.0
            H.append(h)
            slot.append(s)
            kind.append(k)
            sig.append(sigma)
    for j in range(2):  # constraint rows on two velocity states
        h = np.zeros(n)
        h[3 + j] = 1.0
        H.append(h)
        slot.append(core_rows.NO_SLOT)
        kind.append(core_rows.KIND_CONSTRAINT)
        sig.append(0.1)
    H, sig = np.array(H), np.array(sig)
    m = len(sig)
    R = np.diag(sig**2)
    if correlated:  # BSSD-like: rows of one kind share a common (reference) error
        for k in KINDS:
            idx = np.flatnonzero(np.array(kind) == k)
            R[np.ix_(idx, idx)] += 0.5 * np.outer(sig[idx], sig[idx])
    S = H @ P @ H.T + R
    dz = np.linalg.cholesky(S) @ rng.normal(size=m)
    bad = rng.choice(3 * N_SLOTS, size=rng.integers(0, 4), replace=False)
    size = rng.uniform(4, 30, bad.size) * np.sqrt(np.diag(S))[bad]
    dz[bad] += rng.choice([-1, 1], bad.size) * size
    mask = rng.random(m) < 0.85
    rows = core_rows.Rows(jnp.asarray(dz), jnp.asarray(H), jnp.asarray(R), jnp.asarray(mask),
                          jnp.asarray(slot), jnp.asarray(kind))
    return jnp.asarray(P), rows, jnp.asarray(mask)


@pytest.mark.parametrize("correlated", [False, True])
def test_postfit_in_measurement_space_matches_redoing_the_update(correlated):
    cfg = ppp.PppConfig(n_slots=N_SLOTS, postfit_passes=3, gate_chi2=100.0)
    rng = np.random.default_rng(19 + correlated)
    new = jax.jit(lambda P, r, m: tight._update_with_postfit(cfg, P, r, m))
    ref = jax.jit(lambda P, r, m: _reference(cfg, P, r, m))
    rejected = 0
    for _ in range(150):
        P, rows, mask = _epoch(rng, correlated)
        (a, da), (b, db) = new(P, rows, mask), ref(P, rows, mask)
        np.testing.assert_array_equal(a.used, b.used)
        np.testing.assert_array_equal(da, db)
        rejected += int(jnp.sum(_offered(cfg, P, rows, mask) & ~b.used))
        s = np.sqrt(np.diag(b.P))
        assert np.max(np.abs(a.P - b.P) / np.outer(s, s)) <= 1e-9
        assert np.max(np.abs(a.x - b.x) / s) <= 1e-9
        assert abs(a.nis - b.nis) <= 1e-9 * max(1.0, abs(b.nis))
        assert int(a.dof) == int(b.dof)
    # the post-fit test did reject rows (else this would only check a single update)
    assert rejected >= 30, rejected


def _offered(cfg, P, rows, mask):
    """Rows the chi-square gate lets through (what a first update uses): those the reference
    does not use are the post-fit test's rejections (its ``gated`` is reset by a redo)."""
    gnss = rows.kind != core_rows.KIND_CONSTRAINT
    gate = jnp.where(gnss, cfg.gate_chi2, jnp.inf)
    return ekf.innovations(jnp.zeros(P.shape[0]), P, rows.dz, rows.H, rows.R, mask, gate).offered
