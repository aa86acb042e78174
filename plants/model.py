"""The plant-model container shared by every vehicle model.

A :class:`PlantModel` bundles the dynamics ``f(x, u, w, p)`` (written once,
numpy or casadi), the named outputs ``h(x, u, w, p)`` the sensors and logs read,
and the map from the common driver/controller commands to the model's own
physical inputs. Signals are named; nobody indexes ``x[3]`` by hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from .backend import unpack
from .errors import ModelError
from .lti import ContinuousLTI
from .params import VehicleParams
from .signals import Layout, Signal

COMMANDS = Layout("plant commands", [
    Signal("steer", "rad", "front road-wheel angle"),
    Signal("yaw_moment", "N m", "direct yaw moment"),
    Signal("speed_ref", "m/s", "speed reference"),
    Signal("drive_on", "-", "1 = hold speed with drive torque, 0 = coast"),
    Signal("steer_rate", "rad/s", "rate of the road-wheel angle command"),
    *(Signal(f"brake_{c}", "N m", f"friction brake torque at the {c} wheel (>= 0; opposes its spin)", default=0.0)
      for c in ("fl", "fr", "rl", "rr")),
])
"""Common commands every plant accepts (front road-wheel angle [rad], direct yaw
moment [N m], speed reference [m/s], 1 = hold speed with drive torque / 0 = coast,
rate of the road-wheel angle command [rad/s]: the feed-forward of a plant with a
steering servo; plants that take the angle directly ignore it), and the friction brake torque at
each wheel [N m] (0 when not given; a negative one counts as 0; it opposes the wheel's spin and
never drives a wheel backwards: see each plant)."""

DISTURBANCES = Layout("disturbances", [
    Signal("lateral_force", "N", "lateral force at the CG"),
    Signal("yaw_moment_dist", "N m", "yaw moment"),
    Signal("roll_moment_dist", "N m", "roll moment"),
    Signal("bank", "rad", "road bank angle, + left side up"),
    *(Signal(f"mu_{c}", "-", f"friction coefficient under the {c} wheel") for c in ("fl", "fr", "rl", "rr")),
])
"""Common disturbance inputs: lateral force at the CG [N], yaw moment [N m], roll
moment [N m], road bank angle [rad] (positive = left side up, pushes the car to
the right), friction coefficient under each wheel [-]. Linear models ignore mu."""

TRUTH = Layout("plant outputs", [
    Signal("vx", "m/s", "body longitudinal velocity"), Signal("vy", "m/s", "body lateral velocity"),
    Signal("beta", "rad", "sideslip at the CG"), Signal("yaw_rate", "rad/s", "yaw rate"),
    Signal("yaw", "rad", "yaw angle"), Signal("x", "m", "east position"), Signal("y", "m", "north position"),
    Signal("ax", "m/s^2", "longitudinal acceleration"), Signal("ay", "m/s^2", "lateral acceleration"),
    Signal("roll", "rad", "body roll"), Signal("roll_rate", "rad/s", "roll rate"),
    *(Signal(f"wheel_speed_{c}", "rad/s", f"{c} wheel angular speed") for c in ("fl", "fr", "rl", "rr")),
])
"""Named outputs of every plant (ISO 8855, SI): body velocities, sideslip at the CG,
yaw rate and angle, position in the earth frame, kinematic accelerations of the CG
in the road plane (``ax = vx' - vy r``, ``ay = vy' + vx r``), body roll and roll
rate, wheel angular speeds [rad/s] (NaN where the model has no wheel radius)."""


def torque_difference(yaw_moment, wheel_radius, track_rear):
    """The rear wheels' torque difference ``T_rr - T_mean = T_mean - T_rl`` [N m] that makes
    ``yaw_moment`` [N m]: ``N_z = (T_rr - T_rl) t_r / (2 R_w)`` (a wheel torque ``T`` is a force
    ``T / R_w`` at the contact patch, ``t_r / 2`` from the centre line). The one torque split of
    the plants, the actuators and the ECU."""
    return yaw_moment * wheel_radius / track_rear


def brake_yaw_moment(brakes, wheel_radius, track_front, track_rear):
    """The yaw moment [N m] the friction brake torques ``(fl, fr, rl, rr)`` [N m] make on a car going
    forward at small slip angles: a brake torque ``T`` is a force ``-T / R_w`` at the contact patch,
    ``+-t / 2`` from the centre line (left positive, ISO 8855), so braking a left wheel turns the car
    left: ``N_z = ((T_fl - T_fr) t_f + (T_rl - T_rr) t_r) / (2 R_w)`` (the motors' rule,
    :func:`torque_difference`, with the sign of a brake)."""
    fl, fr, rl, rr = brakes
    return ((fl - fr) * track_front + (rl - rr) * track_rear) / (2.0 * wheel_radius)


def yaw_moment_of(torque_diff, wheel_radius, track_rear):
    """The yaw moment [N m] a rear torque difference [N m] makes (the inverse of :func:`torque_difference`)."""
    return torque_diff * track_rear / wheel_radius


@dataclass(frozen=True)
class PlantModel:
    """One vehicle model: dynamics, outputs and command map with named signals."""

    name: str
    description: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    f: Callable
    h: Callable
    command_map: Callable
    initial: Callable
    required_params: tuple[str, ...] = ()
    max_step: Callable | None = None
    """``max_step(p) -> h``: the largest RK4 step [s] the stiffest mode allows (None: any)."""

    def check_params(self, p: VehicleParams) -> None:
        p.require(*self.required_params, model=f"the '{self.name}' plant")

    def initial_state(self, p: VehicleParams, speed: float) -> np.ndarray:
        """Straight-line equilibrium-ish start at ``speed`` [m/s]."""
        return np.asarray(self.initial(p, float(speed)), dtype=float)

    def state_index(self, name: str) -> int:
        try:
            return self.states.index(name)
        except ValueError:
            raise ModelError(f"'{self.name}' has no state '{name}'; states: {', '.join(self.states)}") from None

    def unpack_state(self, x):
        return unpack(x, self.states)

    # -------------------------------------------------------- linearisation
    def linearize(self, p: VehicleParams, x0, u0, w0=None, outputs=("beta", "yaw_rate", "yaw")) -> ContinuousLTI:
        """Jacobian linearisation (casadi AD) about ``(x0, u0, w0)``.

        Inputs of the result are the model inputs followed by the common
        disturbances; outputs are the named truth outputs given.
        """
        x = ca.SX.sym("x", len(self.states))
        u = ca.SX.sym("u", len(self.inputs))
        w = ca.SX.sym("w", len(DISTURBANCES))
        w0 = default_disturbance() if w0 is None else np.asarray(w0, float)
        xdot = self.f(x, u, w, p)
        y = self.h(x, u, w, p)
        iy = [TRUTH.index(o) for o in outputs]
        y = ca.vertcat(*[y[i] for i in iy])
        uw = ca.vertcat(u, w)
        jac = ca.Function("linearization", [x, u, w], [ca.jacobian(xdot, x), ca.jacobian(xdot, uw),
                                            ca.jacobian(y, x), ca.jacobian(y, uw)])
        A, B, C, D = (np.array(m) for m in jac(np.asarray(x0, float), np.asarray(u0, float), w0))
        return ContinuousLTI(A=A, B=B, C=C, D=D, states=self.states, inputs=self.inputs + DISTURBANCES,
                             outputs=tuple(outputs))


def default_disturbance(mu: float = 1.0) -> np.ndarray:
    """No wind, no bank, uniform friction ``mu``."""
    return np.array([0.0, 0.0, 0.0, 0.0, mu, mu, mu, mu])
