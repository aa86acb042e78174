"""Actuators: active front steering (a superposition gear) and the two rear in-wheel motors.

* Steer: the driver's angle reaches the road wheels through the column as it is; the gear adds
  the ECU's correction (its ``steer_correction`` output: the command less the driver's angle as the
  ECU read it) through a first-order lag ``tau`` and a rate limit,
  and the sum is held within the road-wheel angle limit (at the limit the gear's angle is what
  the rack leaves it). A passive ECU asks no correction at all and leaves the car exactly as
  the driver drives it, whatever it read of the driver's angle. ``superposition=False`` models a
  steer-by-wire servo of the whole angle instead (lag and rate limit on the driver's steer too).
* Motors: the direct yaw moment is made by the rear torque difference,
  ``N_z = (T_rr - T_rl) t_r / (2 R_w)``, on top of the driver's longitudinal
  demand ``T_rl + T_rr = 2 T_mean``, which is kept (clipped to the limit); the
  difference is cut to the room each wheel has left. Each motor has a torque limit
  and a torque-rate limit; what cannot be realised is reported (the achieved yaw
  moment and the ``yaw_moment_limited`` flag), never dropped silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.backend import NUMPY
from evstab.plants.model import torque_difference, yaw_moment_of
from evstab.plants.signals import Layout, Signal


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
    superposition: bool = True
    """Active front steering by a superposition gear: the driver's angle reaches the wheels through the column
    as it is, and the actuator (its lag and rate limit) makes only the correction the command asks beyond it."""


STATE = Layout("actuator state", [
    Signal("steer", "rad", "road-wheel angle of the steer actuator"),
    Signal("torque_diff", "N m", "the rear motors' torque difference, T_rr - T_mean"),
])
SIGNALS = Layout("actuator commands", [
    Signal("steer_cmd", "rad", "road-wheel angle command"),
    Signal("steer_driver", "rad", "the driver's road-wheel angle through the column"),
    Signal("steer_correction", "rad", "the correction the ECU asks of the superposition gear"),
    Signal("yaw_moment_cmd", "N m", "yaw moment command"),
    Signal("t_mean", "N m", "the driver's mean rear torque per wheel"),
    Signal("dt", "s", "the period"),
])
OUTPUTS = Layout("actuator outputs", [
    Signal("steer", "rad", "road-wheel angle applied"),
    Signal("yaw_moment", "N m", "yaw moment the motors achieved"),
    Signal("steer_limited", "-", "1 while the steer was at a limit"),
    Signal("yaw_moment_limited", "-", "1 while the motors were at a limit"),
])



def actuator_law(p: VehicleParams, lim: ActuatorLimits, torque_max: float, z, sig, o=NUMPY):
    """One sample of the steer and motor actuators, numpy or casadi: ``(z, sig) -> (z_next, out)``."""
    zs = STATE.unpack(z)
    steer, t_diff = zs.steer, zs.torque_diff
    s = SIGNALS.unpack(sig)
    # the superposition gear makes the ECU's correction on top of the column's angle (a driver's angle the ECU
    # misread reaches the wheels as the driver steers it); a whole-angle servo follows the command
    asked = s.steer_driver + s.steer_correction if lim.superposition else s.steer_cmd
    target = o.fmin(o.fmax(asked, -lim.steer_max), lim.steer_max)
    base = s.steer_driver if lim.superposition else 0.0 * target
    rate = (target - base - steer) / lim.steer_tau
    rate_c = o.fmin(o.fmax(rate, -lim.steer_rate_max), lim.steer_rate_max)
    steer_new = o.fmin(o.fmax(base + (steer + s.dt * rate_c), -lim.steer_max), lim.steer_max)
    steer_limited = o.if_else(o.fabs(asked) > lim.steer_max, 1.0,
                              o.if_else(o.fabs(rate) > lim.steer_rate_max, 1.0, 0.0))
    # allocation (as :func:`allocate`): common torque kept, difference cut to the room left
    t_mean = o.fmin(o.fmax(s.t_mean, -torque_max), torque_max)
    dt_req = torque_difference(s.yaw_moment_cmd, p.wheel_radius, p.track_rear)
    room = torque_max - o.fabs(t_mean)
    want = o.fmin(o.fmax(dt_req, -room), room)
    step_max = lim.torque_rate_max * s.dt
    t_diff_new = o.fmin(o.fmax(want, t_diff - step_max), t_diff + step_max)
    cut = o.fabs(want - dt_req) > 1e-9 * o.fmax(1.0, o.fabs(dt_req))
    slow = o.fabs(t_diff_new - want) > 1e-9 * o.fmax(1.0, o.fabs(want))
    limited = o.if_else(cut, 1.0, o.if_else(slow, 1.0, 0.0))
    achieved = yaw_moment_of(t_diff_new, p.wheel_radius, p.track_rear)
    return STATE.pack(o=o, steer=steer_new - base, torque_diff=t_diff_new), \
        OUTPUTS.pack(o=o, steer=steer_new, yaw_moment=achieved, steer_limited=steer_limited, yaw_moment_limited=limited)
