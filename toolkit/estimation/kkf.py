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
from .kalman import wrap
from .spec import FilterDesign

STATE_SIZE = 9


def initial_state(d: FilterDesign) -> np.ndarray:
    z = np.zeros(STATE_SIZE)
    z[2] = np.pi ** 2  # heading unknown until the first fix
    z[5] = d.initial_covariance()[d.index("gyro_bias"), d.index("gyro_bias")]
    z[7] = np.deg2rad(2.0) ** 2
    return z


def step(d: FilterDesign, z, u, o=NUMPY):
    """One sample: ``(z, u) -> (z_next, y)``, ``u`` and ``y`` as :data:`toolkit.estimation.kalman.INPUTS`
    and ``OUTPUTS``."""
    nz = d.noise
    dt, v, gyro, fix, course, hdop, sats = u[0], u[1], u[4], u[5], u[6], u[7], u[8]
    psi, b = z[0], z[1]
    p11, p21, p12, p22 = z[2], z[3], z[4], z[5]
    beta, beta_var, init = z[6], z[7], z[8]
    rate = gyro - b
    # time update: psi += (gyro - b) dt; F = [[1, -dt], [0, 1]]
    psi = psi + rate * dt
    q_psi = (nz.gyro_std * dt) ** 2
    n11 = p11 - dt * (p21 + p12) + dt * dt * p22 + q_psi
    n12 = p12 - dt * p22
    n22 = p22 + nz.q_bias * dt
    p11, p12, p21, p22 = n11, n12, n12, n22
    # the course at a usable fix
    usable = (fix > 0.5) * (sats >= 4) * (v >= nz.gps_min_speed)
    sd = o.fmax(nz.gps_velocity_std * hdop / o.fmax(v, nz.gps_min_speed), nz.course_std_min) if d.hdop_noise \
        else nz.course_std + 0.0 * v
    r_c = sd * sd
    first = usable * (init < 0.5)
    straight = o.fabs(rate) < nz.kkf_turn_rate
    upd = usable * straight * (1.0 - first)
    innov = wrap(course - psi, o)
    S = p11 + r_c
    k1, k2 = p11 / S, p21 / S
    g = upd  # 0/1: the update happens or leaves everything as it was
    psi_u = psi + g * k1 * innov
    b_u = b + g * k2 * innov
    # Joseph form for H = [1, 0]: P - K m^T - m K^T + S K K^T, m = P H^T = (p11, p21)
    u11 = p11 - g * (2 * k1 * p11 - S * k1 * k1)
    u12 = p12 - g * (k1 * p21 + p11 * k2 - S * k1 * k2)
    u22 = p22 - g * (2 * k2 * p21 - S * k2 * k2)
    # the first fix sets the heading (sideslip taken as zero), its variance the fix's
    psi_n = o.if_else(first > 0.5, course, psi_u)
    u11 = o.if_else(first > 0.5, r_c, u11)
    u12 = o.if_else(first > 0.5, 0.0 * v, u12)
    # sideslip: course - heading at every usable fix (after the update when straight), held between
    turning_fix = usable * (1.0 - first)
    beta_n = o.if_else(turning_fix > 0.5, wrap(course - psi_n, o), beta)
    beta_var_n = o.if_else(turning_fix > 0.5, r_c + u11, beta_var)
    init_n = o.fmax(init, usable)
    z_next = o.stack([psi_n, b_u, u11, u12, u12, u22, beta_n, beta_var_n, init_n])
    nan = float("nan")
    zero = 0.0 * v
    resid = innov / o.sqrt(S)
    y = o.stack([beta_n, gyro - b_u, psi_n, o.sqrt(beta_var_n), zero + nan, zero + nan, b_u,
                 o.fmax(upd, first), o.if_else(upd > 0.5, resid * resid, nan), zero,
                 o.if_else(upd > 0.5, resid, nan), zero + nan, zero + nan, zero + nan, zero + nan])
    return z_next, y
