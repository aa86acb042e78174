"""Combined-slip tire model: Magic Formula on the normalised slip vector.

The model is Pacejka's Magic Formula applied to the magnitude of a
stiffness-normalised combined slip vector (the "similarity" / normalised-slip
approach of Pacejka, *Tire and Vehicle Dynamics*, 3rd ed., sec. 4.3.2, with the
isotropic simplification). For one tire with vertical load ``F_z``, friction
``mu``, cornering stiffness ``C_a`` and longitudinal slip stiffness ``C_k``
(both at the nominal load ``F_z0``, scaled linearly with load):

``u_x = C_k kappa / (mu F_z0)``,   ``u_y = C_a tan(alpha) / (mu F_z0)``,
``u = sqrt(u_x^2 + u_y^2)``,
``F(u) = sin(C atan(B u - E (B u - atan(B u))))`` with ``B = 1 / C``,
``F_x = mu F_z F(u) u_x / u``,   ``F_y = -mu F_z F(u) u_y / u``.

``F'(0) = 1``, so for small slip ``F_x = C_k (F_z/F_z0) kappa`` and
``F_y = -C_a (F_z/F_z0) tan(alpha)``: exactly the linear tire of the bicycle
model, and the sum over an axle is unchanged by lateral load transfer. The
resultant never exceeds ``mu F_z`` (the friction circle), and a longitudinal
force uses up lateral grip: the coupling the two-track plant must show when the
rear motors make a yaw moment. Shape ``C`` and curvature ``E`` are vehicle
parameters (defaults 1.3 and -2.0: peak at ``u = 2.01``, i.e. where the linear
tire would ask for twice the available grip, sliding at ``sin(1.3 pi/2) = 0.89`` of
peak).

Sign conventions (ISO 8855 wheel axes): ``kappa = (omega R - v_x) / v_ref``
positive when driving; slip angle ``alpha = atan(v_y / v_ref)`` of the wheel
centre velocity, and the lateral force opposes it.
"""

from __future__ import annotations

EPS_SLIP = 1e-9
"""Regularises |u| at zero slip (keeps F and its derivatives finite)."""


def magic_formula_normalised(u, shape: float, curvature: float, ops):
    """Normalised Magic Formula ``F(u)`` with unit initial slope (peak value 1)."""
    b = 1.0 / shape
    bu = b * u
    return ops.sin(shape * ops.arctan(bu - curvature * (bu - ops.arctan(bu))))


def combined_forces(kappa, tan_alpha, fz, fz0, mu, c_alpha, c_kappa, shape, curvature, ops):
    """Longitudinal and lateral tire force [N] in wheel axes for combined slip."""
    ux = c_kappa * kappa / (mu * fz0)
    uy = c_alpha * tan_alpha / (mu * fz0)
    u = ops.sqrt(ux * ux + uy * uy + EPS_SLIP**2)
    scale = mu * fz * magic_formula_normalised(u, shape, curvature, ops) / u
    return scale * ux, -scale * uy


def peak_normalised_slip(shape: float, curvature: float) -> float:
    """The normalised slip ``u`` at which ``F(u)`` peaks (numerically)."""
    import numpy as np
    from scipy.optimize import minimize_scalar

    from .backend import NUMPY
    res = minimize_scalar(lambda u: -magic_formula_normalised(np.array(u), shape, curvature, NUMPY),
                          bounds=(1e-3, 100.0), method="bounded", options={"xatol": 1e-10})
    return float(res.x)
