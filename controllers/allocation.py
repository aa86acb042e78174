"""Actuator allocation: the yaw moment the stability law asks, shared between the rear in-wheel motors
and the four friction brakes, each within its tyre's remaining grip; a slip limiter on every braked
wheel; the driver's own braking passed through. Written once for numpy and casadi, like the law.

* **Share** (:func:`allocate`, ``mode``): ``motors`` gives the whole moment to the rear motors' torque
  difference (the source paper's architecture); ``brakes`` to the brakes alone (a conventional ESC:
  no motor torque); ``blend`` gives the motors what they can make, ``motor_share`` of their yaw moment
  capacity ``2 T_max t_r / (2 R_w)``, fast and smooth, and the brakes the rest.
* **Which brake** (:func:`brake_moments`). A brake torque ``T`` at a wheel on side ``s`` (left +1) of an
  axle of track ``t`` makes the yaw moment ``s T t / (2 R_w)`` (:func:`plants.model.brake_yaw_moment`), so
  the brakes of the side the moment turns towards make it. The axle is chosen by what the brake costs
  the tyre's side force (combined slip): against the car's own rotation (oversteer: the moment and the
  yaw rate of opposite signs) the outer front wheel, whose lost side force turns the car less; with it
  (understeer) the inner rear wheel, whose lost side force lets the car turn more. The front share
  goes from 1 to 0 as ``N_z r`` goes from ``-axle_blend`` to ``+axle_blend`` (half each at ``N_z r`` =
  0, going straight).
* **Grip** (:func:`wheel_grip`). Each braked wheel's torque is held within what its tyre has left for a
  longitudinal force, ``sqrt((mu F_z)^2 - F_y^2) R_w``, with the static load plus the lateral load
  transfer of ``a_y`` (half the moment on each axle) and each axle's side force ``m a_y`` shared by the
  static axle loads (``l_r / L`` front), split between the axle's wheels by load; and within the
  hydraulic unit's largest pressure times the wheel's gain. What neither lets through is not made:
  :func:`allocate` returns the moment the brakes were given.
* **Slip limiter** (:func:`slip_limit`): a braked wheel's slip ``(v - omega R_w) / max(v, slip_speed)``
  beyond ``slip_onset`` times ``slip_max`` scales its pressure down, to nothing at ``slip_max`` (an
  anti-lock bound): the driver's pressure as much as the controller's.
* **Driver's braking**: each wheel's pressure is the driver's (the master cylinder's, the same at every
  wheel) plus the controller's, then slip-limited.

Pressures in pascal, torques in N m, yaw moments + turning left (ISO 8855).
"""

from __future__ import annotations

from dataclasses import dataclass

from evstab.plants import G
from evstab.plants.backend import NUMPY
from evstab.plants.errors import SettingsError
from evstab.plants.model import brake_yaw_moment

from .brakes import FIELDS as BRAKE_FIELDS

MODES = ("motors", "brakes", "blend")


@dataclass(frozen=True)
class AllocationDesign:
    """What the allocation needs of the car and its settings (SI)."""

    mass: float
    lf: float
    lr: float
    cg_height: float
    track_front: float
    track_rear: float
    wheel_radius: float
    brake_gain_front: float
    """[N m/Pa] torque per pascal of one front brake."""
    brake_gain_rear: float
    brake_pressure_max: float
    """[Pa] the hydraulic unit's largest pressure."""
    torque_max: float
    """[N m] one rear motor's torque limit."""
    mode: str = "motors"
    """``motors``, ``brakes`` or ``blend`` (the module notes)."""
    motor_share: float = 1.0
    """``blend``: the share of the motors' yaw capacity they are given before the brakes take the rest."""
    axle_blend: float = 100.0
    """[N m rad/s] the width in ``N_z r`` over which the brakes' moment moves from the front axle to the rear."""
    slip_max: float = 0.15
    """[-] a braked wheel's slip at which its pressure is gone."""
    slip_onset: float = 0.6
    """[-] share of ``slip_max`` where the slip limiter starts to take pressure off."""
    slip_speed: float = 3.0
    """[m/s] the smallest speed a slip is referred to (below it a slip says little)."""

    def __post_init__(self):
        if self.mode not in MODES:
            raise SettingsError(f"allocation mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for k in ("mass", "cg_height", "track_front", "track_rear", "wheel_radius", "brake_gain_front",
                  "brake_gain_rear", "brake_pressure_max", "torque_max", "axle_blend", "slip_max", "slip_speed"):
            if not getattr(self, k) > 0:
                raise SettingsError(f"allocation setting '{k}' must be > 0, got {getattr(self, k)!r}")
        if not 0.0 <= self.motor_share <= 1.0:
            raise SettingsError(f"allocation setting 'motor_share' must be within [0, 1], got {self.motor_share!r}")
        if not 0.0 < self.slip_onset < 1.0:
            raise SettingsError(f"allocation setting 'slip_onset' must be within (0, 1), got {self.slip_onset!r}")

    @classmethod
    def from_vehicle(cls, p, mode: str = "motors", **settings) -> "AllocationDesign":
        """The allocation of vehicle ``p`` (:class:`plants.params.VehicleParams`: its geometry, brakes and motor
        torque limit; a :class:`plants.errors.ParameterError` naming what the file lacks) in ``mode``."""
        p.require("cg_height", "track_front", "track_rear", "wheel_radius", "max_motor_torque", *BRAKE_FIELDS,
                  model="the brakes' allocation")
        return cls(mass=p.mass, lf=p.lf, lr=p.lr, cg_height=p.cg_height, track_front=p.track_front,
                   track_rear=p.track_rear, wheel_radius=p.wheel_radius, brake_gain_front=p.brake_gain_front,
                   brake_gain_rear=p.brake_gain_rear, brake_pressure_max=p.brake_pressure_max,
                   torque_max=p.max_motor_torque, mode=mode, **settings)

    @property
    def gains(self) -> tuple[float, float, float, float]:
        """[N m/Pa] at (FL, FR, RL, RR)."""
        return (self.brake_gain_front, self.brake_gain_front, self.brake_gain_rear, self.brake_gain_rear)

    @property
    def motor_yaw_capacity(self) -> float:
        """[N m] the yaw moment the rear motors' torque difference makes at their torque limit."""
        return self.torque_max * self.track_rear / self.wheel_radius


def brake_yaw_capacity(d: AllocationDesign, mu):
    """[N m] The yaw moment one wheel's brake makes at friction ``mu`` with its static load, the larger of a front
    and a rear wheel (``mu F_z t / 2``): what the law may ask of the brakes (:func:`wheel_grip` holds each wheel
    within its tyre's grip as the car turns)."""
    L = d.lf + d.lr
    front = 0.5 * d.mass * G * d.lr / L * 0.5 * d.track_front
    rear = 0.5 * d.mass * G * d.lf / L * 0.5 * d.track_rear
    return mu * max(front, rear)


def wheel_grip(d: AllocationDesign, mu, ay, o=NUMPY):
    """The brake torque [N m] each tyre (FL, FR, RL, RR) has left for a longitudinal force at friction ``mu``
    and lateral acceleration ``ay`` [m/s^2] (the module notes: static load plus lateral transfer, the axle's
    side force shared by load)."""
    L = d.lf + d.lr
    m = d.mass
    fz_axle = (m * G * d.lr / L, m * G * d.lf / L)
    fy_axle = (m * ay * d.lr / L, m * ay * d.lf / L)
    tracks = (d.track_front, d.track_rear)
    out = []
    for a in range(2):
        dz = 0.5 * m * d.cg_height * ay / tracks[a]  # half the overturning moment on each axle
        for side in (1.0, -1.0):  # left, right: a left turn (ay > 0) loads the right (outer) wheel
            fz = o.fmax(0.5 * fz_axle[a] - side * dz, 0.0)
            fy = fy_axle[a] * fz / fz_axle[a]
            room = (mu * fz) ** 2 - fy ** 2
            out.append(o.sqrt(o.fmax(room, 0.0)) * d.wheel_radius)
    return tuple(out)


def brake_moments(d: AllocationDesign, nz_brake, yaw_rate, o=NUMPY):
    """The brake torques (FL, FR, RL, RR) [N m] that make ``nz_brake`` [N m] (before any limit): the side
    ``nz_brake`` turns towards, the front and rear shares from ``nz_brake x yaw_rate`` (the module notes)."""
    front = o.fmin(o.fmax(0.5 - nz_brake * yaw_rate / (2.0 * d.axle_blend), 0.0), 1.0)
    left = nz_brake > 0.0
    size = o.fabs(nz_brake) * 2.0 * d.wheel_radius
    t_front = front * size / d.track_front
    t_rear = (1.0 - front) * size / d.track_rear
    zero = 0.0 * nz_brake
    return (o.if_else(left, t_front, zero), o.if_else(left, zero, t_front),
            o.if_else(left, t_rear, zero), o.if_else(left, zero, t_rear))


def slip_limit(d: AllocationDesign, pressure, omega, speed, o=NUMPY):
    """``pressure`` [Pa] at a wheel spinning at ``omega`` [rad/s], the car at ``speed`` [m/s], after the slip
    limiter: whole up to ``slip_onset x slip_max`` of braking slip, none from ``slip_max``, linear between."""
    slip = (speed - omega * d.wheel_radius) / o.fmax(speed, d.slip_speed)
    onset = d.slip_onset * d.slip_max
    keep = o.fmin(o.fmax((d.slip_max - slip) / (d.slip_max - onset), 0.0), 1.0)
    return pressure * keep


def allocate(d: AllocationDesign, nz, yaw_rate, speed, ay, mu, omegas, p_driver, o=NUMPY):
    """The law's yaw moment ``nz`` [N m] shared out (the module notes).

    ``yaw_rate`` [rad/s], ``speed`` [m/s], ``ay`` [m/s^2] and ``mu`` as the ECU estimates them; ``omegas`` the
    four wheel speeds (FL, FR, RL, RR) [rad/s]; ``p_driver`` [Pa] the driver's brake pressure.

    Returns ``(nz_motors, pressures, nz_brakes)``: the yaw moment the rear motors are asked, the pressure at
    each wheel (FL, FR, RL, RR) [Pa], and the yaw moment the brakes' controller pressures make before the slip
    limiter (what the grip and the hydraulic unit let through).
    """
    if d.mode == "motors":
        nz_m = nz
    elif d.mode == "brakes":
        nz_m = 0.0 * nz
    else:
        share = d.motor_share * d.motor_yaw_capacity
        nz_m = o.fmin(o.fmax(nz, -share), share)
    wanted = brake_moments(d, nz - nz_m, yaw_rate, o)
    grip = wheel_grip(d, mu, ay, o)
    gains = d.gains
    torques = [o.fmin(wanted[i], o.fmin(grip[i], d.brake_pressure_max * gains[i])) for i in range(4)]
    made = brake_yaw_moment(torques, d.wheel_radius, d.track_front, d.track_rear)
    p_drv = o.fmax(p_driver, 0.0)
    pressures = tuple(slip_limit(d, o.fmin(p_drv + torques[i] / gains[i], d.brake_pressure_max), omegas[i], speed, o)
                      for i in range(4))
    return nz_m, pressures, made
