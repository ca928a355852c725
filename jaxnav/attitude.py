"""Attitude: quaternions, direction-cosine matrices, Euler angles and rotation vectors.

One convention everywhere (docs/architecture.md):
- Body frame b is right-forward-up (x right, y forward, z up) as in seeds 000/002; the
  local-level frame l is ENU.
- ``C_b_l`` is the DCM taking body vectors to ENU: v^l = C_b_l v^b.
- Euler angles are (roll r, pitch p, azimuth A) in radians, azimuth clockwise from north;
  C_b_l is the S002 eq 3.5 matrix (rows E, N, U), i.e. C_b_l = R3(-A) R1(p) R2(r) written with
  active rotations about the l-frame's up, east and the body's forward axes.
- Quaternions are Hamilton, scalar first, ``q = [w, x, y, z]``; ``q_b_l`` rotates body to ENU
  (v^l = q (x) v^b (x) q*), so ``dcm_from_quat(q_b_l) == C_b_l``.
- Rotation vectors are axis * angle; ``quat_from_rotvec(phi)`` is the rotation exp([phi x]).
- Small attitude errors: the estimated DCM is C_hat = (I - [eps x]) C_b_l, eps in ENU.
"""

from __future__ import annotations

import jax.numpy as jnp


def skew(v):
    """Cross-product matrix [v x] such that skew(a) @ b == cross(a, b)."""
    z = jnp.zeros_like(v[0])
    return jnp.array(
        [
            [z, -v[2], v[1]],
            [v[2], z, -v[0]],
            [-v[1], v[0], z],
        ]
    )


def dcm_from_euler(euler_rpa):
    """C_b_l from (roll, pitch, azimuth): S002 eq 3.5 (S000 A.9 transposed, with its typo fixed)."""
    r, p, a = euler_rpa[0], euler_rpa[1], euler_rpa[2]
    sr, cr = jnp.sin(r), jnp.cos(r)
    sp, cp = jnp.sin(p), jnp.cos(p)
    sa, ca = jnp.sin(a), jnp.cos(a)
    return jnp.array(
        [
            [ca * cr + sa * sp * sr, sa * cp, ca * sr - sa * sp * cr],
            [-sa * cr + ca * sp * sr, ca * cp, -sa * sr - ca * sp * cr],
            [-cp * sr, sp, cp * cr],
        ]
    )


def dcm_euler_partials(euler_rpa):
    """Partial derivatives (dC/droll, dC/dpitch, dC/dazimuth) of ``dcm_from_euler``."""
    r, p, a = euler_rpa[0], euler_rpa[1], euler_rpa[2]
    sr, cr = jnp.sin(r), jnp.cos(r)
    sp, cp = jnp.sin(p), jnp.cos(p)
    sa, ca = jnp.sin(a), jnp.cos(a)
    z = jnp.zeros_like(r)
    d_roll = jnp.array(
        [
            [-ca * sr + sa * sp * cr, z, ca * cr + sa * sp * sr],
            [sa * sr + ca * sp * cr, z, -sa * cr + ca * sp * sr],
            [-cp * cr, z, -cp * sr],
        ]
    )
    d_pitch = jnp.array(
        [
            [sa * cp * sr, -sa * sp, -sa * cp * cr],
            [ca * cp * sr, -ca * sp, -ca * cp * cr],
            [sp * sr, cp, -sp * cr],
        ]
    )
    d_azimuth = jnp.array(
        [
            [-sa * cr + ca * sp * sr, ca * cp, -sa * sr - ca * sp * cr],
            [-ca * cr - sa * sp * sr, -sa * cp, -ca * sr + sa * sp * cr],
            [z, z, z],
        ]
    )
    return d_roll, d_pitch, d_azimuth


def euler_from_dcm(C_b_l):
    """(roll, pitch, azimuth) from C_b_l: p = asin(C32), r = atan2(-C31, C33), A = atan2(C12, C22).

    Azimuth is returned in (-pi, pi]; pitch is clipped to [-pi/2, pi/2] against round-off.
    """
    pitch = jnp.arcsin(jnp.clip(C_b_l[2, 1], -1.0, 1.0))
    roll = jnp.arctan2(-C_b_l[2, 0], C_b_l[2, 2])
    azimuth = jnp.arctan2(C_b_l[0, 1], C_b_l[1, 1])
    return jnp.stack([roll, pitch, azimuth])


def quat_multiply(q, r):
    """Hamilton product q (x) r (scalar first)."""
    w1, x1, y1, z1 = q[0], q[1], q[2], q[3]
    w2, x2, y2, z2 = r[0], r[1], r[2], r[3]
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_conjugate(q):
    """Conjugate (inverse of a unit quaternion): [w, -x, -y, -z]."""
    return q * jnp.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q):
    """Unit quaternion with a non-negative scalar part (q and -q are the same rotation)."""
    q = q / jnp.linalg.norm(q)
    return jnp.where(q[0] < 0.0, -q, q)


def dcm_from_quat(q):
    """DCM of a unit quaternion: C = (w^2 - |v|^2) I + 2 v v^T + 2 w [v x]."""
    w, v = q[0], q[1:]
    return (w * w - v @ v) * jnp.eye(3) + 2.0 * jnp.outer(v, v) + 2.0 * w * skew(v)


def quat_from_dcm(C):
    """Unit quaternion of a DCM (Shepperd's method: branch on the largest diagonal term)."""
    tr = jnp.trace(C)
    d = jnp.array([tr, C[0, 0], C[1, 1], C[2, 2]])
    k = jnp.argmax(d)
    # Each branch divides by its own largest component, so none of them loses precision.
    q0 = jnp.array([1.0 + tr, C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]])
    q1 = jnp.array(
        [C[2, 1] - C[1, 2], 1.0 + 2.0 * C[0, 0] - tr, C[0, 1] + C[1, 0], C[0, 2] + C[2, 0]]
    )
    q2 = jnp.array(
        [C[0, 2] - C[2, 0], C[0, 1] + C[1, 0], 1.0 + 2.0 * C[1, 1] - tr, C[1, 2] + C[2, 1]]
    )
    q3 = jnp.array(
        [C[1, 0] - C[0, 1], C[0, 2] + C[2, 0], C[1, 2] + C[2, 1], 1.0 + 2.0 * C[2, 2] - tr]
    )
    q = jnp.stack([q0, q1, q2, q3])[k]
    return quat_normalize(q)


def quat_from_rotvec(phi):
    """Quaternion of rotation vector phi: [cos(|phi|/2), sin(|phi|/2) phi/|phi|].

    Uses the Taylor series below 1e-4 rad so the function and its derivative stay exact at 0.
    """
    theta2 = phi @ phi
    small = theta2 < 1e-8
    theta = jnp.sqrt(jnp.where(small, 1.0, theta2))
    half_sinc = jnp.where(small, 0.5 - theta2 / 48.0, jnp.sin(0.5 * theta) / theta)
    w = jnp.where(small, 1.0 - theta2 / 8.0, jnp.cos(0.5 * theta))
    return jnp.concatenate([w[None], half_sinc * phi])


def rotvec_from_quat(q):
    """Rotation vector of a unit quaternion (inverse of ``quat_from_rotvec``), angle in [0, pi]."""
    q = quat_normalize(q)
    s = jnp.linalg.norm(q[1:])
    small = s < 1e-8
    angle = 2.0 * jnp.arctan2(s, q[0])
    scale = jnp.where(small, 2.0 / q[0], angle / jnp.where(small, 1.0, s))
    return scale * q[1:]


def dcm_from_rotvec(phi):
    """DCM exp([phi x]) (Rodrigues)."""
    return dcm_from_quat(quat_from_rotvec(phi))


def rotvec_from_dcm(C):
    """Rotation vector of a DCM."""
    return rotvec_from_quat(quat_from_dcm(C))


def quat_from_euler(euler_rpa):
    """q_b_l from (roll, pitch, azimuth)."""
    return quat_from_dcm(dcm_from_euler(euler_rpa))


def euler_from_quat(q_b_l):
    """(roll, pitch, azimuth) from q_b_l."""
    return euler_from_dcm(dcm_from_quat(q_b_l))


def attitude_error(C_hat_b_l, C_b_l):
    """Attitude error eps (ENU) with C_hat = (I - [eps x]) C, taken as eps = -rotvec(C_hat C^T)."""
    return -rotvec_from_dcm(C_hat_b_l @ C_b_l.T)


def correct_attitude(C_hat_b_l, eps):
    """Remove an estimated attitude error: C = (I - [eps x])^-1 C_hat = exp([eps x]) C_hat."""
    return dcm_from_rotvec(eps) @ C_hat_b_l


def wrap_angle(a):
    """Wrap an angle to (-pi, pi]."""
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))
