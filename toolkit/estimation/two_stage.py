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
from .kalman import INPUTS, _col, scalar_update, wrap
from .spec import FilterDesign

STATE_SIZE = 2 + 4 + 4 + 16 + 1
NEEDS = ("ax", "ay", "gps_speed", "gps_heading")


def initial_state(d: FilterDesign) -> np.ndarray:
    z = np.zeros(STATE_SIZE)
    z[2:6] = np.diag([np.pi ** 2, 0.01 ** 2]).ravel(order="F")
    z[10:26] = np.diag([1.0, 1.0, 0.5 ** 2, 0.5 ** 2]).ravel(order="F")
    return z


def sideslip_at(vx, vy, r, x: float, y: float = 0.0):
    """Sideslip at body point (x forward, y left, from the reference point) of a body moving with
    (vx, vy) at the reference point and yaw rate r: ``atan2(vy + r x, vx - r y)``."""
    return np.arctan2(np.asarray(vy) + np.asarray(r) * x, np.asarray(vx) - np.asarray(r) * y)


def step(d: FilterDesign, z, u, o=NUMPY):
    nz = d.noise
    g = {name: u[i] for i, name in enumerate(INPUTS)}
    dt, gyro, fix, v = g["dt"], g["yaw_rate"], g["fix"], g["speed"]
    sats = g["sats"]
    # ---- KF1: heading and gyro bias
    x1 = z[0:2]
    P1 = o.reshape(z[2:6], 2, 2)
    rate = gyro - x1[1]
    F1 = o.eye(2) + o.zeros(2, 2)
    F1[0, 1] = -dt
    x1 = o.stack([x1[0] + rate * dt, x1[1]])
    Q1 = o.zeros(2, 2)
    Q1[0, 0] = (nz.gyro_std * dt) ** 2
    Q1[1, 1] = nz.q_bias * dt
    P1 = F1 @ P1 @ F1.T + Q1
    have_h = (g["heading_valid"] > 0.5) * (sats >= 4)
    heading = g["heading"]
    init = z[26]
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
    x2 = z[6:10]
    P2 = o.reshape(z[10:26], 4, 4)
    ax, ay = g["ax"], g["ay"]
    vx, vy, bx, by = x2[0], x2[1], x2[2], x2[3]
    x2 = o.stack([vx + (ax - bx + r * vy) * dt, vy + (ay - by - r * vx) * dt, bx, by])
    F2 = o.eye(4) + o.zeros(4, 4)
    F2[0, 1], F2[0, 2] = r * dt, -dt
    F2[1, 0], F2[1, 3] = -r * dt, -dt
    Q2 = o.zeros(4, 4)
    Q2[0, 0] = Q2[1, 1] = (nz.accel_std * dt) ** 2 + nz.q_velocity * dt
    Q2[2, 2] = Q2[3, 3] = nz.q_accel_bias * dt
    P2 = F2 @ P2 @ F2.T + Q2
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
    z_next = o.concat([x1, o.flatten(P1), x2, o.flatten(P2), o.stack([init_n])])
    nan = float("nan")
    zero = 0.0 * v
    y = o.stack([beta, r, psi, zero + nan, zero + nan, zero + nan, x1[1], usable, zero + nan, zero,
                 zero + nan, zero + nan, x2[0], x2[1], zero + nan])
    return z_next, y
