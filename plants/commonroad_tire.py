"""The tyre of CommonRoad's multi-body car (``vehiclemodels.utils.tire_model``), numpy or casadi.

Pure and combined slip of the package's MF 5.2-style Magic Formula, term by term, with
evstab's road-friction scale ``mu`` (MF 5.2's ``lambda_mu`` on the friction coefficients and
vertical shifts; 1 is the package's tyre) and the camber sign as a parameter: the package's
``sign`` (:func:`exact_sign`) or evstab's :func:`smooth_sign` (see :mod:`plants.commonroad_mb`).
"""

from __future__ import annotations

CAMBER_SMOOTH = 0.01
"""Half-width [rad] of the smoothed camber sign; exactly ``sign`` beyond it."""


def smooth_sign(x, o, width: float = CAMBER_SMOOTH):
    """``sign(x)`` for ``|x| >= width``; inside, the C2 quintic ``s (15 - 10 s^2 + 3 s^4) / 8`` of
    ``s = x / width`` (odd, slope 15/(8 width) at 0, value and two derivatives match at the ends)."""
    s = o.fmin(o.fmax(x / width, -1.0), 1.0)
    s2 = s * s
    return s * (15.0 - 10.0 * s2 + 3.0 * s2 * s2) / 8.0


def exact_sign(x, o):
    """The package's ``sign`` (1, -1, or 0 at 0)."""
    return o.if_else(x > 0, 1.0, o.if_else(x < 0, -1.0, 0.0))


def _mf_angle(x, b, c, e, o):
    """The Magic Formula's angle ``C atan(B x - E (B x - atan(B x)))``."""
    return c * o.arctan(b * x - e * (b * x - o.arctan(b * x)))


def _longitudinal(kappa, gamma, fz, t, o, mu):
    kappa_x = -kappa + t.p_hx1  # the package's sign change, then its horizontal shift
    d_x = t.p_dx1 * (1 - t.p_dx3 * gamma ** 2) * mu * fz
    b_x = fz * t.p_kx1 / (t.p_cx1 * d_x)
    # the package adds the vertical shift inside the sine: kept as it is
    return d_x * o.sin(_mf_angle(kappa_x, b_x, t.p_cx1, t.p_ex1, o) + fz * t.p_vx1 * mu)


def _lateral(alpha, gamma, fz, t, o, mu, sign):
    sg = sign(gamma, o)
    alpha_y = alpha + sg * (t.p_hy1 + t.p_hy3 * o.fabs(gamma))
    mu_y = t.p_dy1 * (1 - t.p_dy3 * gamma ** 2) * mu
    d_y = mu_y * fz
    b_y = fz * t.p_ky1 / (t.p_cy1 * d_y)
    s_vy = sg * fz * (t.p_vy1 + t.p_vy3 * o.fabs(gamma)) * mu
    return d_y * o.sin(_mf_angle(alpha_y, b_y, t.p_cy1, t.p_ey1, o)) + s_vy, mu_y


def _longitudinal_comb(kappa, alpha, f0_x, t, o):
    s_hxalpha = t.r_hx1
    alpha_s = alpha + s_hxalpha
    b_xalpha = t.r_bx1 * o.cos(o.arctan(t.r_bx2 * kappa))
    c_xalpha = t.r_cx1
    e_xalpha = t.r_ex1
    d_xalpha = f0_x / (o.cos(c_xalpha * o.arctan(
        b_xalpha * s_hxalpha - e_xalpha * (b_xalpha * s_hxalpha - o.arctan(b_xalpha * s_hxalpha)))))
    return d_xalpha * o.cos(
        c_xalpha * o.arctan(b_xalpha * alpha_s - e_xalpha * (b_xalpha * alpha_s - o.arctan(b_xalpha * alpha_s))))


def _lateral_comb(kappa, alpha, gamma, mu_y, fz, f0_y, t, o):
    s_hykappa = t.r_hy1
    kappa_s = kappa + s_hykappa
    b_ykappa = t.r_by1 * o.cos(o.arctan(t.r_by2 * (alpha - t.r_by3)))
    c_ykappa = t.r_cy1
    e_ykappa = t.r_ey1
    d_ykappa = f0_y / (o.cos(c_ykappa * o.arctan(
        b_ykappa * s_hykappa - e_ykappa * (b_ykappa * s_hykappa - o.arctan(b_ykappa * s_hykappa)))))
    d_vykappa = mu_y * fz * (t.r_vy1 + t.r_vy3 * gamma) * o.cos(o.arctan(t.r_vy4 * alpha))
    s_vykappa = d_vykappa * o.sin(t.r_vy5 * o.arctan(t.r_vy6 * kappa))
    return d_ykappa * o.cos(c_ykappa * o.arctan(
        b_ykappa * kappa_s - e_ykappa * (b_ykappa * kappa_s - o.arctan(b_ykappa * kappa_s)))) + s_vykappa
