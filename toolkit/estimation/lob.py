"""Seed 003's linear observer (LOB) baseline: (beta, r) from yaw rate and lateral acceleration.

The observer runs the nominal bicycle model with output injection,
``x' = A x + B u + L (y - C x - D u)``, ``y = (r_gyro, a_y)``, where
``a_y = v (beta' + r)`` gives ``C = [[0, 1], [v a11, v (a12 + 1)]]`` and
``D = [[0, 0], [v b11, 0]]``. ``C`` is invertible whenever ``a11 != 0``, so the
observer poles are placed exactly by ``L = (A - A_des) C^-1`` with
``A_des = diag(tr A, tr A)`` (both poles at the sum of the plant's poles, about
twice as fast as the plant). It uses no GPS, so its yaw is the integrated gyro.
Below ``min_speed`` it holds beta and follows the gyro.
"""

from __future__ import annotations

import numpy as np

from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal
from .kalman import INPUTS, outputs
from .spec import FilterDesign, lateral_coefficients

STATE = Layout("observer state", [Signal("beta", "rad"), Signal("yaw_rate", "rad/s"), Signal("yaw", "rad")])
STATE_SIZE = STATE.size


def initial_state(d: FilterDesign) -> np.ndarray:
    return STATE.zeros()


def gains(d: FilterDesign, v, o=NUMPY):
    """Observer gain L (2x2 as nested tuples) and the model terms at speed ``v``."""
    a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(d.params, v)
    lam = a11 + a22
    # (A - A_des) and C^-1 for C = [[0, 1], [c21, c22]]: C^-1 = [[c22, -1], [-c21, 0]] / det, det = -c21
    c21, c22 = v * a11, v * (a12 + 1.0)
    m = ((a11 - lam, a12), (a21, a22 - lam))
    det = -c21
    ci = ((c22 / det, -1.0 / det), (-c21 / det, 0.0))
    L = tuple(tuple(m[i][0] * ci[0][j] + m[i][1] * ci[1][j] for j in range(2)) for i in range(2))
    return L, (a11, a12, a21, a22, b11, b21, b22), (c21, c22)


def step(d: FilterDesign, z, u, o=NUMPY):
    g = INPUTS.unpack(u)
    dt, v, steer, nzm, gyro, ay = g.dt, g.speed, g.steer, g.yaw_moment, g.yaw_rate, g.ay
    zs = STATE.unpack(z)
    beta, r, yaw = zs.beta, zs.yaw_rate, zs.yaw
    v_m = o.fmax(v, d.noise.min_speed)
    L, (a11, a12, a21, a22, b11, b21, b22), (c21, c22) = gains(d, v_m, o)
    e_r = gyro - r
    e_ay = ay - (c21 * beta + c22 * r + v_m * b11 * steer)
    db = a11 * beta + a12 * r + b11 * steer + L[0][0] * e_r + L[0][1] * e_ay
    dr = a21 * beta + a22 * r + b21 * steer + b22 * nzm + L[1][0] * e_r + L[1][1] * e_ay
    # semi-implicit Euler on the fast observer: stable for |lambda| dt < 2
    dyn = v >= d.noise.min_speed
    beta_n = o.if_else(dyn, beta + dt * db, beta)
    r_n = o.if_else(dyn, r + dt * dr, gyro)
    yaw_n = yaw + dt * gyro
    y = outputs(o, v, beta=beta_n, yaw_rate=r_n, yaw=yaw_n, bias_alarm=0.0 * v, gyro_resid=gyro - r)
    return STATE.pack(o=o, beta=beta_n, yaw_rate=r_n, yaw=yaw_n), y
