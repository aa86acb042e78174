"""Seed 000's two-stage Kalman filter: heading first, then body velocities; sideslip from them.

KF1, states ``(psi, b_g)``: ``psi' = r_gyro - b_g`` (gyro as input), the dual-antenna GPS
heading as measurement at each fix that has one; gives heading and gyro bias.

KF2, states ``(v_x, v_y, b_ax, b_ay)``: the body-frame kinematics with KF1's yaw rate
``r = r_gyro - b_g``:

    v_x' = a_x - b_ax + r v_y,        v_y' = a_y - b_ay - r v_x,

accelerometer biases as random walks, and the GPS velocity turned into the body frame
with KF1's heading as measurements at each fix: ``v_x,GPS = V cos(nu - psi)``,
``v_y,GPS = V sin(nu - psi)`` (``V`` ground speed, ``nu`` course). Sideslip
``beta = atan2(v_y, v_x)`` at the GPS antenna's reference point (the body origin here);
:func:`sideslip_at` moves it to any point of the body (000 eq. 28-29:
``V_P = V_A + gamma x R_AP``). The lateral accelerometer reads gravity through body roll
and road bank; the bias state takes the slow part of it.

State vector: ``psi, b_g, P1 (2 x 2), v_x, v_y, b_ax, b_ay, P2 (4 x 4), init``, column-major.
"""

from __future__ import annotations

import numpy as np

from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal
from .core import column as _col, predict, scalar_update
from .kalman import INPUTS, outputs, wrap
from .kkf import heading_predict
from .spec import FilterDesign

STATE = Layout("two-stage state", [
    Signal("x1", "-", "KF1: heading [rad], gyro bias [rad/s]", 2), Signal("P1", "-", "its covariance", 4),
    Signal("x2", "-", "KF2: v_x, v_y [m/s], accelerometer biases [m/s^2]", 4), Signal("P2", "-", "its covariance", 16),
    Signal("init", "-", "1 once the heading is initialised"),
])
STATE_SIZE = STATE.size
NEEDS = ("ax", "ay", "gps_speed", "gps_heading")


def initial_state(d: FilterDesign) -> np.ndarray:
    return STATE.pack(x1=np.zeros(2), P1=np.diag([np.pi ** 2, 0.01 ** 2]).ravel(order="F"), x2=np.zeros(4),
                      P2=np.diag([1.0, 1.0, 0.5 ** 2, 0.5 ** 2]).ravel(order="F"), init=0.0)


def sideslip_at(vx, vy, r, x: float, y: float = 0.0):
    """Sideslip at body point (x forward, y left, from the reference point) of a body moving with
    (vx, vy) at the reference point and yaw rate r: ``atan2(vy + r x, vx - r y)``."""
    return np.arctan2(np.asarray(vy) + np.asarray(r) * x, np.asarray(vx) - np.asarray(r) * y)


def step(d: FilterDesign, z, u, o=NUMPY):
    nz = d.noise
    g = INPUTS.as_dict(u)
    dt, gyro, fix, v = g["dt"], g["yaw_rate"], g["fix"], g["speed"]
    sats = g["sats"]
    # ---- KF1: heading and gyro bias
    zs = STATE.unpack(z)
    x1 = zs.x1
    P1 = o.reshape(zs.P1, 2, 2)
    x1, P1 = heading_predict(x1, P1, gyro, dt, nz.gyro_std, nz.q_bias, o)
    have_h = (g["heading_valid"] > 0.5) * (sats >= 4)
    heading = g["heading"]
    init = zs.init
    first = have_h * (init < 0.5)
    h1 = _col([1.0, 0.0], o)
    x1u, P1u, _, _ = scalar_update(x1, P1, h1, wrap(heading - x1[0], o), nz.heading_std ** 2, o, 2,
                                   gate=have_h * (1.0 - first))
    x1_first = o.stack([heading, x1[1]])
    x1 = o.if_else(first > 0.5, x1_first, x1u)
    P1f = o.zeros(2, 2)
    P1f[0, 0] = nz.heading_std ** 2
    P1f[1, 1] = P1u[1, 1]
    P1 = o.if_else(first > 0.5, P1f, P1u)
    psi, r = x1[0], gyro - x1[1]
    # ---- KF2: body velocities and accelerometer biases
    x2 = zs.x2
    P2 = o.reshape(zs.P2, 4, 4)
    ax, ay = g["ax"], g["ay"]
    F2 = o.eye(4) + o.zeros(4, 4)
    F2[0, 1], F2[0, 2] = r * dt, -dt
    F2[1, 0], F2[1, 3] = -r * dt, -dt
    Q2 = o.zeros(4, 4)
    Q2[0, 0] = Q2[1, 1] = (nz.accel_std * dt) ** 2 + nz.q_velocity * dt
    Q2[2, 2] = Q2[3, 3] = nz.q_accel_bias * dt
    # linear in the state for the yaw rate r of KF1, the accelerometers inputs
    x2, P2 = predict(x2, P2, F2, Q2, o, 4, w=o.stack([ax * dt, ay * dt, 0.0 * dt, 0.0 * dt]))
    usable = (fix > 0.5) * (sats >= 4) * (v >= nz.gps_min_speed) * (init > 0.5)
    speed_g = o.if_else(usable > 0.5, g["gps_speed"], 0.0 * v)
    course = g["course"]
    ang = course - psi
    meas = (speed_g * o.cos(ang), speed_g * o.sin(ang))
    r_v = nz.gps_velocity_std ** 2 * g["hdop"] ** 2
    for i in range(2):
        h = _col(np.eye(4)[i], o)
        x2, P2, _, _ = scalar_update(x2, P2, h, meas[i] - x2[i], r_v, o, 4, gate=usable)
    beta = o.arctan2(x2[1], o.fmax(x2[0], 0.1))
    init_n = o.fmax(init, have_h)
    z_next = STATE.pack(o=o, x1=x1, P1=o.flatten(P1), x2=x2, P2=o.flatten(P2), init=init_n)
    y = outputs(o, v, beta=beta, yaw_rate=r, yaw=psi, gyro_bias=x1[1], gps_used=usable, bias_alarm=0.0 * v,
                vx=x2[0], vy=x2[1])
    return z_next, y
