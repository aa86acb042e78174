"""Disturbance profiles: lateral wind, friction changes and split, road bank.

:func:`disturbance_profile` turns a :class:`Disturbances` description into the
(8, N) array of the common disturbance inputs (:data:`plants.model.DISTURBANCES`)
sampled at the simulation times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ManeuverError
from .model import DISTURBANCES
from .params import G, VehicleParams


@dataclass(frozen=True, kw_only=True)
class Wind:
    """Lateral wind gust: force [N] at the CG and yaw moment [N m], on between start and end [s].

    The gust ramps in and out over ``ramp`` s (raised cosine). Positive force pushes
    the car to the left. Seed 003 applies its wind from 4 to 8 s without giving a
    magnitude; :func:`default_wind` scales one to the vehicle.
    """

    start: float = 4.0
    end: float = 8.0
    force: float
    yaw_moment: float
    ramp: float = 0.2

    def __post_init__(self) -> None:
        if not self.end > self.start:
            raise ManeuverError(f"wind: end ({self.end} s) must be after start ({self.start} s)")

    def envelope(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        up = np.clip((t - self.start) / self.ramp, 0.0, 1.0)
        down = np.clip((self.end - t) / self.ramp, 0.0, 1.0)
        u = np.minimum(up, down)
        return 0.5 * (1.0 - np.cos(np.pi * u))


def default_wind(p: VehicleParams, start: float = 4.0, end: float = 8.0) -> Wind:
    """A side gust of 5 % of the vehicle weight acting 0.3 m ahead of the CG (evstab's choice)."""
    force = 0.05 * p.mass * G
    return Wind(start=start, end=end, force=force, yaw_moment=0.3 * force)


@dataclass(frozen=True, kw_only=True)
class Friction:
    """Tire-road friction: uniform ``mu``; optionally changed to ``mu_after`` at ``change_at`` [s];
    optionally split with ``mu_left``/``mu_right`` for the left/right wheels."""

    mu: float = 1.0
    mu_after: float | None = None
    change_at: float | None = None
    mu_left: float | None = None
    mu_right: float | None = None

    def __post_init__(self) -> None:
        for name in ("mu", "mu_after", "mu_left", "mu_right"):
            v = getattr(self, name)
            if v is not None and not (0.0 < v <= 2.0):
                raise ManeuverError(f"friction: '{name}' = {v!r} is outside (0, 2]")
        if (self.mu_after is None) != (self.change_at is None):
            raise ManeuverError("friction: give both 'mu_after' and 'change_at' or neither")

    def per_wheel(self, t: np.ndarray) -> np.ndarray:
        """(4, N) friction under FL, FR, RL, RR."""
        t = np.asarray(t, float)
        base = np.full_like(t, self.mu)
        if self.mu_after is not None:
            base = np.where(t >= self.change_at, self.mu_after, base)
        left = base if self.mu_left is None else np.full_like(t, self.mu_left)
        right = base if self.mu_right is None else np.full_like(t, self.mu_right)
        return np.stack([left, right, left, right])


@dataclass(frozen=True, kw_only=True)
class Disturbances:
    """Everything the environment does to the car during a run."""

    wind: Wind | None = None
    friction: Friction = Friction()
    bank: float = 0.0
    """Road bank angle [rad], positive = left side up (pushes the car to the right)."""


def disturbance_profile(d: Disturbances, t: np.ndarray) -> np.ndarray:
    """(len(DISTURBANCES), N) array of disturbance inputs at times ``t``."""
    t = np.asarray(t, float)
    out = np.zeros((len(DISTURBANCES), len(t)))
    if d.wind is not None:
        env = d.wind.envelope(t)
        out[DISTURBANCES.index("lateral_force")] = d.wind.force * env
        out[DISTURBANCES.index("yaw_moment_dist")] = d.wind.yaw_moment * env
    out[DISTURBANCES.index("bank")] = d.bank
    out[DISTURBANCES.span("mu_fl", "mu_rr")] = d.friction.per_wheel(t)
    return out
