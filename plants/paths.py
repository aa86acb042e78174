"""Reference paths (polylines in the earth frame) and the path-tracking driver.

The driver is a pure-pursuit steering law with understeer compensation: it aims
at the path point one look-ahead distance ``l_d = max(L_MIN, T_p v)`` ahead and
commands the front road-wheel angle

``delta = (L + K_us v^2) * 2 sin(alpha) / l_d``

where ``alpha`` is the bearing of that point from the vehicle heading, ``L`` the
wheelbase and ``K_us`` the understeer gradient (so that the steady-state
curvature is right for an understeering car). It holds an explicit state (the
index of the closest path point) and follows the simulator's step protocol.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ManeuverError
from .params import VehicleParams


@dataclass(frozen=True)
class Path:
    """A polyline ``(x, y)`` [m] in the earth frame, densely sampled (<= 0.5 m)."""

    x: np.ndarray
    y: np.ndarray
    s: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        x, y = np.asarray(self.x, float), np.asarray(self.y, float)
        if x.shape != y.shape or x.ndim != 1 or len(x) < 2:
            raise ManeuverError("a path needs two equally long 1-D coordinate arrays with >= 2 points")
        seg = np.hypot(np.diff(x), np.diff(y))
        if np.any(seg <= 0):
            raise ManeuverError("path points must be distinct")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "s", np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def point_at(self, s: float) -> tuple[float, float]:
        s = min(max(s, 0.0), self.length)
        return float(np.interp(s, self.s, self.x)), float(np.interp(s, self.s, self.y))

    def closest(self, px: float, py: float, start: int, window: int = 400) -> int:
        """Index of the closest point, searched forward from ``start`` (paths are driven forward)."""
        lo, hi = max(start - 5, 0), min(start + window, len(self.x))
        d2 = (self.x[lo:hi] - px) ** 2 + (self.y[lo:hi] - py) ** 2
        return lo + int(np.argmin(d2))

    def lateral_offset(self, px, py) -> np.ndarray:
        """Signed distance [m] of points from the path (positive = left of it), brute force."""
        px, py = np.atleast_1d(px), np.atleast_1d(py)
        out = np.empty(len(px))
        tx, ty = np.gradient(self.x), np.gradient(self.y)
        for i in range(len(px)):
            j = int(np.argmin((self.x - px[i]) ** 2 + (self.y - py[i]) ** 2))
            out[i] = (tx[j] * (py[i] - self.y[j]) - ty[j] * (px[i] - self.x[j])) / np.hypot(tx[j], ty[j])
        return out


def path_from_function(y_of_x, x_start: float, x_end: float, ds: float = 0.25) -> Path:
    xs = np.arange(x_start, x_end + ds / 2, ds)
    return Path(xs, np.asarray(y_of_x(xs), float))


@dataclass(frozen=True)
class PathDriver:
    """Pure-pursuit steering driver; see the module docstring for the law."""

    path: Path
    params: VehicleParams
    preview_time: float = 0.6
    min_lookahead: float = 5.0
    max_steer: float = 0.6

    def initial_state(self) -> int:
        return 0

    def steer(self, state: int, x: float, y: float, yaw: float, speed: float) -> tuple[int, float]:
        """Advance the closest-point index and return the road-wheel steer command [rad]."""
        idx = self.path.closest(x, y, state)
        ld = max(self.min_lookahead, self.preview_time * abs(speed))
        tx, ty = self.path.point_at(self.path.s[idx] + ld)
        alpha = np.arctan2(ty - y, tx - x) - yaw
        alpha = (alpha + np.pi) % (2 * np.pi) - np.pi
        gain = self.params.wheelbase + self.params.understeer_gradient * speed**2
        delta = gain * 2.0 * np.sin(alpha) / ld
        return idx, float(np.clip(delta, -self.max_steer, self.max_steer))


@dataclass(frozen=True)
class HumanDriver:
    """A driver who sees the path like :class:`PathDriver` but acts like a person: the pure-pursuit
    command reaches the hand-wheel after a reaction ``delay`` [s] and through a first-order
    neuromuscular ``lag`` [s] (the crossover-model values of a driver in an emergency manoeuvre:
    0.1-0.2 s of delay, about 0.1 s of lag; McRuer and Krendel, *Mathematical Models of Human Pilot
    Behavior*, AGARDograph 188, 1974). Stepped every ``dt`` [s] like :class:`PathDriver`."""

    path: Path
    params: VehicleParams
    dt: float
    delay: float = 0.15
    lag: float = 0.1
    preview_time: float = 0.8
    min_lookahead: float = 5.0
    max_steer: float = 0.6

    def __post_init__(self) -> None:
        if not (self.dt > 0 and self.delay >= 0 and self.lag >= 0):
            raise ManeuverError(f"human driver: dt must be > 0 s, delay and lag >= 0 s (got {self.dt!r}, "
                                f"{self.delay!r}, {self.lag!r})")

    def initial_state(self):
        n = int(round(self.delay / self.dt))
        return (0, [0.0] * n, 0, 0.0)

    def steer(self, state, x: float, y: float, yaw: float, speed: float):
        idx, buf, head, out = state
        idx, wanted = PathDriver(self.path, self.params, self.preview_time, self.min_lookahead,
                                 self.max_steer).steer(idx, x, y, yaw, speed)
        if buf:  # a ring buffer of the last delay / dt commands
            wanted, buf[head] = buf[head], wanted
            head = (head + 1) % len(buf)
        out = wanted if self.lag == 0 else out + (wanted - out) * min(self.dt / self.lag, 1.0)
        return (idx, buf, head, out), out


@dataclass(frozen=True)
class DriverModel:
    """How a path-following manoeuvre is driven: :class:`HumanDriver`'s reaction ``delay`` [s],
    neuromuscular ``lag`` [s] and ``preview_time`` [s]."""

    delay: float = 0.15
    lag: float = 0.1
    preview_time: float = 0.8

    def make(self, path: Path, params: VehicleParams, dt: float) -> HumanDriver:
        return HumanDriver(path, params, dt, self.delay, self.lag, self.preview_time)
