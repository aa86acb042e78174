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
``reference_tau``, whose derivative ``(x_ss - x_d) / tau`` is known exactly: that is
the ``x_d'`` the feed-forward uses (``reference_model="static"``, the paper's).

A car's own yaw response is not a first-order lag: at a quick turn-in it lags the lagged
reference and then overshoots it, and a law that tracks that reference fights the driver
in a swerve the car drives through alone. The default reference
(``reference_model="linear"``) is therefore the nominal linear car itself, driven by the
driver's steer, ``x_l' = A x_l + B (delta_driver, 0)``, its yaw rate held within the same
friction and rollover limit (approached through the lag when the limit binds). Where the
limit does not bind its feed-forward is exactly the driver's steer and no yaw moment. The
error the supervised law acts on is the distance to the band between the linear car and
the lagged static reference (0 while the estimate lies between them: a car whose tyres are
softer than the nominal's responds more slowly than the linear car but reaches the same
steady state). Where the driver's linear demand exceeds the rollover limit by
``limit_demand_lo`` to ``limit_demand_hi`` times (the ``limit_share`` signal, 0 to 1), the
reference and the band move to the lagged static reference: a high car needs the law early,
before the transient's overshoot of lateral acceleration tips it. With ``always_active``
(the paper's controller and the stability analysis) there is no band: the error is the
reference minus the estimate.

Discrete realisation at the control period ``dt``: the integrator and the
reference lag by zero-order hold (``xi[k+1] = xi[k] + dt e[k]``, exact for a held
error; the lag with ``exp(-dt/tau)``). Anti-windup by conditional integration: the sideslip
integrator is held while the steer is limited; the yaw-rate integrator while the yaw moment and the
steer are both limited (with the yaw moment alone limited, :func:`allocate` moves the yaw-rate row to the
steer, which can still close the error: the rear tyres at the limit leave the yaw moment no authority,
and a held integrator left a slow slide uncorrected for seconds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from evstab.plants import G, VehicleParams
from evstab.plants.backend import NUMPY
from evstab.plants.bicycle import lateral_coefficients, lateral_matrices, steady_state_gains
from evstab.plants.errors import DesignError
from evstab.plants.signals import Layout, Signal

if TYPE_CHECKING:
    from .schedule import SpeedSchedule



REFERENCE_MODELS = ("linear", "static")
"""The law's reference models (:attr:`TwoDofDesign.reference_model`)."""
FRICTION_MARGIN = 0.87
"""Default yaw-rate reference limit [share of mu g / v] in a held limit turn (:attr:`TwoDofDesign.friction_margin`).
A saturated car sustains about ``peak_ratio`` (0.95) of mu g, and the friction estimate follows what it
delivers: a reference with no margin in a steady limit turn asks for the last of the rear tyres' grip and the
car drifts out over seconds (a step held 8 s at 130 km/h on mu 0.5). The figures are in docs/controller.md."""
TURN_IN_MARGIN = 0.95
"""Default yaw-rate reference limit [share of mu g / v] in the first :attr:`TwoDofDesign.turn_in_time` of a turn
beyond the limit (:attr:`TwoDofDesign.turn_in_margin`): a transient reaches the tyres' peak without a steady
slide, and a lower limit cuts a swerve the car can drive (the Vanagon's file +40 % in FMVSS 126 on mu 0.5
misses the lateral displacement with the steady 0.87 from the first period)."""
STEER_AUTHORITY = float(np.deg2rad(20.0))
"""Default steer authority [rad road wheel] where the vehicle file gives none."""
STEER_AUTHORITY_RATE = float(np.deg2rad(100.0))
"""Default steer-authority rate [rad/s] where the vehicle file gives none."""


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
    reference_model: str = "linear"
    """``linear``: the nominal linear car driven by the driver's steer, with the band to the lagged static
    reference; ``static``: seed 003's static reference through the lag (see the module notes)."""
    limit_demand_lo: float = 1.2
    """Driver's linear lateral-acceleration demand, as a multiple of the rollover limit
    (:attr:`ay_limit`), from which the reference moves towards the lagged static one ..."""
    limit_demand_hi: float = 1.5
    """... and at which it is the lagged static one."""
    min_speed: float = 3.0
    """Below this speed [m/s] the controller passes the driver's steer through and makes no yaw moment."""
    friction_margin: float = FRICTION_MARGIN
    """The reference's yaw-rate limit as a share of ``mu g / v`` (seed 003 eq. 23-24's ``k``, with ``mu`` the
    ECU's friction estimate) once a turn beyond the limit is held; :data:`FRICTION_MARGIN` by default. The
    law itself (:func:`control_law`, :func:`reference`) always uses this share; the ECU moves the friction
    it passes the law so that the limit is ``turn_in_margin`` at a turn-in
    (:func:`controllers.supervisor.reference_margin`)."""
    turn_in_margin: float = TURN_IN_MARGIN
    """The ECU's reference limit as a share of ``mu g / v`` for the first ``turn_in_time`` while the driver's
    linear demand is beyond the limit; it then moves to ``friction_margin`` over ``turn_in_fall_time``."""
    turn_in_time: float = 1.0
    """How long [s] the reference limit stays at ``turn_in_margin`` once the driver's linear demand is beyond it."""
    turn_in_fall_time: float = 1.0
    """How long [s] it then takes to move linearly from ``turn_in_margin`` to ``friction_margin``."""
    disturbance_rejection: bool = True
    yaw_moment_max: float | None = None
    """Largest achievable |N_z| [N m]; default from the rear motors: T_max t_r / R_w."""
    steer_max: float = np.deg2rad(35.0)
    yaw_priority: float = 4.0
    """Weight of the yaw-rate row against the sideslip row when a command saturates."""
    beta_error_max: float = np.inf
    """Largest sideslip error [rad] the feedback acts on (inf: no limit)."""
    disturbance_filter_tau: float = 0.0
    """First-order low-pass [s] on the disturbance estimates before rejection (0 = none)."""
    # supervision (controllers.supervisor): when the law acts, its authority, the friction on board
    always_active: bool = False
    """True: the law acts whenever the car is above ``min_speed`` (seed 003's controller), no dead bands."""
    yaw_rate_deadband: float = np.deg2rad(2.0)
    """Yaw-rate error [rad/s] that activates the law at standstill speed."""
    yaw_rate_deadband_per_speed: float = np.deg2rad(0.05)
    """Growth of that dead band with speed [rad/s per m/s]: 3.1 deg/s at 80 km/h."""
    deadband_shrink: float = 0.5
    """Share by which the dead bands shrink at full friction use [-]."""
    understeer_band: float = 0.2
    """Share of the reference band's smaller yaw rate by which the band reaches towards 0 [-]: a car that turns
    the reference's way at no less than ``1 - understeer_band`` of it is inside (a nominal model's stiffness
    error shows as a share of the reference; oversteer gets no such allowance), while the driver asks at most
    ``understeer_demand`` of the reference's yaw-rate limit, none from the limit on (:func:`understeer_share`)."""
    understeer_demand: float = 0.8
    """The driver's linear demand, as a share of the reference's yaw-rate limit, up to which the understeer band
    is whole [-] (below 1)."""
    beta_threshold: float = np.deg2rad(3.0)
    """Estimated sideslip [rad] that activates the law (when ``beta_std < beta_std_max``)."""
    beta_std_max: float = np.deg2rad(2.0)
    """Sideslip-estimate standard deviation [rad] above which the sideslip criterion is not trusted."""
    deactivate_ratio: float = 0.5
    """Hysteresis: the law stays active until both errors are below this share of their thresholds."""
    hold_time: float = 0.5
    """... for this long [s]."""
    release_use: float = 0.9
    """... and while the car uses less than this share of the estimated friction (``|a_y| / (mu_est g)``): a law
    released at the limit gives the drive torque back to saturated rear tyres (the drive cut ends with it)."""
    blend_time: float = 0.1
    """The law's authority ramps in and out over this time [s]."""
    drive_cut: float = 0.5
    """Share of the driver's drive torque the ECU takes away at the law's full authority [-], in proportion to
    its blend weight (the ``drive_share`` output; none with ``always_active``): the torque intervention of an
    ESC, which leaves the rear tyres' grip to the side force and the yaw moment while the law acts. Not all
    of it: in a turn held at the limit the whole cut slows the car, moves load to the front axle and the rear
    drifts out (lift-off oversteer; a step held 8 s at 130 km/h on mu 0.5 slides to 6 deg with 1.0)."""
    ay_roll_factor: float | None = None
    """The car's lateral acceleration per lateral accelerometer reading in steady cornering [-]: the body rolls
    ``phi = k a_y`` (``k`` :attr:`plants.VehicleParams.roll_gradient`) and the accelerometer reads
    ``a_y + g phi``, so the factor is ``1 / (1 + g k)``; None: the nominal file's
    :attr:`plants.VehicleParams.roll_reading_factor` (1 without its roll data).
    The supervisor reads the friction the car uses through it (a reading 10 % high on compact-ev set the
    friction estimate above the road's)."""
    steer_authority: float | None = None
    """Largest steer correction [rad road wheel] the steer-by-wire adds to the driver's; None: the
    vehicle file's ``steer_authority``, else :data:`STEER_AUTHORITY`. FMVSS 126 on
    compact-ev (two-track, 80 km/h) needs it: on mu 1, 3 deg pass 22 / 44 runs, 6 deg 32, 8 deg 40,
    10 deg 44; on mu 0.6, 10 deg 40 / 44 and 20 deg 44 (the rear motors cannot help a car whose rear
    tyres are saturated, and the front has only the steer)."""
    steer_authority_rate: float | None = None
    """Largest rate of that correction [rad/s]; None: the vehicle file's ``steer_authority_rate``, else
    :data:`STEER_AUTHORITY_RATE`."""
    mu_max: float = 1.0
    """Friction the ECU assumes without evidence of less (and its upper bound) [-]."""
    mu_min: float = 0.1
    saturation_ratio: float = 0.8
    """Saturated when the car delivers less than this share of the linear model's lateral acceleration."""
    saturation_ay_min: float = 2.0
    """Lateral-acceleration demand [m/s^2] below which saturation is not judged."""
    demand_tau: float = 0.15
    """Lag [s] of the linear lateral-acceleration demand the measured one is compared with."""
    rollover_share: float = 0.7
    """The reference's lateral acceleration stays below this share of the quasi-static rollover threshold
    (:attr:`plants.params.VehicleParams.rollover_threshold`, when the vehicle file gives the tracks and the
    CG height; the rigid car's ``g (t_f + t_r) / (4 h)`` lowered by the body's roll where the file gives
    the roll data). The margin is for the transient: a step of lateral acceleration overshoots the body's
    steady roll by the lightly damped roll mode (damping ratio 0.28-0.35 on the bundled cars)."""
    slip_max: float = 0.1
    """Rear wheel slip [-] beyond which the yaw moment is withdrawn (slip control)."""
    slip_onset: float = 0.5
    """Share of ``slip_max`` where slip control starts to withdraw the yaw moment [-]."""
    slip_lead_time: float = 0.05
    """[s] ahead that slip control predicts the slip from its growth (the time constant of the slip's lag)."""
    slip_cut_time: float = 0.02
    """[s] for the yaw moment's authority to fall to 0 while a rear wheel slips."""
    slip_recover_time: float = 0.5
    """[s] for it to come back."""
    ay_headroom: float = 2.0
    """[m/s^2] above the measured lateral acceleration (and ``ay_headroom_share`` of it) the yaw-rate
    reference may ask for: a reference beyond ``|a_y| / v`` asks for a growing slide. At a quick turn-in the
    yaw rate leads the lateral acceleration while the car's own sideslip builds up; with 1.25 the Vanagon
    (+40 % file) read that as a slide in FMVSS 126 on mu 0.5, cut the steer to 0.35 deg of the driver's 16.4 and
    fell 14 mm short of the 1.83 m of lateral displacement."""
    ay_headroom_share: float = 0.1
    phase_beta: float = np.deg2rad(4.0)
    """Half-width [rad] of the sideslip phase-plane region ``|beta + phase_tau beta'| <= phase_beta``
    (:func:`controllers.supervisor.phase_plane_excess`); a value beyond any sideslip (1e9) switches the
    guard off."""
    phase_tau: float = 0.3
    """Weight [s] of the sideslip rate in the phase-plane region (how far ahead it looks)."""
    geometric_share: float = 1.0
    """Share of the geometric sideslip ``l_r r / v`` (the rear axle's path inside the CG's in a turn) the
    sideslip threshold and the phase plane leave out of the sideslip they judge [-]."""
    phase_gain_nz: float = 50.0
    """Yaw moment per unit of phase-plane excess, as a yaw acceleration [1/s^2] (times I_z)."""
    phase_gain_steer: float = 1.0
    """Steer correction per unit of phase-plane excess [rad/rad]."""
    guard_share: float = 0.0
    """The yaw guard acts once the yaw-rate error exceeds this share of the activation dead band."""
    guard_width: float = 0.25
    """... and drops an opposing command in full from ``guard_share + guard_width`` of it, in proportion
    between (a guard that switched at one error would chatter the command with the gyro's noise)."""
    gust_deadband: float = np.deg2rad(0.3)
    """Yaw-rate and course-rate error [rad/s] beyond which the gust channel acts while the driver goes
    straight (:func:`controllers.supervisor.gust_moment`)."""
    gust_gain: float = 80.0
    """Gust channel's yaw moment per rad/s of error beyond its band, as a yaw acceleration [1/s] (times I_z)."""
    gust_nz_max: float = 2000.0
    """Largest yaw moment [N m] of the gust channel (never above what the rear tyres' grip allows)."""
    gust_course_share: float = 0.6
    """Share of the kinematic sideslip rate ``a_y / v - r`` in the error the gust channel acts on: 1 makes
    it the course-rate error ``r_ref - a_y / v`` (a gust pushes the car sideways as much as it turns it),
    0 the yaw-rate error. Below 1 because the accelerometer also reads the body's roll: at 1 the
    channel's moment swings at about 2 Hz on the multi-body cars (docs/controller.md)."""
    gust_tau: float = 0.05
    """Low-pass time constant [s] of the gust channel's errors (the sensors' noise)."""
    gust_demand: float = 0.15
    """The driver goes straight while the linear demand and its change are below this [m/s^2]: the gust
    channel has its whole authority up to it and none from twice it."""
    rear_grip_share: float = 0.5
    """Share of the rear tyres' remaining grip (friction circle less the lateral use) the yaw moment
    may take: differential torque costs rear side force."""
    peak_ratio: float = 0.95
    """Lateral acceleration of a saturated car as a share of mu g [-]."""
    mu_tau_down: float = 0.2
    """Time constant [s] of the friction estimate falling to what a saturated car delivers."""
    mu_tau_slide: float = 0.05
    """... while the car slides out: its yaw rate beyond what its lateral acceleration carries, ``(r - a_y / v)
    sign(a_y)``, by more than ``slide_rate_fast`` (a road turned slippery under a car in a turn)."""
    slide_rate_fast: float = np.deg2rad(4.0)
    """Sideslip rate against the turn [rad/s] from which the friction estimate falls with ``mu_tau_slide``. In the
    envelope's friction drop on compact-ev (seed 0) the rate is at most 2.2 deg/s while the car turns in at 0.5 g
    and 6.2-7.5 deg/s in the first 50 ms after the drop."""
    slide_demand_steady: float = 0.2
    """... and only while the driver holds the turn: the linear demand now within this share of the lagged one
    [-]. In ISO 3888-1 at 100 km/h on mu 0.5 (compact-ev, seed 2) the reversal's yaw rate leads the lateral
    acceleration by more than ``slide_rate_fast`` without a slide."""
    mu_tau_up: float = 2.0
    """Time constant [s] of its recovery towards ``mu_max``."""
    method: str = "zoh (integrator and reference lag); feed-forward from the lag's exact derivative"
    schedule: SpeedSchedule | None = None
    """A :class:`controllers.schedule.SpeedSchedule` (firmware: coefficients and reference gains from
    tables), or None (exact model)."""

    def __post_init__(self):
        for name, default in (("steer_authority", STEER_AUTHORITY), ("steer_authority_rate", STEER_AUTHORITY_RATE)):
            if getattr(self, name) is None:
                own = getattr(self.params, name, None)
                object.__setattr__(self, name, float(default if own is None else own))
        if self.ay_roll_factor is None:
            object.__setattr__(self, "ay_roll_factor", float(self.params.roll_reading_factor))
        if not 0.0 < self.ay_roll_factor <= 1.0:
            raise DesignError(f"controller setting 'ay_roll_factor' must be in (0, 1], got {self.ay_roll_factor!r}")
        if not self.turn_in_time >= 0:
            raise DesignError(f"controller setting 'turn_in_time' must be >= 0 s, got {self.turn_in_time!r}")
        if not (self.k_beta > 0 and self.k_gamma > 0):
            raise DesignError(f"K_beta and K_gamma must be > 0 rad/s, got {self.k_beta}, {self.k_gamma}")
        if not self.dt > 0:
            raise DesignError(f"control period must be > 0 s, got {self.dt}")
        for name in ("blend_time", "hold_time", "mu_tau_down", "mu_tau_up", "peak_ratio", "mu_min", "demand_tau",
                     "slip_cut_time", "slip_recover_time", "slip_lead_time", "guard_width", "mu_tau_slide",
                     "turn_in_fall_time", "release_use", "friction_margin", "turn_in_margin"):
            if not getattr(self, name) > 0:
                raise DesignError(f"controller setting '{name}' must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.drive_cut <= 1.0:
            raise DesignError(f"controller setting 'drive_cut' must be in [0, 1], got {self.drive_cut!r}")
        if not 0.0 <= self.understeer_demand < 1.0:
            raise DesignError(f"controller setting 'understeer_demand' must be in [0, 1), got {self.understeer_demand!r}")
        if self.reference_model not in REFERENCE_MODELS:
            raise DesignError(f"controller setting 'reference_model' must be one of {', '.join(REFERENCE_MODELS)}, "
                              f"got {self.reference_model!r}")
        if not self.limit_demand_hi > self.limit_demand_lo:
            raise DesignError(f"controller settings need limit_demand_hi > limit_demand_lo, got "
                              f"{self.limit_demand_hi!r}, {self.limit_demand_lo!r}")
        if not 0 <= self.slip_onset < 1:
            raise DesignError(f"controller setting 'slip_onset' must be in [0, 1), got {self.slip_onset!r}")
        if not 0 < self.mu_min <= self.mu_max:
            raise DesignError(f"controller friction bounds need 0 < mu_min <= mu_max, got {self.mu_min}, {self.mu_max}")

    @property
    def nz_max(self) -> float:
        if self.yaw_moment_max is not None:
            return self.yaw_moment_max
        p = self.params
        if p.max_motor_torque is not None and p.track_rear is not None and p.wheel_radius is not None:
            return p.max_motor_torque * p.track_rear / p.wheel_radius
        return np.inf

    @property
    def ay_limit(self):
        """Largest lateral acceleration [m/s^2] the reference asks for: ``rollover_share`` of the
        quasi-static rollover threshold (:attr:`plants.params.VehicleParams.rollover_threshold`: the
        body's roll counted where the vehicle file gives it), or no limit without tracks and CG height."""
        threshold = self.params.rollover_threshold
        return 1e6 if threshold is None else self.rollover_share * threshold

    @property
    def kd(self) -> np.ndarray:
        return np.diag([self.k_beta, self.k_gamma])

    def gains(self, speed: float):
        """(B^-1, B^-1 Kd, -B^-1 A Kd, B^-1 A) at ``speed``: the scheduled matrices of the law."""
        A, B = lateral_matrices(self.params, max(speed, self.min_speed))
        Bi = np.linalg.inv(B)
        return Bi, Bi @ self.kd, -Bi @ A @ self.kd, Bi @ A


STATE = Layout("controller state", [
    Signal("xi_beta", "rad s", "integral of the sideslip error"),
    Signal("xi_yaw_rate", "rad", "integral of the yaw-rate error"),
    Signal("beta_ref", "rad", "the lagged sideslip reference"),
    Signal("yaw_rate_ref", "rad/s", "the lagged yaw-rate reference"),
    Signal("dist_beta", "rad/s", "the low-passed disturbance estimate d1"),
    Signal("dist_yaw_rate", "rad/s^2", "the low-passed disturbance estimate d2"),
    Signal("beta_linear", "rad", "sideslip of the nominal linear car driven by the driver's steer"),
    Signal("yaw_rate_linear", "rad/s", "yaw rate of that car, within the friction limit"),
])
"""Controller state: error integrals, the lagged static reference, the low-passed disturbance estimates, the
linear car (reference_model ``linear``; with ``static`` it equals the lagged reference)."""
SIGNALS = Layout("controller signals", [
    Signal("speed", "m/s", "vehicle speed"),
    Signal("steer_driver", "rad", "the driver's road-wheel angle"),
    Signal("beta", "rad", "estimated sideslip"),
    Signal("yaw_rate", "rad/s", "estimated yaw rate"),
    Signal("d1", "rad/s", "disturbance estimate on the sideslip equation"),
    Signal("d2", "rad/s^2", "disturbance estimate on the yaw-rate equation"),
    Signal("mu", "-", "friction the reference is limited with"),
    Signal("steer_limited", "-", "1 while the steer command was limited"),
    Signal("yaw_moment_limited", "-", "1 while the yaw moment was limited"),
    Signal("limit_share", "-", "0: the reference is the linear car, 1: the lagged static one (between: a blend)"),
])
OUTPUTS = Layout("controller outputs", [
    Signal("steer", "rad", "front road-wheel angle command"),
    Signal("yaw_moment", "N m", "direct yaw moment command"),
    Signal("beta_ref", "rad", "sideslip reference"),
    Signal("yaw_rate_ref", "rad/s", "yaw-rate reference"),
    Signal("yaw_rate_error", "rad/s", "the yaw-rate error the law acts on (0 inside the reference band)"),
])


def control_law(d: TwoDofDesign, z, sig, o=NUMPY, nz_limit=None):
    """One control period, written once for numpy and casadi: ``(z, sig) -> (z_next, out)``.

    ``z`` per :data:`STATE`, ``sig`` per :data:`SIGNALS`, ``out`` per :data:`OUTPUTS`; ``nz_limit``
    the largest yaw moment this period allows (default ``nz_max``; the ECU passes what the rear
    tyres' remaining grip allows, :func:`controllers.supervisor.yaw_moment_limit`).
    """
    s = SIGNALS.unpack(sig)
    zs = STATE.unpack(z)
    v = s.speed
    vm = o.fmax(v, d.min_speed)
    beta_lin, gamma_lin, limit, (a11, a12, a21, a22, b11, b21, b22) = _reference_parts(d, vm, s.steer_driver, s.mu, o)
    beta_ss, gamma_ss = _limited(beta_lin, gamma_lin, limit, o)
    lag = float(np.exp(-d.dt / d.reference_tau))
    # the lagged static reference (seed 003 eq. 23 through the lag)
    sb, sr = zs.beta_ref, zs.yaw_rate_ref
    sb_next, sr_next = beta_ss + (sb - beta_ss) * lag, gamma_ss + (sr - gamma_ss) * lag
    if d.reference_model == "linear":
        # the nominal linear car on the driver's steer (explicit Euler at the control period); where its yaw
        # rate would pass the limit it goes through the lag to the limited static reference instead (a steady
        # state of the linear car, for the steer that the limit allows)
        lb, lr = zs.beta_linear, zs.yaw_rate_linear
        ub = lb + d.dt * (a11 * lb + a12 * lr + b11 * s.steer_driver)
        ur = lr + d.dt * (a21 * lb + a22 * lr + b21 * s.steer_driver)
        over = o.fabs(ur) > limit
        lb_next = o.if_else(over, beta_ss + (lb - beta_ss) * lag, ub)
        lr_next = o.if_else(over, gamma_ss + (lr - gamma_ss) * lag, ur)
        w = o.fmin(o.fmax(s.limit_share, 0.0), 1.0)
    else:
        lb, lr, lb_next, lr_next, w = sb, sr, sb_next, sr_next, 1.0
    # the reference: the linear car, moved by limit_share towards the lagged static reference; its derivative
    # from the two parts' own (the lag's exactly, the linear car's over the period)
    xb, xr = lb + w * (sb - lb), lr + w * (sr - lr)
    xb_dot = (1.0 - w) * (lb_next - lb) / d.dt + w * (beta_ss - sb) / d.reference_tau
    xr_dot = (1.0 - w) * (lr_next - lr) / d.dt + w * (gamma_ss - sr) / d.reference_tau
    # the law u = B^-1 (x_d' - A x_d + Kd e - A Kd xi - d); supervised, e is the distance to the band between
    # the reference and the lagged static reference (0 inside it); always active (no band) x_d - x
    if d.always_active:
        e_b, e_r = xb - s.beta, xr - s.yaw_rate
    else:
        e_b = o.fmin(o.fmax(s.beta, o.fmin(xb, sb)), o.fmax(xb, sb)) - s.beta
        # the understeer side reaches towards 0 only while the driver asks less than the road gives (a shortfall
        # there is the model's; beyond, the car may need the law to turn it)
        lo, hi = o.fmin(xr, sr), o.fmax(xr, sr)
        share = _understeer_share(d, gamma_lin, limit, o)
        lo, hi = lo - share * o.fmax(lo, 0.0), hi - share * o.fmin(hi, 0.0)
        e_r = o.fmin(o.fmax(s.yaw_rate, lo), hi) - s.yaw_rate
    if np.isfinite(d.beta_error_max):
        e_b = o.fmin(o.fmax(e_b, -d.beta_error_max), d.beta_error_max)
    if d.disturbance_rejection:
        if d.disturbance_filter_tau > 0:
            k = 1.0 - float(np.exp(-d.dt / d.disturbance_filter_tau))
            dist_b, dist_r = zs.dist_beta + (s.d1 - zs.dist_beta) * k, zs.dist_yaw_rate + (s.d2 - zs.dist_yaw_rate) * k
        else:
            dist_b, dist_r = s.d1, s.d2
    else:
        dist_b, dist_r = 0.0 * v, 0.0 * v
    kb_, kr_ = d.k_beta, d.k_gamma
    xi_b, xi_r = zs.xi_beta, zs.xi_yaw_rate
    v1 = xb_dot - (a11 * xb + a12 * xr) + kb_ * e_b - (a11 * kb_ * xi_b + a12 * kr_ * xi_r) - dist_b
    v2 = xr_dot - (a21 * xb + a22 * xr) + kr_ * e_r - (a21 * kb_ * xi_b + a22 * kr_ * xi_r) - dist_r
    delta = v1 / b11
    nz = (v2 - b21 * delta) / b22
    # the steer the ECU can command: the driver's plus the superposition's authority, within steer_max
    lo = o.fmax(s.steer_driver - d.steer_authority, -d.steer_max)
    hi = o.fmin(s.steer_driver + d.steer_authority, d.steer_max)
    delta, nz = allocate(d, delta, nz, b11, b21, b22, o, lo, hi, nz_limit)
    low = v < d.min_speed
    delta = o.if_else(low, s.steer_driver, delta)
    nz = o.if_else(low, 0.0, nz)
    # conditional integration: hold xi in a channel whose command is limited; reset at low speed
    xi_b_next = o.if_else(low, 0.0, o.if_else(s.steer_limited > 0.5, xi_b, xi_b + d.dt * e_b))
    xi_r_next = o.if_else(low, 0.0, o.if_else(s.yaw_moment_limited * s.steer_limited > 0.5, xi_r, xi_r + d.dt * e_r))
    z_next = STATE.pack(o=o, xi_beta=xi_b_next, xi_yaw_rate=xi_r_next, beta_ref=sb_next, yaw_rate_ref=sr_next,
                        dist_beta=o.if_else(low, 0.0, dist_b), dist_yaw_rate=o.if_else(low, 0.0, dist_r),
                        beta_linear=lb_next, yaw_rate_linear=lr_next)
    return z_next, OUTPUTS.pack(o=o, steer=delta, yaw_moment=nz, beta_ref=xb, yaw_rate_ref=xr, yaw_rate_error=e_r)


def reference(d: TwoDofDesign, vm, steer_driver, mu, o=NUMPY, limited: bool = True):
    """The static reference of seed 003 eq. 23-24 with the friction limit ``|gamma_d| <= k_mu mu g / v``
    at speed ``vm`` (already held at ``min_speed``), and the model's seven coefficients there:
    ``(beta_ss, gamma_ss, (a11, a12, a21, a22, b11, b21, b22))`` (``limited=False``: the linear model's
    own steady state, no friction or rollover limit). The lateral acceleration the reference asks for is
    also held below :attr:`TwoDofDesign.ay_limit`. A design that carries a speed
    schedule reads coefficients and reference gains from its tables (the firmware's arithmetic)."""
    beta_lin, gamma_lin, limit, coeffs = _reference_parts(d, vm, steer_driver, mu, o)
    if not limited:
        return beta_lin, gamma_lin, coeffs
    return (*_limited(beta_lin, gamma_lin, limit, o), coeffs)


def _reference_parts(d: TwoDofDesign, vm, steer_driver, mu, o=NUMPY):
    """``(beta_lin, gamma_lin, limit, coefficients)``: the linear model's steady state for the driver's steer, the
    reference's yaw-rate limit (:func:`yaw_rate_limit`) and the model's seven coefficients at ``vm``, each
    computed once for the law, the reference band and the understeer share."""
    p = d.params
    if d.schedule is not None:
        a11, a12, a21, a22, b11, b21, b22, kb, kg = d.schedule.values(vm, o)
    else:
        kb, kg = steady_state_gains(p, vm)
        a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(p, vm)
    return kb * steer_driver, kg * steer_driver, yaw_rate_limit(d, vm, mu, o), (a11, a12, a21, a22, b11, b21, b22)


def _limited(beta_lin, gamma_lin, limit, o=NUMPY):
    """The static reference: the linear steady state scaled down to the yaw-rate limit where it is beyond it."""
    mag = o.fabs(gamma_lin)
    scale = o.if_else(mag > limit, limit / o.fmax(mag, 1e-12), 1.0)
    return beta_lin * scale, gamma_lin * scale


def understeer_share(d: TwoDofDesign, vm, steer_driver, mu, o=NUMPY):
    """How far the reference band reaches towards 0 on the understeer side, as a share of its smaller yaw rate:
    ``understeer_band`` while the driver's linear demand (the nominal car's steady yaw rate for the driver's
    steer, unlimited) is at most ``understeer_demand`` of the reference's yaw-rate limit
    (:func:`yaw_rate_limit`), falling linearly to 0 at the limit. Below it a car that yaws less than the
    nominal model is the model's error; at the limit (FMVSS 126's sine with dwell on a wet road) the law's
    help to turn the car is what its lateral displacement needs."""
    _, gamma_lin, limit, _ = _reference_parts(d, vm, steer_driver, mu, o)
    return _understeer_share(d, gamma_lin, limit, o)


def _understeer_share(d: TwoDofDesign, gamma_lin, limit, o=NUMPY):
    """:func:`understeer_share` of the linear demand ``gamma_lin`` and the yaw-rate limit ``limit``."""
    demand = o.fabs(gamma_lin) / o.fmax(limit, 1e-12)
    return d.understeer_band * o.fmin(o.fmax((1.0 - demand) / (1.0 - d.understeer_demand), 0.0), 1.0)


def yaw_rate_limit(d: TwoDofDesign, vm, mu, o=NUMPY):
    """The reference's largest yaw rate [rad/s] at speed ``vm``: ``friction_margin mu g`` of lateral acceleration,
    held below :attr:`TwoDofDesign.ay_limit`, over the speed."""
    return o.fmin(d.friction_margin * mu * G, d.ay_limit) / vm


def allocate(d: TwoDofDesign, delta, nz, b11, b21, b22, o=NUMPY, lo=None, hi=None, nz_limit=None):
    """Saturation-aware allocation of ``u = (delta, N_z)``, numpy or casadi.

    When a command exceeds its limit (steer within ``[lo, hi]``, default ``+-steer_max``; yaw moment
    within ``+-nz_max``) it is clipped and the other is chosen to realise the demanded ``B u`` in
    weighted least squares, the yaw-rate row weighted ``yaw_priority`` times the sideslip row (yaw
    stability first). Without saturation the exact inverse is kept.
    """
    w1, w2 = 1.0, d.yaw_priority
    v1, v2 = b11 * delta, b21 * delta + b22 * nz
    lo = -d.steer_max if lo is None else lo
    hi = d.steer_max if hi is None else hi
    nmax = d.nz_max if nz_limit is None else nz_limit
    nz_a = o.fmin(o.fmax(nz, -nmax), nmax)
    delta_a = (w1 * b11 * v1 + w2 * b21 * (v2 - b22 * nz_a)) / (w1 * b11 * b11 + w2 * b21 * b21)
    delta_a = o.fmin(o.fmax(delta_a, lo), hi)
    delta_b = o.fmin(o.fmax(delta, lo), hi)
    nz_b = o.fmin(o.fmax((v2 - b21 * delta_b) / b22, -nmax), nmax)
    nz_sat = o.fabs(nz) > nmax
    d_sat = (delta < lo) + (delta > hi)
    out_delta = o.if_else(nz_sat, delta_a, o.if_else(d_sat > 0.5, delta_b, delta))
    out_nz = o.if_else(nz_sat, nz_a, o.if_else(d_sat > 0.5, nz_b, nz))
    return out_delta, out_nz
