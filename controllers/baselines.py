"""Baseline control law with the same signals as :func:`controllers.two_dof.control_law`.

:func:`yaw_pi_law` — yaw-rate-only control through the direct yaw moment:
``N_z = I_z (k_p e + k_i int e)``, ``e = gamma_d - gamma_hat`` against the friction-limited static
reference of seed 003 eq. 23-24 (:func:`controllers.two_dof.reference`); the steer is the driver's.
``k_p = 10 1/s``, ``k_i = 25 1/s^2`` give a well-damped yaw loop for the nominal car. Conditional
integration while the yaw moment is limited; below ``min_speed`` the driver passes through.
Written once for numpy and casadi, like the 2-DOF law. (No control at all is the ECU's
pass-through, :class:`toolkit.loop.loop_ecu.LoopEcu` kind ``none``.)
"""

from __future__ import annotations

from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal

from .two_dof import OUTPUTS, SIGNALS, TwoDofDesign, reference

YAW_PI_GAINS = (10.0, 25.0)
"""(k_p [1/s], k_i [1/s^2]) of :func:`yaw_pi_law`."""
STATE = Layout("yaw-PI state", [Signal("xi_yaw_rate", "rad", "integral of the yaw-rate error")])


def yaw_pi_law(d: TwoDofDesign, z, sig, o=NUMPY, gains: tuple[float, float] = YAW_PI_GAINS):
    """``(z, sig) -> (z_next, out)`` with ``sig`` per :data:`controllers.two_dof.SIGNALS` and ``out`` per
    :data:`controllers.two_dof.OUTPUTS`; ``d`` supplies the nominal model, reference and limits."""
    s = SIGNALS.unpack(sig)
    xi0 = STATE.unpack(z).xi_yaw_rate
    kp, ki = gains
    vm = o.fmax(s.speed, d.min_speed)
    beta_ss, gamma_ss, _ = reference(d, vm, s.steer_driver, s.mu, o)
    e = gamma_ss - s.yaw_rate
    nmax = d.nz_max
    nz = d.params.yaw_inertia * (kp * e + ki * xi0)
    nz = o.fmin(o.fmax(nz, -nmax), nmax)
    low = s.speed < d.min_speed
    xi = o.if_else(low, 0.0, o.if_else(s.yaw_moment_limited > 0.5, xi0, xi0 + d.dt * e))
    return STATE.pack(o=o, xi_yaw_rate=xi), OUTPUTS.pack(o=o, steer=s.steer_driver, yaw_moment=o.if_else(low, 0.0, nz),
                                                         beta_ref=beta_ss, yaw_rate_ref=gamma_ss, yaw_rate_error=e)
