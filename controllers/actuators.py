"""Actuators: active front steering (steer-by-wire) and the two rear in-wheel motors.

* Steer: first-order lag ``tau`` towards the command, then rate limit and angle
  limit (road-wheel angle).
* Motors: the direct yaw moment is made by the rear torque difference,
  ``N_z = (T_rr - T_rl) t_r / (2 R_w)``, on top of the driver's longitudinal
  demand ``T_rl + T_rr = 2 T_mean``, which is kept. Each motor has a torque limit
  and a torque-rate limit; what cannot be realised is reported
  (``yaw_moment_achieved`` and the ``yaw_moment_limited`` flag), never dropped
  silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plants import VehicleParams


@dataclass(frozen=True)
class ActuatorLimits:
    steer_tau: float = 0.03
    """Front steer actuator time constant [s]."""
    steer_max: float = np.deg2rad(35.0)
    """Road-wheel angle limit [rad]."""
    steer_rate_max: float = np.deg2rad(60.0)
    """Road-wheel angle rate limit [rad/s]."""
    torque_max: float | None = None
    """Per-motor torque limit at the wheel [N m]; default the vehicle's max_motor_torque."""
    torque_rate_max: float = 10000.0
    """Per-motor torque rate limit [N m/s]."""


def allocate(yaw_moment: float, t_mean: float, p: VehicleParams, torque_max: float) -> dict:
    """Split a yaw moment over the rear motors, keeping the longitudinal demand.

    Returns ``torque_rl``, ``torque_rr``, ``yaw_moment_achieved`` and ``limited``.
    The torque difference is cut to what the per-wheel limit leaves after the
    common-mode torque ``t_mean`` (itself clipped to the limit first).
    """
    t_mean = float(np.clip(t_mean, -torque_max, torque_max))
    dt_req = yaw_moment * p.wheel_radius / p.track_rear
    room = torque_max - abs(t_mean)
    dt_ach = float(np.clip(dt_req, -room, room))
    return {"torque_rl": t_mean - dt_ach, "torque_rr": t_mean + dt_ach,
            "yaw_moment_achieved": dt_ach * p.track_rear / p.wheel_radius,
            "limited": bool(abs(dt_ach - dt_req) > 1e-9 * max(1.0, abs(dt_req)))}


class Actuators:
    """Steer and yaw-moment actuators in the step protocol.

    Signals in: ``steer`` and ``yaw_moment`` commands, ``t_mean`` (the driver's
    mean rear torque, 0 when coasting), ``dt``. Outputs: applied ``steer``,
    ``yaw_moment`` (achieved), ``torque_rl``, ``torque_rr`` and the limit flags.
    """

    def __init__(self, params: VehicleParams, limits: ActuatorLimits = ActuatorLimits()):
        self.p, self.lim = params, limits
        self.torque_max = limits.torque_max if limits.torque_max is not None else (params.max_motor_torque or 1e9)

    def initial_state(self, steer0: float = 0.0):
        return (float(steer0), 0.0)

    def step(self, state, t, s):
        steer, t_diff = state
        dt = s["dt"]
        lim = self.lim
        target = float(np.clip(s["steer"], -lim.steer_max, lim.steer_max))
        rate = (target - steer) / lim.steer_tau
        rate_c = float(np.clip(rate, -lim.steer_rate_max, lim.steer_rate_max))
        steer_new = float(np.clip(steer + dt * rate_c, -lim.steer_max, lim.steer_max))
        steer_limited = abs(s["steer"]) > lim.steer_max or abs(rate) > lim.steer_rate_max
        alloc = allocate(s["yaw_moment"], s.get("t_mean", 0.0), self.p, self.torque_max)
        want = (alloc["torque_rr"] - alloc["torque_rl"]) / 2.0
        step_max = lim.torque_rate_max * dt
        t_diff_new = float(np.clip(want, t_diff - step_max, t_diff + step_max))
        achieved = t_diff_new * self.p.track_rear / self.p.wheel_radius
        limited = alloc["limited"] or abs(t_diff_new - want) > 1e-9 * max(1.0, abs(want))
        out = {"steer": steer_new, "yaw_moment": achieved, "steer_limited": float(steer_limited),
               "yaw_moment_limited": float(limited), "yaw_moment_cmd": s["yaw_moment"]}
        return (steer_new, t_diff_new), out
