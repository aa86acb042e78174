"""Baseline controllers with the same step protocol as :class:`controllers.two_dof.TwoDofController`.

* :class:`NoControl` — the driver's steer passes through, no yaw moment.
* :class:`YawRatePI` — yaw-rate-only control through the direct yaw moment:
  ``N_z = I_z (k_p e + k_i int e)``, ``e = gamma_d - gamma_hat`` (reference model with
  the friction limit); steer from the driver. ``k_p = 10 1/s``, ``k_i = 25 1/s^2``
  give a well-damped yaw loop for the nominal car. Conditional integration when the
  yaw moment is limited.
"""

from __future__ import annotations

from dataclasses import dataclass

from plants import VehicleParams

from .reference import ReferenceModel


@dataclass(frozen=True)
class NoControl:
    """No control; the reference is still computed so that tracking errors can be compared."""

    params: VehicleParams
    friction_margin: float = 0.85

    def initial_state(self):
        return None

    def step(self, state, t, s):
        beta_d, gamma_d = ReferenceModel(self.params, self.friction_margin)(
            s["steer_driver"], s["speed"], s.get("mu", self.params.mu))
        return None, {"steer": s["steer_driver"], "yaw_moment": 0.0, "beta_ref": beta_d, "yaw_rate_ref": gamma_d}


@dataclass(frozen=True)
class YawRatePI:
    params: VehicleParams
    kp: float = 10.0
    ki: float = 25.0
    friction_margin: float = 0.85
    min_speed: float = 3.0

    def initial_state(self):
        return 0.0

    def step(self, state, t, s):
        ref = ReferenceModel(self.params, self.friction_margin)
        beta_d, gamma_d = ref(s["steer_driver"], s["speed"], s.get("mu", self.params.mu))
        if s["speed"] < self.min_speed:
            return 0.0, {"steer": s["steer_driver"], "yaw_moment": 0.0, "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
        e = gamma_d - s["yaw_rate"]
        nz = self.params.yaw_inertia * (self.kp * e + self.ki * state)
        integ = state if s.get("yaw_moment_limited", 0.0) > 0.5 else state + s["dt"] * e
        return integ, {"steer": s["steer_driver"], "yaw_moment": nz, "beta_ref": beta_d, "yaw_rate_ref": gamma_d}
