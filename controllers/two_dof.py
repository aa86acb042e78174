"""The 2-DOF model-following controller of seed 003 (eq. 25-33), scheduled on speed.

With the nominal lateral model ``x' = A x + B u + d`` (``x = (beta, r)``,
``u = (delta_f, N_z)``, ``B`` invertible):

* disturbance rejection ``C_dis = B^-1`` (eq. 26): ``u_dis = B^-1 d_hat``;
* feed-forward ``C_ff = P_n^-1 = B^-1 (s I - A)`` (eq. 27-29), realised from the
  reference's derivative: ``u_ff = B^-1 (x_d' - A x_d)``;
* feedback ``C_fb = P_n^-1 K (I - K)^-1`` with ``K = diag(K_b/(s+K_b), K_g/(s+K_g))``
  (eq. 30-32). Since ``K (I - K)^-1 = diag(K_b, K_g) / s``, this is exactly the PI
  law ``u_fb = B^-1 (Kd e - A Kd xi)``, ``xi' = e``, ``e = x_d - x_hat``,
  ``Kd = diag(K_b, K_g)``;
* commands ``u = u_fb + u_ff - u_dis`` (eq. 33).

On the nominal plant the tracking error obeys ``(s I - A)(s I + Kd) xi = 0``: the
reference-to-state map is ``K`` (poles ``-K_b``, ``-K_g``) while the plant's own
poles stay in the loop (the controller inverts the plant), which is why internal
stability is checked (:mod:`controllers.stability`).

Discrete realisation at the control period ``dt``: the integrator by zero-order
hold (``xi[k+1] = xi[k] + dt e[k]``, exact for an error held over the period), the
reference derivative by a backward difference through a first-order low-pass of
time constant ``derivative_tau``. Anti-windup by conditional integration: while a
command is limited by an actuator and the error would push it further, ``xi`` is
held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plants import VehicleParams
from plants.bicycle import lateral_matrices

from .reference import ReferenceModel


@dataclass(frozen=True)
class TwoDofDesign:
    """Frozen controller design (gains and realisation)."""

    params: VehicleParams
    k_beta: float = 5.0
    """Model-following pole for sideslip [rad/s] (seed 003: 5)."""
    k_gamma: float = 5.0
    """Model-following pole for yaw rate [rad/s] (seed 003: 5)."""
    dt: float = 1e-3
    derivative_tau: float = 0.02
    min_speed: float = 3.0
    """Below this speed [m/s] the controller passes the driver's steer through and makes no yaw moment."""
    friction_margin: float = 0.85
    disturbance_rejection: bool = True
    method: str = "zoh-integrator, filtered backward-difference reference derivative"

    def __post_init__(self):
        if not (self.k_beta > 0 and self.k_gamma > 0):
            raise ValueError(f"K_beta and K_gamma must be > 0 rad/s, got {self.k_beta}, {self.k_gamma}")
        if not self.dt > 0:
            raise ValueError(f"control period must be > 0 s, got {self.dt}")

    @property
    def kd(self) -> np.ndarray:
        return np.diag([self.k_beta, self.k_gamma])

    @property
    def reference(self) -> ReferenceModel:
        return ReferenceModel(self.params, self.friction_margin)

    def gains(self, speed: float):
        """(B^-1, B^-1 Kd, -B^-1 A Kd, B^-1 A) at ``speed``: the scheduled matrices of the law."""
        A, B = lateral_matrices(self.params, max(speed, self.min_speed))
        Bi = np.linalg.inv(B)
        return Bi, Bi @ self.kd, -Bi @ A @ self.kd, Bi @ A


@dataclass(frozen=True)
class ControllerState:
    xi: np.ndarray
    xd_prev: np.ndarray
    xd_dot: np.ndarray
    started: bool = False


class TwoDofController:
    """The controller in the simulator's step protocol.

    Signals in: ``speed``, ``steer_driver`` (road-wheel angle command [rad]),
    ``beta``, ``yaw_rate`` (estimates or truth), ``d1``, ``d2`` (disturbance
    estimates, 0 if absent), ``mu`` (friction assumed by the reference), and
    ``steer_limited``/``yaw_moment_limited`` flags from the actuators of the last
    sample. Outputs: ``steer`` [rad], ``yaw_moment`` [N m], ``beta_ref``, ``yaw_rate_ref``.
    """

    def __init__(self, design: TwoDofDesign):
        self.design = design

    def initial_state(self) -> ControllerState:
        z = np.zeros(2)
        return ControllerState(z, z, z, False)

    def step(self, state: ControllerState, t: float, s: dict):
        d = self.design
        v = s["speed"]
        beta_d, gamma_d = d.reference(s["steer_driver"], v, s.get("mu", d.params.mu))
        xd = np.array([beta_d, gamma_d])
        if state.started:
            raw = (xd - state.xd_prev) / d.dt
            a = d.dt / (d.derivative_tau + d.dt)
            xd_dot = state.xd_dot + a * (raw - state.xd_dot)
        else:
            xd_dot = np.zeros(2)
        if v < d.min_speed:
            out = {"steer": s["steer_driver"], "yaw_moment": 0.0, "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
            return ControllerState(np.zeros(2), xd, xd_dot, True), out
        Bi, Kp, Ki, BiA = d.gains(v)
        e = xd - np.array([s["beta"], s["yaw_rate"]])
        dist = np.array([s.get("d1", 0.0), s.get("d2", 0.0)]) if d.disturbance_rejection else np.zeros(2)
        u_ff = Bi @ xd_dot - BiA @ xd
        u = Kp @ e + Ki @ state.xi + u_ff - Bi @ dist
        # conditional integration: hold xi in a channel whose command is limited
        de = e * d.dt
        limited = np.array([s.get("steer_limited", 0.0), s.get("yaw_moment_limited", 0.0)]) > 0.5
        xi = state.xi + np.where(limited, 0.0, de)
        out = {"steer": float(u[0]), "yaw_moment": float(u[1]), "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
        return ControllerState(xi, xd, xd_dot, True), out
