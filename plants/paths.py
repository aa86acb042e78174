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
    """A driver who follows the path like a person: the command reaches the road wheels after a
    reaction ``delay`` [s] and through a first-order neuromuscular ``lag`` [s] (the values of a
    driver in an emergency manoeuvre: 0.1-0.2 s of delay, about 0.1 s of lag; McRuer and Krendel,
    *Mathematical Models of Human Pilot Behavior*, AGARDograph 188, 1974), and which the driver
    anticipates: he steers for where the car will be after them, turning at its present yaw rate.
    From that predicted pose, the steer is the path's curvature ``preview_time`` ahead through the
    linear car, ``(L + K_us v^2) kappa``, plus a correction of the heading error and the lateral
    error (Stanley's law, ``-e_psi - atan(gain_lateral e / (v + 1 m/s))``). Stepped every ``dt`` [s]
    like :class:`PathDriver`."""

    path: Path
    params: VehicleParams
    dt: float
    delay: float = 0.15
    lag: float = 0.1
    preview_time: float = 0.1
    gain_lateral: float = 1.5
    max_steer: float = 0.6
    _heading: np.ndarray = field(init=False, repr=False, compare=False)
    """The path's heading at each point [rad], unwrapped (set from the path)."""
    _kappa: np.ndarray = field(init=False, repr=False, compare=False)
    """The path's curvature at each point [1/m] (set from the path)."""

    def __post_init__(self) -> None:
        if not (self.dt > 0 and self.delay >= 0 and self.lag >= 0 and self.preview_time >= 0):
            raise ManeuverError(f"human driver: dt must be > 0 s, delay, lag and preview >= 0 s (got {self.dt!r}, "
                                f"{self.delay!r}, {self.lag!r}, {self.preview_time!r})")
        x, y = self.path.x, self.path.y
        dx, dy = np.gradient(x, self.path.s), np.gradient(y, self.path.s)
        ddx, ddy = np.gradient(dx, self.path.s), np.gradient(dy, self.path.s)
        object.__setattr__(self, "_heading", np.unwrap(np.arctan2(dy, dx)))
        object.__setattr__(self, "_kappa", (dx * ddy - dy * ddx) / np.maximum(dx * dx + dy * dy, 1e-12) ** 1.5)

    def initial_state(self):
        n = max(int(round(self.delay / self.TICK)), 0)
        return {"idx": 0, "buf": [0.0] * n, "head": 0, "out": 0.0, "k": 0, "held": 0.0}

    TICK = 0.01
    """[s] The driver decides a new command every tick (a person does not act at 1 kHz)."""

    def _predict(self, st, x, y, yaw, speed):
        """The pose after the delay and the lag, steering the commands already on their way (the
        buffer, then the last of them held) through the lag into a kinematic car,
        ``r = v delta / (L + K_us v^2)``."""
        gain = self.params.wheelbase + self.params.understeer_gradient * speed ** 2
        h = self.TICK
        delta = st["out"]
        buf, head = st["buf"], st["head"]
        queue = [buf[(head + i) % len(buf)] for i in range(len(buf))] if buf else []
        steps = len(queue) + max(int(round(self.lag / h)), 0)
        cmd = queue[-1] if queue else st["held"]
        a = min(h / self.lag, 1.0) if self.lag > 0 else 1.0
        for i in range(steps):
            c = queue[i] if i < len(queue) else cmd
            delta += (c - delta) * a
            r = speed * delta / gain
            yaw += r * h
            x += speed * np.cos(yaw) * h
            y += speed * np.sin(yaw) * h
        return x, y, yaw

    def steer(self, state, x: float, y: float, yaw: float, speed: float):
        st = dict(state)
        if st["k"] % max(int(round(self.TICK / self.dt)), 1) == 0:
            xp, yp, yawp = self._predict(st, x, y, yaw, speed)
            idx = self.path.closest(xp, yp, st["idx"])
            px, py, ph = self.path.x[idx], self.path.y[idx], self._heading[idx]
            e = -np.sin(ph) * (xp - px) + np.cos(ph) * (yp - py)  # left of the path positive
            e_psi = (yawp - ph + np.pi) % (2 * np.pi) - np.pi
            kappa = float(np.interp(self.path.s[idx] + speed * self.preview_time, self.path.s, self._kappa))
            gain = self.params.wheelbase + self.params.understeer_gradient * speed ** 2
            wanted = gain * kappa - e_psi - np.arctan(self.gain_lateral * e / (abs(speed) + 1.0))
            wanted = float(np.clip(wanted, -self.max_steer, self.max_steer))
            st["idx"] = idx
            if st["buf"]:  # a ring buffer of the commands of the last delay / TICK ticks
                buf = list(st["buf"])
                wanted, buf[st["head"]] = buf[st["head"]], wanted
                st["buf"], st["head"] = buf, (st["head"] + 1) % len(buf)
            st["held"] = wanted
        st["k"] += 1
        a = min(self.dt / self.lag, 1.0) if self.lag > 0 else 1.0
        st["out"] += (st["held"] - st["out"]) * a
        return st, st["out"]


@dataclass(frozen=True)
class DriverModel:
    """How a path-following manoeuvre is driven: :class:`HumanDriver`'s reaction ``delay`` [s],
    neuromuscular ``lag`` [s] and ``preview_time`` [s]."""

    delay: float = 0.15
    lag: float = 0.1
    preview_time: float = 0.1
    gain_lateral: float = 1.5

    def make(self, path: Path, params: VehicleParams, dt: float) -> HumanDriver:
        return HumanDriver(path, params, dt, self.delay, self.lag, self.preview_time, self.gain_lateral)
