"""Nonlinear two-track (four-wheel) vehicle model after seed 000 eq. 5-13.

Degrees of freedom: longitudinal ``vx``, lateral ``vy``, yaw ``yaw_rate``, body
roll ``roll``/``roll_rate`` and the four wheel spins ``omega_*``; plus the yaw
angle and earth-frame position, and two first-order filtered accelerations
``ax_f``/``ay_f`` that drive the load transfer (time constant
:data:`LOAD_TRANSFER_TAU`, standing in for the pitch/roll dynamics of the
suspension, and avoiding the algebraic loop ``F_z -> F -> a -> F_z``).

Equations (ISO 8855 axes, wheels 1..4 = FL, FR, RL, RR as in seed 000):

* ``sum F_x = M (vx' - vy r)``                                  (000 eq. 5-6)
* ``sum F_y = M (vy' + vx r) - M_s h_s phi''``                 (000 eq. 7-8)
* ``I_z r' = sum M_z`` with each wheel force at its contact point (000 eq. 9-10, I_xz = 0)
* ``I_x phi'' - M_s h_s (vy' + vx r) = -K phi - C phi' + M_s g h_s sin(phi)`` (000 eq. 11-12)
* ``I_w omega_i' = T_i - F_xi R_w - rolling resistance``        (000 eq. 13, T = drive - brake)

Tire forces come from :mod:`plants.tires` (Magic Formula on the normalised
combined slip), so a drive or brake torque costs side force. Vertical loads are
static plus longitudinal (``M h a_x / L``) and lateral (``M h a_y / t``, split
front/rear by roll-stiffness share) transfer, kept positive smoothly.

Low speed: slips are divided by a smooth ``max(|v|, V_LOW)`` instead of ``|v|``,
so the model is smooth through standstill (the tires act as stiff dampers there)
and exact at driving speeds.
"""

from __future__ import annotations

import math

import numpy as np

from .backend import ops_for, smooth_abs, smooth_max, unpack
from .model import COMMANDS, DISTURBANCES, PlantModel, torque_difference
from .params import G, VehicleParams, known
from .tires import combined_forces

STATES = ("vx", "vy", "yaw_rate", "roll", "roll_rate",
          "omega_fl", "omega_fr", "omega_rl", "omega_rr", "yaw", "x", "y", "ax_f", "ay_f")
INPUTS = ("steer", "torque_fl", "torque_fr", "torque_rl", "torque_rr", "brake_fl", "brake_fr", "brake_rl",
          "brake_rr")
REQUIRED = ("sprung_mass", "roll_inertia", "roll_damping", "roll_stiffness", "roll_arm", "cg_height",
            "track_front", "track_rear", "wheel_radius", "wheel_inertia", "longitudinal_stiffness")

V_LOW = 2.5
"""Slip reference-speed floor [m/s]: slips are divided by a smooth ``max(|v|, V_LOW)``."""
V_BLEND = 0.5
"""Width [m/s] of the smooth max; above ``V_LOW + 4 V_BLEND`` the reference speed is |v| to < 0.4 %."""
BRAKE_LOCK_SHARE = 0.35
"""The friction brake's torque against a slow wheel, ``T_b tanh(k omega / T_b)``, rises with slope ``k`` =
this share of the tyre's own spin stiffness at :data:`V_LOW` (``C_kappa R_w^2 / V_LOW``): the sum of the two
stays inside the RK4 step :func:`max_stable_step` allows (2.0 / lambda of the tyre alone, RK4's bound 2.78).
A wheel braked beyond its tyre's grip therefore does not stop dead: it creeps forward at ``omega = (T_b / k)
atanh(F_x R_w / T_b)``, a few rad/s (:func:`brake_lock_slope`), and never turns backwards (the brake's torque
vanishes with the spin)."""
LOAD_TRANSFER_TAU = 0.05
"""Time constant [s] of the accelerations that drive load transfer."""
FZ_MIN = 50.0
"""Smoothing width [N] of the positive-part that keeps vertical loads >= 0."""
AIR_DENSITY = 1.2
SPEED_GAIN = 2.0
"""Bandwidth [1/s] of the built-in speed hold of the command map (the driver's foot)."""


def wheel_geometry(p: VehicleParams):
    """Contact-point coordinates (x_i, y_i) [m] of FL, FR, RL, RR relative to the CG."""
    t_f, t_r = known(p, "track_front", "track_rear")
    tf, tr = t_f / 2.0, t_r / 2.0
    return (p.lf, p.lf, -p.lr, -p.lr), (tf, -tf, tr, -tr)


def _forces(x, u, w, p: VehicleParams):
    o = ops_for(x, u, w)
    s, c, d = unpack(x, STATES), unpack(u, INPUTS), unpack(w, DISTURBANCES)
    L = p.wheelbase
    h, R, t_f, t_r = known(p, "cg_height", "wheel_radius", "track_front", "track_rear")
    xs, ys = wheel_geometry(p)
    share = 0.5 if p.roll_stiffness_front_share is None else p.roll_stiffness_front_share
    fz0 = (p.mass * G * p.lr / L / 2.0, p.mass * G * p.lr / L / 2.0,
           p.mass * G * p.lf / L / 2.0, p.mass * G * p.lf / L / 2.0)
    d_long = p.mass * h * s.ax_f / L / 2.0
    d_lat_f = share * p.mass * h * s.ay_f / t_f
    d_lat_r = (1.0 - share) * p.mass * h * s.ay_f / t_r
    fz_raw = (fz0[0] - d_long - d_lat_f, fz0[1] - d_long + d_lat_f,
              fz0[2] + d_long - d_lat_r, fz0[3] + d_long + d_lat_r)
    fz = [0.5 * (q + smooth_abs(q, FZ_MIN, o)) for q in fz_raw]
    steer = (c.steer, c.steer, 0.0, 0.0)
    omegas = (s.omega_fl, s.omega_fr, s.omega_rl, s.omega_rr)
    mus = (d.mu_fl, d.mu_fr, d.mu_rl, d.mu_rr)
    stiff = ((p.cornering_stiffness_front, fz0[0]), (p.cornering_stiffness_front, fz0[1]),
             (p.cornering_stiffness_rear, fz0[2]), (p.cornering_stiffness_rear, fz0[3]))
    fxw, fx, fy, mz = [], 0.0, 0.0, 0.0
    for i in range(4):
        vxi = s.vx - s.yaw_rate * ys[i]
        vyi = s.vy + s.yaw_rate * xs[i]
        cs, sn = o.cos(steer[i]), o.sin(steer[i])
        v_long = vxi * cs + vyi * sn
        v_lat = -vxi * sn + vyi * cs
        v_ref = smooth_max(smooth_abs(v_long, 0.01, o), V_LOW, V_BLEND, o)
        kappa = (omegas[i] * R - v_long) / v_ref
        tan_alpha = v_lat / v_ref
        fx_w, fy_w = combined_forces(kappa, tan_alpha, fz[i], stiff[i][1], mus[i], stiff[i][0],
                                     p.longitudinal_stiffness, p.tire_shape_factor,
                                     p.tire_curvature_factor, o)
        fxb = fx_w * cs - fy_w * sn
        fyb = fx_w * sn + fy_w * cs
        fxw.append(fx_w)
        fx = fx + fxb
        fy = fy + fyb
        mz = mz + xs[i] * fyb - ys[i] * fxb
    drag = 0.5 * AIR_DENSITY * p.drag_coefficient * p.frontal_area * s.vx * smooth_abs(s.vx, 0.1, o)
    fx = fx - drag
    fy = fy + d.lateral_force - p.mass * G * o.sin(d.bank)
    mz = mz + d.yaw_moment_dist
    return o, s, c, d, fz, fxw, fx, fy, mz


def _accelerations(x, u, w, p: VehicleParams):
    o, s, c, d, fz, fxw, fx, fy, mz = _forces(x, u, w, p)
    ms, hs, kx, cx, ix = known(p, "sprung_mass", "roll_arm", "roll_stiffness", "roll_damping", "roll_inertia")
    msh = ms * hs
    m_roll = (-kx * s.roll - cx * s.roll_rate
              + ms * G * hs * o.sin(s.roll) + d.roll_moment_dist)
    det = p.mass * ix - msh * msh
    ay = (ix * fy + msh * m_roll) / det
    roll_acc = (p.mass * m_roll + msh * fy) / det
    ax = fx / p.mass
    yaw_acc = mz / p.yaw_inertia
    return o, s, c, fz, fxw, ax, ay, roll_acc, yaw_acc


def brake_lock_slope(p: VehicleParams) -> float:
    """[N m s/rad] The slope ``k`` of a friction brake's torque against the spin of a slow wheel
    (:data:`BRAKE_LOCK_SHARE` of ``C_kappa R_w^2 / V_LOW``)."""
    c_kappa, r_w = known(p, "longitudinal_stiffness", "wheel_radius")
    return BRAKE_LOCK_SHARE * c_kappa * r_w**2 / V_LOW


def brake_torque(o, brake, omega, slope):
    """The torque [N m] a friction brake asked for ``brake`` (>= 0; below 0 counts as 0) puts on a wheel
    spinning at ``omega`` [rad/s], signed as a drive torque: ``-T_b tanh(k omega / T_b)`` (the full torque
    against the spin beyond a few rad/s, nothing at a standstill; ``slope`` = k, :func:`brake_lock_slope`)."""
    t_b = o.fmax(brake, 0.0)
    return -t_b * o.tanh(slope * omega / o.fmax(t_b, 1.0))


def f(x, u, w, p: VehicleParams):
    """State derivative of the two-track model."""
    o, s, c, fz, fxw, ax, ay, roll_acc, yaw_acc = _accelerations(x, u, w, p)
    torques = (c.torque_fl, c.torque_fr, c.torque_rl, c.torque_rr)
    brakes = (c.brake_fl, c.brake_fr, c.brake_rl, c.brake_rr)
    omegas = (s.omega_fl, s.omega_fr, s.omega_rl, s.omega_rr)
    R = p.wheel_radius
    k = brake_lock_slope(p)
    wheel_acc = [(torques[i] - fxw[i] * R
                  - p.rolling_resistance * fz[i] * R * o.tanh(omegas[i] * R / 0.1)
                  + brake_torque(o, brakes[i], omegas[i], k)) / p.wheel_inertia
                 for i in range(4)]
    vx_dot = ax + s.vy * s.yaw_rate
    vy_dot = ay - s.vx * s.yaw_rate
    return o.stack([
        vx_dot, vy_dot, yaw_acc, s.roll_rate, roll_acc, *wheel_acc, s.yaw_rate,
        s.vx * o.cos(s.yaw) - s.vy * o.sin(s.yaw), s.vx * o.sin(s.yaw) + s.vy * o.cos(s.yaw),
        (ax - s.ax_f) / LOAD_TRANSFER_TAU, (ay - s.ay_f) / LOAD_TRANSFER_TAU,
    ])


def h(x, u, w, p: VehicleParams):
    """Named truth outputs (see :data:`plants.model.TRUTH`)."""
    o, s, c, fz, fxw, ax, ay, roll_acc, yaw_acc = _accelerations(x, u, w, p)
    beta = o.arctan2(s.vy, smooth_abs(s.vx, 1e-3, o))
    return o.stack([s.vx, s.vy, beta, s.yaw_rate, s.yaw, s.x, s.y, ax, ay, s.roll, s.roll_rate,
                    s.omega_fl, s.omega_fr, s.omega_rl, s.omega_rr])


def vertical_loads(x, u, w, p: VehicleParams):
    """Vertical tire loads (FL, FR, RL, RR) [N] at a state (diagnostics and tests)."""
    return _forces(x, u, w, p)[4]


def command_map(cmd, x, p: VehicleParams):
    """Common commands -> (steer, wheel torques).

    The driver's longitudinal demand is a speed hold (``drive_on = 1``): a force
    ``M k (v_ref - v_x)`` plus the resistances, made by the two rear in-wheel
    motors; the direct yaw moment is the motor torque difference
    ``N_z = (T_rr - T_rl) t_r / (2 R_w)``. Per-wheel limits ``max_motor_torque``
    apply when set. Front wheels carry no drive torque. The friction brake torques pass through
    (:func:`brake_torque` applies them against each wheel's spin).
    """
    o = ops_for(cmd, x)
    s = unpack(x, STATES)
    c = COMMANDS.unpack(cmd)
    steer, yaw_moment, speed_ref, drive_on = c.steer, c.yaw_moment, c.speed_ref, c.drive_on
    resist = (0.5 * AIR_DENSITY * p.drag_coefficient * p.frontal_area * s.vx * smooth_abs(s.vx, 0.1, o)
              + p.rolling_resistance * p.mass * G * o.tanh(s.vx / 0.1))
    force = drive_on * (p.mass * SPEED_GAIN * (speed_ref - s.vx) + resist)
    t_mean = force * p.wheel_radius / 2.0
    t_diff = torque_difference(yaw_moment, p.wheel_radius, p.track_rear)
    t_rl, t_rr = t_mean - t_diff, t_mean + t_diff
    if p.max_motor_torque is not None:
        lim = p.max_motor_torque
        t_rl, t_rr = o.fmin(o.fmax(t_rl, -lim), lim), o.fmin(o.fmax(t_rr, -lim), lim)
    zero = 0.0 * steer
    return o.stack([steer, zero, zero, t_rl, t_rr, c.brake_fl, c.brake_fr, c.brake_rl, c.brake_rr])


def initial(p: VehicleParams, speed: float):
    x0 = np.zeros(len(STATES))
    x0[STATES.index("vx")] = speed
    for name in ("omega_fl", "omega_fr", "omega_rl", "omega_rr"):
        x0[STATES.index(name)] = speed / known(p, "wheel_radius")[0]
    return x0


def max_stable_step(p: VehicleParams) -> float:
    """Largest RK4 step [s] for the stiffest mode (wheel spin at standstill), with margin.

    The wheel-spin eigenvalue is about ``-C_kappa R^2 / (I_w V_LOW)``; RK4 is stable
    on the negative real axis up to ``|lambda h| = 2.78``; 2.0 keeps a margin.
    """
    c_kappa, r_w, i_w = known(p, "longitudinal_stiffness", "wheel_radius", "wheel_inertia")
    lam = c_kappa * r_w**2 / (i_w * V_LOW)
    return 2.0 / lam if lam > 0 else math.inf


MODEL = PlantModel(
    name="two-track", description="nonlinear two-track model with roll, wheel spin and combined-slip tires, "
                                  "after seed 000 eq. 5-13",
    states=STATES, inputs=INPUTS, f=f, h=h, command_map=command_map, initial=initial,
    required_params=REQUIRED, max_step=max_stable_step,
)
