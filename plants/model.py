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

COMMANDS = ("steer", "yaw_moment", "speed_ref", "drive_on", "steer_rate")
"""Common commands every plant accepts (front road-wheel angle [rad], direct yaw
moment [N m], speed reference [m/s], 1 = hold speed with drive torque / 0 = coast,
rate of the road-wheel angle command [rad/s]: the feed-forward of a plant with a
steering servo; plants that take the angle directly ignore it)."""

DISTURBANCES = ("lateral_force", "yaw_moment_dist", "roll_moment_dist", "bank",
                "mu_fl", "mu_fr", "mu_rl", "mu_rr")
"""Common disturbance inputs: lateral force at the CG [N], yaw moment [N m], roll
moment [N m], road bank angle [rad] (positive = left side up, pushes the car to
the right), friction coefficient under each wheel [-]. Linear models ignore mu."""

TRUTH = ("vx", "vy", "beta", "yaw_rate", "yaw", "x", "y", "ax", "ay", "roll", "roll_rate",
         "wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")
"""Named outputs of every plant (ISO 8855, SI): body velocities, sideslip at the CG,
yaw rate and angle, position in the earth frame, kinematic accelerations of the CG
in the road plane (``ax = vx' - vy r``, ``ay = vy' + vx r``), body roll and roll
rate, wheel angular speeds [rad/s] (NaN where the model has no wheel radius)."""


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
