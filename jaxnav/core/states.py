"""Named index layouts of every error-state vector. Nothing outside this module uses bare indices.

Sign conventions (used by every model in jaxnav):
- Error = estimated - true: dx = x_hat - x.
- Position errors are geodetic (d_lat [rad], d_lon [rad], d_h [m]); velocity errors are ENU [m/s].
- Attitude error eps (ENU, rad) is defined by C_hat_b_l = (I - [eps x]) C_b_l.
- Sensor-error states are errors of the *compensated* sensor output the mechanization uses
  (e.g. f_used - f = b_a + diag(f) S_a), so feedback folds them into the running estimates.
- Measurement residuals are dz = h(x_hat) - z, so dz ~ H dx + noise with H = dh/dx.
- Closed loop: after an update the estimate dx_hat is removed from the navigation state
  (x <- x_hat - dx_hat) and the error state is reset to zero.

A layout is built from an ordered list of (name, size) blocks; ``layout.sl("vel")`` is the slice
of a block and ``layout.i("azimuth")`` the index of a one-element block. Indices are Python ints,
so they are static under ``jit``.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class StateLayout:
    """An ordered, named partition of a state vector into blocks."""

    blocks: tuple[tuple[str, int], ...]
    _start: dict[str, int] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self):
        start, offset = {}, 0
        for name, size in self.blocks:
            if name in start:
                raise ValueError(f"duplicate state block name {name!r}")
            if size < 1:
                raise ValueError(f"state block {name!r} must have size >= 1, got {size}")
            start[name] = offset
            offset += size
        object.__setattr__(self, "_start", start)

    @property
    def size(self) -> int:
        return sum(size for _, size in self.blocks)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.blocks)

    def block_size(self, name: str) -> int:
        return dict(self.blocks)[name]

    def sl(self, name: str) -> slice:
        """Slice of block ``name``."""
        start = self._start[name]
        return slice(start, start + self.block_size(name))

    def i(self, name: str) -> int:
        """Index of a one-element block."""
        if self.block_size(name) != 1:
            raise ValueError(f"block {name!r} has {self.block_size(name)} elements; use sl()")
        return self._start[name]

    def has(self, name: str) -> bool:
        return name in self._start

    def extend(self, *blocks: tuple[str, int]) -> StateLayout:
        """A new layout with ``blocks`` appended."""
        return StateLayout(self.blocks + tuple(blocks))

    def labels(self) -> list[str]:
        """One label per element, e.g. ['pos[0]', 'pos[1]', ..., 'azimuth']."""
        out = []
        for name, size in self.blocks:
            out += [name] if size == 1 else [f"{name}[{k}]" for k in range(size)]
        return out


# ---- Full IMU (body right-forward-up, ENU) ---------------------------------------------------
#: 15 states (S002 eq 4.17): position, velocity, attitude, accelerometer bias, gyro bias (GM).
INS15 = StateLayout(
    (("pos", 3), ("vel", 3), ("att", 3), ("accel_bias", 3), ("gyro_bias", 3)),
)
#: 21 states: INS15 + accelerometer and gyro scale factors (GM) (S001 eq 14, S004 eq 15).
INS21 = INS15.extend(("accel_scale", 3), ("gyro_scale", 3))
#: 27 states (S003 eq 2): INS15 with GM bias drifts, + turn-on biases (random constants) + scale
#: factors. Order as printed: pos, vel, att, b_a drift, b_g drift, b_a turn-on, b_g turn-on,
#: S_a, S_g.
INS27 = INS15.extend(
    ("accel_bias_ton", 3), ("gyro_bias_ton", 3), ("accel_scale", 3), ("gyro_scale", 3)
)

# ---- RISS (body right-forward-up, ENU) -------------------------------------------------------
#: Seed 000's 16 states in its F-matrix order (SEED_SPEC 4, S000 item 1): position, velocity,
#: azimuth, odometer acceleration, vertical-gyro bias, receiver clock bias [m] and drift [m/s],
#: roll, pitch, transverse and forward accelerometer biases, odometer speed.
RISS16 = StateLayout(
    (
        ("pos", 3),
        ("vel", 3),
        ("azimuth", 1),
        ("odo_accel", 1),
        ("gyro_bias_z", 1),
        ("clock_bias", 1),
        ("clock_drift", 1),
        ("roll", 1),
        ("pitch", 1),
        ("accel_bias_x", 1),
        ("accel_bias_y", 1),
        ("odo_speed", 1),
    )
)
#: Seed 002 chapter 5's 9 navigation states (eq 5.8, states 1-9); the GNSS states follow.
RISS9 = StateLayout(
    (("pos", 3), ("vel", 3), ("azimuth", 1), ("odo_accel", 1), ("gyro_bias_z", 1)),
)
