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

The static reference of seed 003 eq. 23 jumps with the steer (and with the
friction limit); inverting the plant against a jump asks for an impulse. The
reference therefore passes through a first-order lag of time constant
``reference_tau`` (the car's own yaw response is of that order), whose derivative
``(x_ss - x_d) / tau`` is known exactly: that is the ``x_d'`` the feed-forward uses.

Discrete realisation at the control period ``dt``: the integrator and the
reference lag by zero-order hold (``xi[k+1] = xi[k] + dt e[k]``, exact for a held
error; the lag with ``exp(-dt/tau)``). Anti-windup by conditional integration: while a
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
    reference_tau: float = 0.1
    """Time constant [s] of the lag applied to the static reference (see the module notes)."""
    min_speed: float = 3.0
    """Below this speed [m/s] the controller passes the driver's steer through and makes no yaw moment."""
    friction_margin: float = 0.85
    disturbance_rejection: bool = True
    yaw_moment_max: float | None = None
    """Largest achievable |N_z| [N m]; default from the rear motors: T_max t_r / R_w."""
    steer_max: float = np.deg2rad(35.0)
    yaw_priority: float = 4.0
    """Weight of the yaw-rate row against the sideslip row when a command saturates."""
    disturbance_filter_tau: float = 0.0
    """First-order low-pass [s] on the disturbance estimates before rejection (0 = none)."""
    method: str = "zoh (integrator and reference lag); feed-forward from the lag's exact derivative"

    def __post_init__(self):
        if not (self.k_beta > 0 and self.k_gamma > 0):
            raise ValueError(f"K_beta and K_gamma must be > 0 rad/s, got {self.k_beta}, {self.k_gamma}")
        if not self.dt > 0:
            raise ValueError(f"control period must be > 0 s, got {self.dt}")

    @property
    def nz_max(self) -> float:
        if self.yaw_moment_max is not None:
            return self.yaw_moment_max
        p = self.params
        if p.max_motor_torque is not None and p.track_rear is not None and p.wheel_radius is not None:
            return p.max_motor_torque * p.track_rear / p.wheel_radius
        return np.inf

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
    """Integral of the tracking error."""
    xd: np.ndarray
    """The lagged reference (beta_d, gamma_d)."""
    dist: np.ndarray = None
    """Low-passed disturbance estimates (d1, d2)."""


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
        return ControllerState(np.zeros(2), np.zeros(2), np.zeros(2))

    def step(self, state: ControllerState, t: float, s: dict):
        d = self.design
        v = s["speed"]
        x_ss = np.array(d.reference(s["steer_driver"], v, s.get("mu", d.params.mu)))
        xd = state.xd
        xd_dot = (x_ss - xd) / d.reference_tau
        xd_next = x_ss + (xd - x_ss) * np.exp(-d.dt / d.reference_tau)
        beta_d, gamma_d = float(xd[0]), float(xd[1])
        if v < d.min_speed:
            out = {"steer": s["steer_driver"], "yaw_moment": 0.0, "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
            return ControllerState(np.zeros(2), xd_next, np.zeros(2)), out
        Bi, Kp, Ki, BiA = d.gains(v)
        e = xd - np.array([s["beta"], s["yaw_rate"]])
        d_raw = np.array([s.get("d1", 0.0), s.get("d2", 0.0)]) if d.disturbance_rejection else np.zeros(2)
        prev = state.dist if state.dist is not None else np.zeros(2)
        dist = d_raw if d.disturbance_filter_tau <= 0 else prev + (d_raw - prev) * (1 - np.exp(-d.dt / d.disturbance_filter_tau))
        u_ff = Bi @ xd_dot - BiA @ xd
        u = Kp @ e + Ki @ state.xi + u_ff - Bi @ dist
        u = self._allocate(u, v)
        # conditional integration: hold xi in a channel whose command is limited
        de = e * d.dt
        limited = np.array([s.get("steer_limited", 0.0), s.get("yaw_moment_limited", 0.0)]) > 0.5
        xi = state.xi + np.where(limited, 0.0, de)
        out = {"steer": float(u[0]), "yaw_moment": float(u[1]), "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
        return ControllerState(xi, xd_next, dist), out

    def _allocate(self, u: np.ndarray, speed: float) -> np.ndarray:
        """Saturation-aware allocation: when one command exceeds its limit, clip it and choose the
        other to realise the demanded ``B u`` in weighted least squares, the yaw-rate row weighted
        ``yaw_priority`` times the sideslip row (yaw stability comes first). Without saturation the
        exact inverse is kept."""
        d = self.design
        delta, nz = float(u[0]), float(u[1])
        if abs(delta) <= d.steer_max and abs(nz) <= d.nz_max:
            return u
        _, B = lateral_matrices(d.params, max(speed, d.min_speed))
        v = B @ u
        w = np.array([1.0, d.yaw_priority])
        if abs(nz) > d.nz_max:
            nz = float(np.clip(nz, -d.nz_max, d.nz_max))
            col, rest = B[:, 0], v - B[:, 1] * nz
            delta = float(np.clip(np.sum(w * col * rest) / np.sum(w * col * col), -d.steer_max, d.steer_max))
        if abs(delta) > d.steer_max:
            delta = float(np.clip(delta, -d.steer_max, d.steer_max))
            col, rest = B[:, 1], v - B[:, 0] * delta
            nz = float(np.clip(np.sum(w * col * rest) / np.sum(w * col * col), -d.nz_max, d.nz_max))
        return np.array([delta, nz])
