"""Seed 001's kinematic Kalman filter (KKF): heading and gyro bias, sideslip from course minus heading.

States ``(psi, b)``; the gyro is the input: ``psi' = r_gyro - b`` (its white noise
becomes heading process noise, ``gyro_std^2 dt^2`` per sample), ``b`` a random walk.
While driving straight (``|r_gyro - b| < kkf_turn_rate``) each usable fix is a heading
measurement (course = heading when the sideslip is ~0; noise from HDOP and speed as
in ``dakf``), which is how the bias is learned. While turning the observation matrix is
zero (001: "turns off the bias estimate and integrates the gyro"), and each fix gives
the sideslip ``beta = course - psi`` with ``sigma_beta^2 = sigma_course^2 + P_psi``
(001 eq. 6); between fixes the last sideslip is held. No vehicle model: a gyro scale
factor error goes straight into the heading, and so into the sideslip (001 Fig. 5).

State vector: ``psi, b, P (2 x 2, column-major), beta, beta_var, init``.
"""

from __future__ import annotations

import numpy as np

from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal

from .core import column, predict, scalar_update
from .kalman import INPUTS, outputs, wrap
from .spec import FilterDesign

STATE = Layout("KKF state", [
    Signal("x", "-", "heading psi [rad], gyro bias b [rad/s]", 2), Signal("P", "-", "its covariance, column-major", 4),
    Signal("beta", "rad", "the sideslip of the last fix"), Signal("beta_var", "rad^2", "its variance"),
    Signal("init", "-", "1 once the heading is initialised"),
])
STATE_SIZE = STATE.size


def initial_state(d: FilterDesign) -> np.ndarray:
    ib = d.index("gyro_bias")
    # heading unknown until the first fix
    P0 = np.diag([np.pi ** 2, d.initial_covariance()[ib, ib]])
    return STATE.pack(x=np.zeros(2), P=P0.ravel(order="F"), beta=0.0, beta_var=np.deg2rad(2.0) ** 2, init=0.0)


def heading_predict(x, P, gyro, dt, gyro_std, q_bias, o=NUMPY):
    """The time update of the heading / gyro-bias filter ``(psi, b)``: ``psi' = r_gyro - b`` with the gyro
    as input (its white noise ``gyro_std`` per sample becomes heading process noise, ``gyro_std^2 dt^2``),
    ``b`` a random walk of intensity ``q_bias``; ``F = [[1, -dt], [0, 1]]``. Shared with seed 000's KF1
    (:mod:`toolkit.estimation.two_stage`)."""
    F = o.eye(2) + o.zeros(2, 2)
    F[0, 1] = -dt
    Q = o.zeros(2, 2)
    Q[0, 0] = (gyro_std * dt) ** 2
    Q[1, 1] = q_bias * dt
    return predict(x, P, F, Q, o, 2, w=o.stack([gyro * dt, 0.0 * dt]))


def step(d: FilterDesign, z, u, o=NUMPY):
    """One sample: ``(z, u) -> (z_next, y)``, ``u`` and ``y`` as :data:`toolkit.estimation.kalman.INPUTS`
    and ``OUTPUTS``."""
    nz = d.noise
    g = INPUTS.unpack(u)
    dt, v, gyro, fix, course, hdop, sats = g.dt, g.speed, g.yaw_rate, g.fix, g.course, g.hdop, g.sats
    zs = STATE.unpack(z)
    x, P = zs.x, o.reshape(zs.P, 2, 2)
    beta, beta_var, init = zs.beta, zs.beta_var, zs.init
    rate = gyro - x[1]
    x, P = heading_predict(x, P, gyro, dt, nz.gyro_std, nz.q_bias, o)
    psi = x[0]
    # the course at a usable fix
    usable = (fix > 0.5) * (sats >= 4) * (v >= nz.gps_min_speed)
    sd = o.fmax(nz.gps_velocity_std * hdop / o.fmax(v, nz.gps_min_speed), nz.course_std_min) if d.hdop_noise \
        else nz.course_std + 0.0 * v
    r_c = sd * sd
    first = usable * (init < 0.5)
    straight = o.fabs(rate) < nz.kkf_turn_rate
    upd = usable * straight * (1.0 - first)  # 0/1: the update happens or leaves everything as it was
    innov = wrap(course - psi, o)
    xu, Pu, S, _ = scalar_update(x, P, column([1.0, 0.0], o), innov, r_c, o, 2, gate=upd)
    # the first fix sets the heading (sideslip taken as zero), its variance the fix's
    psi_n = o.if_else(first > 0.5, course, xu[0])
    u11 = o.if_else(first > 0.5, r_c, Pu[0, 0])
    u12 = o.if_else(first > 0.5, 0.0 * v, Pu[0, 1])
    # sideslip: course - heading at every usable fix (after the update when straight), held between
    turning_fix = usable * (1.0 - first)
    beta_n = o.if_else(turning_fix > 0.5, wrap(course - psi_n, o), beta)
    beta_var_n = o.if_else(turning_fix > 0.5, r_c + u11, beta_var)
    init_n = o.fmax(init, usable)
    b_u = xu[1]
    z_next = STATE.pack(o=o, x=o.stack([psi_n, b_u]), P=o.stack([u11, u12, u12, Pu[1, 1]]), beta=beta_n,
                        beta_var=beta_var_n, init=init_n)
    nan = float("nan")
    resid = innov / o.sqrt(S)
    y = outputs(o, v, beta=beta_n, yaw_rate=gyro - b_u, yaw=psi_n, beta_std=o.sqrt(beta_var_n), gyro_bias=b_u,
                gps_used=o.fmax(upd, first), nis=o.if_else(upd > 0.5, resid * resid, nan), bias_alarm=0.0 * v,
                course_resid=o.if_else(upd > 0.5, resid, nan))
    return z_next, y
