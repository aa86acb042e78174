"""Seed 002's dual-antenna GPS/INS estimator: lateral velocity, heading and total roll with sensor biases.

States ``(u_y, b_ay, psi, b_r, phi_t, b_p)``: body lateral velocity, lateral-accelerometer
bias, heading, yaw-gyro bias, total roll ``phi_t`` = road bank + body roll, roll-gyro
bias. The INS readings are inputs (002 eq. 3, the roll-centre model on a road side
slope, with the small terms ``c r'`` and ``h phi''`` left to the process noise):

    u_y' = a_y,m - (r_m - b_r) u_x - g phi_t - b_ay,
    psi' = r_m - b_r,        phi_t' = p_m - b_p,

``u_x`` the wheels' speed. At each fix the dual antenna measures heading and total roll
(002 eq. 5: the roll from a lateral baseline), and the velocity direction gives
``nu = psi + (u_y - h_a p) / U`` (002 eq. 6-9, small angles; ``h_a`` the antenna's height
above the roll centre, 0 unless given: the simulator's antenna has no height).
Sideslip ``beta = atan2(u_y, u_x)``; the tire slip angles follow from it (docs/models.md
signs: ``alpha_f = delta - beta - l_f r / u_x``, ``alpha_r = -beta + l_r r / u_x``) and
:mod:`toolkit.estimation.identify` turns them and the lateral acceleration into the
cornering stiffness. Bank and body roll cannot be told apart by these measurements
(002: only their sum is observable); the filter does not try.

State vector: ``x`` (6), ``P`` (6 x 6, column-major), ``init``.
"""

from __future__ import annotations

import numpy as np

from evstab.plants.backend import NUMPY
from evstab.plants.params import G
from evstab.plants.signals import Layout, Signal
from .core import column as _col, predict, scalar_update
from .kalman import INPUTS, outputs, wrap
from .spec import FilterDesign


def bank_estimate(p, roll_total, speed, yaw_rate):
    """Road bank from the total roll less the body roll of the roll model in steady state
    (seed 004 eq. 3 with ``phi'' = phi' = 0``: ``K_x phi = M_s h_s a_y``, ``a_y = v r``): 002 eq. 7's
    separation of the two angles by the vehicle's dynamics."""
    body = p.sprung_mass * p.roll_arm * np.asarray(speed, float) * np.asarray(yaw_rate, float) / p.roll_stiffness
    return np.asarray(roll_total, float) - body

N = 6
STATE = Layout("dual-antenna state", [
    Signal("x", "-", "u_y [m/s], b_ay [m/s^2], psi [rad], b_r [rad/s], phi_t [rad], b_p [rad/s]", N),
    Signal("P", "-", "its covariance, column-major", N * N), Signal("init", "-", "1 once the heading is set")])
STATE_SIZE = STATE.size
NEEDS = ("ay", "roll_rate", "gps_speed", "gps_heading")
"""Columns the filter needs; ``gps_roll`` (a third antenna's total roll) is used where present."""


def initial_state(d: FilterDesign) -> np.ndarray:
    P0 = np.diag([1.0, 0.5 ** 2, np.pi ** 2, 0.01 ** 2, np.radians(5.0) ** 2, 0.01 ** 2])
    return STATE.pack(x=np.zeros(N), P=P0.ravel(order="F"), init=0.0)


def step(d: FilterDesign, z, u, o=NUMPY):
    nz = d.noise
    g = INPUTS.as_dict(u)
    dt, ux, gyro, ay, pm = g["dt"], g["speed"], g["yaw_rate"], g["ay"], g["roll_rate"]
    zs = STATE.unpack(z)
    x = zs.x
    P = o.reshape(zs.P, N, N)
    init = zs.init
    uy, bay, psi, br, phi, bp = (x[i] for i in range(N))
    r = gyro - br
    ux_m = o.fmax(ux, nz.min_speed)
    F = o.eye(N) + o.zeros(N, N)
    F[0, 1], F[0, 3], F[0, 4] = -dt, ux * dt, -G * dt
    F[2, 3] = -dt
    F[4, 5] = -dt
    Q = o.zeros(N, N)
    Q[0, 0] = (nz.accel_std * dt) ** 2 + nz.q_velocity * dt
    Q[1, 1] = nz.q_accel_bias * dt
    Q[2, 2] = (nz.gyro_std * dt) ** 2
    Q[3, 3] = nz.q_bias * dt
    Q[4, 4] = (nz.gyro_std * dt) ** 2
    Q[5, 5] = nz.q_bias * dt
    # the nonlinear kinematics propagate the state, their Jacobian F the covariance
    x_next = o.stack([uy + (ay - r * ux - G * phi - bay) * dt, bay, psi + r * dt, br, phi + (pm - bp) * dt, bp])
    _, P = predict(x, P, F, Q, o, N)
    x = x_next
    sats_ok = g["sats"] >= 4
    have_h = (g["heading_valid"] > 0.5) * sats_ok
    have_r = (g["gps_roll_valid"] > 0.5) * sats_ok
    first = have_h * (init < 0.5)
    # the first heading sets psi outright (any heading error would otherwise reach u_y)
    e2 = _col(np.eye(N)[2], o)
    keep = _col(1.0 - np.eye(N)[2], o)
    x = x + e2 * (first * wrap(g["heading"] - x[2], o))
    P = o.if_else(first > 0.5, P * o.outer(keep, keep) + o.outer(e2, e2) * nz.heading_std ** 2, P)
    x, P, _, _ = scalar_update(x, P, e2, wrap(g["heading"] - x[2], o), nz.heading_std ** 2, o, N,
                               gate=have_h * (1.0 - first))
    e4 = _col(np.eye(N)[4], o)
    x, P, _, _ = scalar_update(x, P, e4, g["gps_roll"] - x[4], nz.roll_std ** 2, o, N, gate=have_r)
    # the velocity direction: nu = psi + (u_y - h_a (p_m - b_p)) / U
    U = o.fmax(g["gps_speed"], nz.gps_min_speed)
    usable = (g["fix"] > 0.5) * sats_ok * (g["gps_speed"] >= nz.gps_min_speed) * (init > 0.5)
    ha = nz.antenna_height
    hc = _col([1.0, 0.0, 0.0, 0.0, 0.0, 0.0], o) * (1.0 / U) + e2 + _col(np.eye(N)[5], o) * (ha / U)
    pred = x[2] + (x[0] - ha * (pm - x[5])) / U
    r_c = (nz.gps_velocity_std * g["hdop"] / U) ** 2
    x, P, _, _ = scalar_update(x, P, hc, wrap(g["course"] - pred, o), r_c, o, N, gate=usable)
    init_n = o.fmax(init, have_h)
    z_next = STATE.pack(o=o, x=x, P=o.flatten(P), init=init_n)
    beta = o.arctan2(x[0], ux_m)
    y = outputs(o, ux, beta=beta, yaw_rate=gyro - x[3], yaw=x[2], beta_std=o.sqrt(o.fmax(P[0, 0], 0.0)) / ux_m,
                gyro_bias=x[3], gps_used=usable, bias_alarm=0.0 * ux, vx=ux + 0.0 * ux, vy=x[0], roll=x[4])
    return z_next, y
