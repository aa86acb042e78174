"""Linear single-track (bicycle) model of seed 003 eq. 1-3.

States ``beta`` (sideslip at the CG), ``yaw_rate``, ``yaw`` plus the earth-frame
position ``x``, ``y``; inputs front road-wheel angle ``steer``, direct yaw moment
``yaw_moment`` and the longitudinal speed ``vx`` (a scheduling input: the model is
linear in the lateral states for fixed speed).

Seed 003 eq. 10 misprints ``a_n11``; the correct entry, used here, is
``-2 (C_f + C_r) / (M v_x)`` as in seed 004 eq. 38.
"""

from __future__ import annotations

import numpy as np

from .backend import ops_for, unpack
from .lti import ContinuousLTI
from .model import COMMANDS, DISTURBANCES, TRUTH, PlantModel, brake_yaw_moment
from .params import G, VehicleParams
from .errors import ModelError

STATES = ("beta", "yaw_rate", "yaw", "x", "y")
INPUTS = ("steer", "yaw_moment", "vx")
V_MIN = 1.0
"""Below this speed [m/s] the bicycle model holds its 1/v_x terms at V_MIN: the
linear tire model has no meaning at standstill (use the two-track plant there)."""


def tire_forces(beta, yaw_rate, steer, vx, p: VehicleParams):
    """Axle lateral forces ``F_yf, F_yr`` [N] (seed 004 eq. 6-7, linear tires)."""
    fyf = -2.0 * p.cornering_stiffness_front * (beta + p.lf * yaw_rate / vx - steer)
    fyr = -2.0 * p.cornering_stiffness_rear * (beta - p.lr * yaw_rate / vx)
    return fyf, fyr


def f(x, u, w, p: VehicleParams):
    """State derivative of the bicycle model (seed 003 eq. 1-2 plus kinematics)."""
    o = ops_for(x, u, w)
    s, c, d = unpack(x, STATES), unpack(u, INPUTS), unpack(w, DISTURBANCES)
    vx = o.fmax(c.vx, V_MIN)
    fyf, fyr = tire_forces(s.beta, s.yaw_rate, c.steer, vx, p)
    fy = fyf + fyr + d.lateral_force - p.mass * G * o.sin(d.bank)
    beta_dot = fy / (p.mass * vx) - s.yaw_rate
    yaw_acc = (fyf * p.lf - fyr * p.lr + c.yaw_moment + d.yaw_moment_dist) / p.yaw_inertia
    vy = c.vx * o.tan(s.beta)
    x_dot = c.vx * o.cos(s.yaw) - vy * o.sin(s.yaw)
    y_dot = c.vx * o.sin(s.yaw) + vy * o.cos(s.yaw)
    return o.stack([beta_dot, yaw_acc, s.yaw_rate, x_dot, y_dot])


def h(x, u, w, p: VehicleParams):
    """Named truth outputs (see :data:`plants.model.TRUTH`)."""
    o = ops_for(x, u, w)
    s, c = unpack(x, STATES), unpack(u, INPUTS)
    xd = unpack(f(x, u, w, p), STATES)
    vy = c.vx * o.tan(s.beta)
    ay = c.vx * (xd.beta + s.yaw_rate)
    zero = 0.0 * s.beta
    if p.wheel_radius is not None:
        wf = c.vx / p.wheel_radius + zero
        wheels = [wf, wf, wf, wf]
    else:
        wheels = [zero + np.nan] * 4
    return o.stack([c.vx + zero, vy, s.beta, s.yaw_rate, s.yaw, s.x, s.y, -vy * s.yaw_rate, ay,
                    zero, zero, *wheels])


def command_map(cmd, x, p: VehicleParams):
    """Common commands -> (steer, yaw_moment, vx): the speed reference is the speed. The friction
    brakes add the yaw moment their torques make (:func:`plants.model.brake_yaw_moment`) where the
    vehicle file gives the tracks and the wheel radius, and nothing otherwise; the speed they take
    off is not modelled (the speed is the reference)."""
    o = ops_for(cmd, x)
    c = COMMANDS.unpack(cmd)
    nz = c.yaw_moment
    if all(v is not None for v in (p.track_front, p.track_rear, p.wheel_radius)):
        brakes = [o.fmax(b, 0.0) for b in (c.brake_fl, c.brake_fr, c.brake_rl, c.brake_rr)]
        nz = nz + brake_yaw_moment(brakes, p.wheel_radius, p.track_front, p.track_rear)
    return o.stack([c.steer, nz, c.speed_ref])


def initial(p: VehicleParams, speed: float):
    return np.zeros(len(STATES))


MODEL = PlantModel(
    name="bicycle", description="linear single-track model, seed 003 eq. 1-3",
    states=STATES, inputs=INPUTS, f=f, h=h, command_map=command_map, initial=initial,
)


def matrices(p: VehicleParams, vx: float) -> ContinuousLTI:
    """Continuous linear bicycle at speed ``vx`` [m/s] (seed 003 eq. 5-11, 004 eq. 38).

    States ``(beta, yaw_rate, yaw)``; inputs ``(steer, yaw_moment, lateral_force,
    yaw_moment_dist)``; outputs ``(beta, yaw_rate, yaw, course, ay)`` with
    ``course = yaw + beta`` (seed 003 eq. 3) and ``ay = vx (beta' + yaw_rate)``.
    """
    if not vx > 0.0:
        raise ModelError(f"the linear bicycle model needs a positive speed, got vx = {vx!r} m/s")
    m, iz = p.mass, p.yaw_inertia
    a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(p, vx)
    A = np.array([[a11, a12, 0.0], [a21, a22, 0.0], [0.0, 1.0, 0.0]])
    B = np.array([[b11, 0.0, 1.0 / (m * vx), 0.0],
                  [b21, b22, 0.0, 1.0 / iz],
                  [0.0, 0.0, 0.0, 0.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0],
                  [vx * a11, vx * (a12 + 1.0), 0.0]])
    D = np.zeros((5, 4))
    D[4] = vx * B[0]
    return ContinuousLTI(A=A, B=B, C=C, D=D, states=("beta", "yaw_rate", "yaw"),
                         inputs=("steer", "yaw_moment", "lateral_force", "yaw_moment_dist"),
                         outputs=("beta", "yaw_rate", "yaw", "course", "ay"))


def lateral_coefficients(p: VehicleParams, v):
    """a11, a12, a21, a22, b11, b21, b22 of the lateral bicycle model at speed ``v``.

    Seed 003 eq. 10-11 with 004 eq. 38's a11; written with plain arithmetic so it
    works on numbers and on casadi symbols. (b12 = 0: the yaw moment does not act
    on beta directly; b22 = 1 / I_z.)
    """
    m, iz, lf, lr = p.mass, p.yaw_inertia, p.lf, p.lr
    cf, cr = p.cornering_stiffness_front, p.cornering_stiffness_rear
    a11 = -2.0 * (cf + cr) / (m * v)
    a12 = -1.0 - 2.0 * (cf * lf - cr * lr) / (m * v * v)
    a21 = -2.0 * (cf * lf - cr * lr) / iz
    a22 = -2.0 * (cf * lf * lf + cr * lr * lr) / (iz * v)
    return a11, a12, a21, a22, 2.0 * cf / (m * v), 2.0 * cf * lf / iz, 1.0 / iz


def lateral_matrices(p: VehicleParams, v: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of ``(beta, r)' = A (beta, r) + B (delta_f, N_z)`` at speed ``v`` (seed 003 eq. 25)."""
    a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(p, v)
    return np.array([[a11, a12], [a21, a22]]), np.array([[b11, 0.0], [b21, b22]])


def steady_state_gains(p: VehicleParams, vx: float) -> tuple[float, float]:
    """Steady-state sideslip and yaw-rate per unit steer (seed 003 eq. 23-24).

    ``beta/delta = (1 - M l_f v^2 / (2 L C_r l_r)) l_r / (L (1 + G v^2))`` and
    ``r/delta = v / (L (1 + G v^2))``.

    Examples
    --------
    A 2 deg road-wheel step at 60 km/h: the yaw rate and sideslip a linear single-track car settles at.

    >>> import numpy as np
    >>> from evstab.plants import load_vehicle
    >>> from evstab.plants.bicycle import steady_state_gains
    >>> kb, kg = steady_state_gains(load_vehicle("compact-ev"), 60 / 3.6)
    >>> [round(float(np.degrees(k * np.radians(2.0))), 3) for k in (kg, kb)]  # deg/s, deg
    [10.217, -0.113]
    """
    L, g = p.wheelbase, p.stability_factor
    den = 1.0 + g * vx**2
    beta = (1.0 - p.mass / (2.0 * L) * p.lf / (p.cornering_stiffness_rear * p.lr) * vx**2) / den * p.lr / L
    return beta, vx / (L * den)


__all__ = ["MODEL", "lateral_coefficients", "lateral_matrices", "matrices", "steady_state_gains", "tire_forces", "TRUTH"]
