"""Seed 004's double-layer estimator (layer 2) and its two baselines.

Layer 1 is the advanced multi-rate filter (``dakf`` or ``amrkf``: sideslip, yaw rate,
yaw). Layer 2 (004 eq. 39-42) has states ``(v_x, v_y, phi, phi', d)``:

    v_x' = a_x + r v_y,      v_y' = a_y - r v_x - g phi,      (004 eq. 4-5)
    phi'' = (-K_x phi - C_x phi' + M_s h_s a_y) / I_x + d,    (004 eq. 3)

with the accelerometers as inputs, the disturbance ``d`` (roll-model error and roll
moments) a random walk, the roll rate as the fast measurement and, at each GPS fix,
the pseudo-measurements ``v_x = V cos(beta)``, ``v_y = V sin(beta)`` (004 eq. 8-9) from
the GPS ground speed ``V`` and layer 1's sideslip. The lateral kinematics tie ``phi``
to ``v_y``, so the roll angle is observed through the velocities even where the roll
model is wrong. Discretised as in 004 (``I + A T_c``).

Baselines: :func:`roll_kf` (Tseng et al.: states ``phi, phi'``, roll-rate measurement,
``a_y`` input, the roll model alone) and :func:`velocity_kf` (Chen et al.: kinematic
``v_x, v_y`` with the non-driven wheels' speed as the ``v_x`` measurement).

These run in numpy over a whole log (a 5-state filter at 1 kHz: about 3 s per minute
of log); ``evstab estimate --method double-layer`` runs layer 2 on ``dakf``'s estimate (004's layer 1
is the advanced multi-rate filter, ``amrkf``; its inter-sample residual prediction as printed
over-corrects with evstab's noise, and evstab's correlation-weighted one leaves ``amrkf`` equal to
``dakf`` where the fixes' innovations are white, so layer 1 is the filter without it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.params import G

from evstab.plants.signals import Layout, Signal

from .core import predict, scalar_update, unit


LAYER2 = Layout("layer-2 state", [
    Signal("vx", "m/s", "body longitudinal velocity"), Signal("vy", "m/s", "body lateral velocity"),
    Signal("roll", "rad", "roll angle"), Signal("roll_rate", "rad/s", "roll rate"),
    Signal("d", "rad/s^2", "roll disturbance"),
])
VELOCITY = Layout("velocity state", [Signal("vx", "m/s"), Signal("vy", "m/s")])


@dataclass(frozen=True, kw_only=True)
class Layer2Noise:
    accel_std: float = 0.05
    """[m/s^2] accelerometer noise per sample (enters v_x', v_y')."""
    q_roll_acc: float = 1e-3
    """[rad^2/s^3] white noise on phi''."""
    q_d: float = 1.0
    """[rad^2/s^5] random walk of the roll disturbance d."""
    roll_rate_std: float = 0.004
    """[rad/s] roll gyro noise per sample."""
    speed_std: float = 0.04
    """[m/s] GPS ground-speed noise per fix."""
    beta_std_min: float = np.radians(0.2)
    """[rad] The pseudo-velocities' sideslip noise is layer 1's ``beta_std``, but at least this: a linear
    model's spread does not hold its own model error (a nominal stiffness 43 % high, say)."""


def _kf_update(x, P, h_idx, z, r):
    """Scalar update of the measurement ``x[h_idx]`` (Joseph form, :func:`core.scalar_update`)."""
    x, P, _, _ = scalar_update(x, P, unit(len(x), h_idx), z - x[h_idx], r)
    return x, P


def layer2(p: VehicleParams, t, ax, ay, yaw_rate, roll_rate, gps_speed, beta, beta_std=None,
           noise: Layer2Noise = Layer2Noise(), v0: float | None = None) -> dict:
    """Run layer 2 over a log; ``gps_speed`` NaN between fixes; ``beta`` from layer 1 (rad)."""
    t, ax, ay, r, pr, V, b = (np.asarray(a, float) for a in (t, ax, ay, yaw_rate, roll_rate, gps_speed, beta))
    n = len(t)
    floor = noise.beta_std_min
    bs = np.full(n, floor) if beta_std is None else np.fmax(np.nan_to_num(np.asarray(beta_std, float), nan=floor),
                                                           floor)
    ix, cx, kx = p.roll_inertia, p.roll_damping, p.roll_stiffness
    msh = p.sprung_mass * p.roll_arm
    x = np.zeros(5)
    x[0] = v0 if v0 is not None else (V[np.isfinite(V)][0] if np.isfinite(V).any() else 0.0)
    P = np.diag([1.0, 0.25, np.radians(2.0) ** 2, 0.01, 1.0])
    out = np.empty((n, 5))
    dt0 = np.median(np.diff(t)) if n > 1 else 1e-3
    for k in range(n):
        dt = dt0 if k == 0 else t[k] - t[k - 1]
        A = np.array([[0.0, r[k], 0.0, 0.0, 0.0],
                      [-r[k], 0.0, -G, 0.0, 0.0],
                      [0.0, 0.0, 0.0, 1.0, 0.0],
                      [0.0, 0.0, -kx / ix, -cx / ix, 1.0],
                      [0.0, 0.0, 0.0, 0.0, 0.0]])
        F = np.eye(5) + A * dt
        u = np.array([ax[k], ay[k], 0.0, msh / ix * ay[k], 0.0])
        Q = np.diag([(noise.accel_std * dt) ** 2, (noise.accel_std * dt) ** 2, 0.0,
                     noise.q_roll_acc * dt, noise.q_d * dt])
        x, P = predict(x, P, F, Q, w=u * dt)
        x, P = _kf_update(x, P, LAYER2.index("roll_rate"), pr[k], noise.roll_rate_std ** 2)
        if np.isfinite(V[k]) and np.isfinite(b[k]):
            # pseudo-measurements (004 eq. 8-9); their noise from the speed's and the sideslip's
            cb, sb = np.cos(b[k]), np.sin(b[k])
            x, P = _kf_update(x, P, LAYER2.index("vx"), V[k] * cb,
                              (noise.speed_std * cb) ** 2 + (V[k] * sb * bs[k]) ** 2)
            x, P = _kf_update(x, P, LAYER2.index("vy"), V[k] * sb,
                              (noise.speed_std * sb) ** 2 + (V[k] * cb * bs[k]) ** 2)
        out[k] = x
    return LAYER2.columns(out)


def roll_kf(p: VehicleParams, t, ay, roll_rate, noise: Layer2Noise = Layer2Noise()) -> np.ndarray:
    """Two-state roll KF (phi, phi'): the roll model driven by ``a_y``, the roll rate measured."""
    t, ay, pr = (np.asarray(a, float) for a in (t, ay, roll_rate))
    ix, cx, kx = p.roll_inertia, p.roll_damping, p.roll_stiffness
    msh = p.sprung_mass * p.roll_arm
    x, P = np.zeros(2), np.diag([np.radians(2.0) ** 2, 0.01])
    out = np.empty(len(t))
    dt0 = np.median(np.diff(t)) if len(t) > 1 else 1e-3
    for k in range(len(t)):
        dt = dt0 if k == 0 else t[k] - t[k - 1]
        F = np.eye(2) + np.array([[0.0, 1.0], [-kx / ix, -cx / ix]]) * dt
        x, P = predict(x, P, F, np.diag([0.0, noise.q_roll_acc * dt]), w=np.array([0.0, msh / ix * ay[k]]) * dt)
        x, P = _kf_update(x, P, 1, pr[k], noise.roll_rate_std ** 2)
        out[k] = x[0]
    return out


def velocity_kf(t, ax, ay, yaw_rate, wheel_speed, noise: Layer2Noise = Layer2Noise(),
                wheel_speed_std: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Kinematic two-state velocity KF (v_x, v_y): accelerometers and yaw rate as inputs, the
    non-driven wheels' speed as the v_x measurement every sample (no roll correction)."""
    t, ax, ay, r, w = (np.asarray(a, float) for a in (t, ax, ay, yaw_rate, wheel_speed))
    x, P = VELOCITY.pack(vx=w[0], vy=0.0), np.diag([1.0, 0.25])
    out = np.empty((len(t), 2))
    dt0 = np.median(np.diff(t)) if len(t) > 1 else 1e-3
    for k in range(len(t)):
        dt = dt0 if k == 0 else t[k] - t[k - 1]
        F = np.eye(2) + np.array([[0.0, r[k]], [-r[k], 0.0]]) * dt
        x, P = predict(x, P, F, np.eye(2) * (noise.accel_std * dt) ** 2, w=np.array([ax[k], ay[k]]) * dt)
        x, P = _kf_update(x, P, VELOCITY.index("vx"), w[k], wheel_speed_std ** 2)
        out[k] = x
    v = VELOCITY.columns(out)
    return v["vx"], v["vy"]


def roll_model_error(p: VehicleParams, error: float = 0.3) -> VehicleParams:
    """004 eq. 43: I_x, C_x and K_x all ``(1 + error)`` times the truth."""
    import dataclasses
    return dataclasses.replace(p, roll_inertia=p.roll_inertia * (1 + error), roll_damping=p.roll_damping * (1 + error),
                               roll_stiffness=p.roll_stiffness * (1 + error))
