"""Reference model of seed 003 eq. 23-24 with the friction limit every production ESC applies.

``beta_d = (1 - M l_f v^2 / (2 L C_r l_r)) l_r / (L (1 + G v^2)) delta_cmd`` and
``gamma_d = v / (L (1 + G v^2)) delta_cmd`` with the nominal parameters; then
``|gamma_d| <= k_mu mu g / v`` (``k_mu`` = 0.85 by default: the yaw rate the
available friction can sustain at this speed, with a margin). When the limit
acts, ``beta_d`` is scaled by the same factor, so the two references stay those of
one steady turn.
"""

from __future__ import annotations

from dataclasses import dataclass


from plants import G, VehicleParams
from plants.bicycle import steady_state_gains


@dataclass(frozen=True)
class ReferenceModel:
    params: VehicleParams
    """Nominal vehicle parameters (what the controller believes)."""
    friction_margin: float = 0.85
    """k_mu: fraction of mu g / v allowed as reference yaw rate."""
    min_speed: float = 1.0

    def __call__(self, steer_cmd: float, speed: float, mu: float) -> tuple[float, float]:
        """Desired (beta_d, gamma_d) [rad, rad/s] for a road-wheel steer command [rad]."""
        v = max(speed, self.min_speed)
        kb, kg = steady_state_gains(self.params, v)
        beta_d, gamma_d = kb * steer_cmd, kg * steer_cmd
        limit = self.friction_margin * mu * G / v
        if abs(gamma_d) > limit:
            scale = limit / abs(gamma_d)
            beta_d, gamma_d = beta_d * scale, gamma_d * scale
        return float(beta_d), float(gamma_d)
