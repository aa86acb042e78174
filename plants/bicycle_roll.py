"""Single-track model with body roll, seed 004 eq. 1-9.

``M v_x (beta' + r) - M_s h_s phi'' = F_yf + F_yr + F_yd``        (004 eq. 1)
``I_z r' = F_yf l_f - F_yr l_r + N_z + N_zd``                      (004 eq. 2)
``I_x phi'' + C_x phi' + K_x phi = M_s h_s a_y + N_xd``            (004 eq. 3)

with linear tire forces (004 eq. 6-7) and ``a_y = v_x (beta' + r)``. Eq. 1 and 3
are coupled through ``phi''`` and ``a_y``; they are solved together. As in 004,
``K_x`` is the effective roll stiffness (the gravity moment ``M_s g h_s phi`` is
taken to be inside it). Positive roll (ISO 8855) lifts the left side, so a left
turn (``a_y > 0``) rolls the body positively.
"""

from __future__ import annotations

import numpy as np

from .backend import ops_for, unpack
from .bicycle import INPUTS, V_MIN, command_map, tire_forces
from .model import DISTURBANCES, PlantModel
from .params import G, VehicleParams, known

STATES = ("beta", "yaw_rate", "roll", "roll_rate", "yaw", "x", "y")
REQUIRED = ("sprung_mass", "roll_inertia", "roll_damping", "roll_stiffness", "roll_arm")


def _lateral(x, u, w, p: VehicleParams):
    o = ops_for(x, u, w)
    s, c, d = unpack(x, STATES), unpack(u, INPUTS), unpack(w, DISTURBANCES)
    vx = o.fmax(c.vx, V_MIN)
    fyf, fyr = tire_forces(s.beta, s.yaw_rate, c.steer, vx, p)
    fy = fyf + fyr + d.lateral_force - p.mass * G * o.sin(d.bank)
    ms, hs, kx, cx, ix = known(p, "sprung_mass", "roll_arm", "roll_stiffness", "roll_damping", "roll_inertia")
    msh = ms * hs
    # Solve [M, -msh; -msh, I_x] [a_y; phi''] = [F_y; M_roll] in closed form.
    m_roll = -cx * s.roll_rate - kx * s.roll + d.roll_moment_dist
    det = p.mass * ix - msh * msh
    ay = (ix * fy + msh * m_roll) / det
    roll_acc = (p.mass * m_roll + msh * fy) / det
    yaw_acc = (fyf * p.lf - fyr * p.lr + c.yaw_moment + d.yaw_moment_dist) / p.yaw_inertia
    return o, s, c, vx, ay, roll_acc, yaw_acc


def f(x, u, w, p: VehicleParams):
    """State derivative of the bicycle + roll model."""
    o, s, c, vx, ay, roll_acc, yaw_acc = _lateral(x, u, w, p)
    beta_dot = ay / vx - s.yaw_rate
    vy = c.vx * o.tan(s.beta)
    return o.stack([beta_dot, yaw_acc, s.roll_rate, roll_acc, s.yaw_rate,
                    c.vx * o.cos(s.yaw) - vy * o.sin(s.yaw), c.vx * o.sin(s.yaw) + vy * o.cos(s.yaw)])


def h(x, u, w, p: VehicleParams):
    o, s, c, vx, ay, roll_acc, yaw_acc = _lateral(x, u, w, p)
    vy = c.vx * o.tan(s.beta)
    zero = 0.0 * s.beta
    if p.wheel_radius is not None:
        wheels = [c.vx / p.wheel_radius + zero] * 4
    else:
        wheels = [zero + np.nan] * 4
    return o.stack([c.vx + zero, vy, s.beta, s.yaw_rate, s.yaw, s.x, s.y, -vy * s.yaw_rate, ay,
                    s.roll, s.roll_rate, *wheels])


def initial(p: VehicleParams, speed: float):
    return np.zeros(len(STATES))


MODEL = PlantModel(
    name="bicycle-roll", description="single-track model with body roll, seed 004 eq. 1-9",
    states=STATES, inputs=INPUTS, f=f, h=h, command_map=command_map, initial=initial,
    required_params=REQUIRED,
)
