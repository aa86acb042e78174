"""The ECU step: one control period of estimator and controller, numpy or casadi.

This is the part of the stability loop that runs on the vehicle, and the loop
(:func:`toolkit.loop.closed_loop.loop_step`) runs exactly this step: the Kalman-filter step of
:mod:`toolkit.estimation.kalman`, the control law of :mod:`controllers.two_dof`
(both with the speed schedule of :mod:`controllers.schedule`, the firmware's model),
and the split of the yaw-moment command over the rear motors. Its inputs are what
an ECU receives each period (:data:`INPUTS`, SI units, ISO 8855 signs), its state
the filter's and the controller's, its outputs :data:`OUTPUTS`.

Step semantics: each period the filter takes the measurements and the yaw moment applied over the last
period, then the controller takes the new estimates, the driver's steer and the
actuators' limit flags of the last period. Before the step the schedule is read at
``max(speed, filter min_speed)`` for the filter and ``max(speed, controller
min_speed)`` for the controller (:meth:`EcuDesign.schedule_inputs`); the generated
C does the same with its own table lookup.

Calibration scalars (:meth:`EcuDesign.calibration`) are inputs of the traced step,
so the C reads them from named calibration data (``EVSTAB_CALIBRATION``, by default
``static const volatile``) that the A2L describes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from evstab.controllers import supervisor as sup_mod
from evstab.controllers.allocation import AllocationDesign, allocate, brake_yaw_capacity
from evstab.controllers.brakes import WHEELS
from evstab.controllers import two_dof as ctl_mod
from evstab.controllers.schedule import ROWS, SpeedSchedule
from evstab.controllers.two_dof import TwoDofDesign, control_law, reference, yaw_rate_limit
from evstab.plants.backend import CASADI, NUMPY
from evstab.plants import G
from evstab.plants.errors import ModelError
from evstab.plants.model import torque_difference
from evstab.plants.signals import Layout, Signal

from ..kernels.compiled import with_fields
from . import guard as guard_mod
from .guard import GuardSettings
from ..estimation import kalman
from ..estimation.spec import LOOP_METHODS, FilterDesign
from ..estimation.tabulate import build_transition
from ..estimation.transition import Transition

INPUTS = Layout("ECU inputs", [
    Signal("dt", "s", "time since the previous step (the control period)"),
    Signal("speed", "m/s", "vehicle speed from the non-driven wheels"),
    Signal("steer", "rad", "measured front road-wheel angle, + left"),
    Signal("yaw_rate", "rad/s", "gyro yaw rate, + counter-clockwise seen from above"),
    Signal("ay", "m/s^2", "lateral acceleration, + left"),
    Signal("gps_valid", "-", "1 when a new GPS course fix arrived in this period, else 0", ctype="int"),
    Signal("gps_course", "rad", "GPS course over ground, same sense and reference as yaw, wrapped or continuous "
           "(the step wraps its innovation; in float32 give it wrapped: a growing angle loses resolution)"),
    Signal("gps_speed", "m/s", "GPS ground speed (not used by this design; kept for logging)"),
    Signal("gps_hdop", "-", "horizontal dilution of precision of the fix"),
    Signal("gps_sats", "-", "satellites used in the fix (fewer than 4: the fix is not used)", ctype="int"),
    Signal("steer_cmd_driver", "rad", "driver's road-wheel angle command (hand-wheel angle / steering ratio)"),
    Signal("yaw_moment_applied", "N m", "yaw moment the actuators made over the last period, + turns left: the rear "
           "motors' and, where the design shares its moment with the brakes, the brakes' at their pressures"),
    Signal("steer_limited", "-", "optional: 1 when the steer actuator was at a limit in the last period (0 without actuator feedback: the ECU's own limit flags feed the anti-windup)", ctype="int"),
    Signal("yaw_moment_limited", "-", "optional: 1 when the motors were at a torque limit in the last period (0 without actuator feedback: as above)", ctype="int"),
    Signal("mu", "-", "optional: friction from a road sensor, an upper bound on the ECU's own estimate (without a sensor: the design's mu_max, or any larger value)"),
    Signal("wheel_speed_rl", "rad/s", "rear-left wheel speed (without a sensor: speed / wheel radius, which switches slip control off)"),
    Signal("wheel_speed_rr", "rad/s", "rear-right wheel speed (without a sensor: as above)"),
    Signal("wheel_speed_fl", "rad/s", "front-left wheel speed (without a sensor: speed / wheel radius, which switches "
           "the brakes' slip limiter off at that wheel)"),
    Signal("wheel_speed_fr", "rad/s", "front-right wheel speed (without a sensor: as above)"),
    Signal("brake_pressure_driver", "Pa", "the driver's brake pressure (master cylinder; 0 without braking or without "
           "a sensor)"),
])
OUTPUTS = Layout("ECU outputs", [
    Signal("beta", "rad", "estimated sideslip at the CG, + velocity left of x"),
    Signal("yaw_rate", "rad/s", "estimated yaw rate"),
    Signal("yaw", "rad", "estimated yaw angle, wrapped to (-pi, pi]"),
    Signal("d1", "rad/s", "disturbance on the sideslip equation (0 without disturbance states)"),
    Signal("d2", "rad/s^2", "disturbance on the yaw-rate equation (0 without disturbance states)"),
    Signal("gyro_bias", "rad/s", "estimated gyro bias (0 without a bias state)"),
    Signal("beta_std", "rad", "standard deviation of the sideslip estimate"),
    Signal("gps_used", "-", "1 when this period's fix was used"),
    Signal("steer_cmd", "rad", "front road-wheel angle command, + left"),
    Signal("yaw_moment_cmd", "N m", "direct yaw moment command, + turns left"),
    Signal("torque_rl", "N m", "rear-left wheel torque command (the yaw part, added to the driver's)"),
    Signal("torque_rr", "N m", "rear-right wheel torque command (the yaw part, added to the driver's)"),
    Signal("beta_ref", "rad", "sideslip reference"),
    Signal("yaw_rate_ref", "rad/s", "yaw-rate reference"),
    Signal("active", "-", "authority of the stability law, 0 (the driver passed through) to 1"),
    Signal("drive_share", "-", "share of the driver's drive torque let through, 1 (all) to 1 - drive_cut"),
    Signal("mu_est", "-", "friction estimate the reference is limited with"),
    Signal("fault_word", "-", "inputs in fault, one bit each (toolkit.ecu.guard.FAULT_BITS; bit 11: the ECU "
           "state was not finite and restarted this period); 0 when all is well"),
    Signal("bad_samples", "-", "input samples the guard has replaced since start (saturates at 1e7)"),
    Signal("steer_correction", "rad", "the steer a superposition gear adds to the driver's road-wheel angle: "
           "steer_cmd less the driver's angle as the ECU read it (0 while the law is passive)"),
    Signal("beta_telemetry", "rad", "sideslip estimate for logs and telemetry: beta conditioned on zero "
           "disturbances while they are insignificant (telemetry_chi2_on/full); the law reads beta"),
    *(Signal(f"brake_pressure_{w}", "Pa", f"{side} brake pressure command to the hydraulic unit: the driver's plus "
             "the ECU's, slip-limited (the driver's alone without an allocation to the brakes)")
      for w, side in (("fl", "front-left"), ("fr", "front-right"), ("rl", "rear-left"), ("rr", "rear-right"))),
    Signal("yaw_moment_brakes", "N m", "yaw moment the ECU's brake pressures make before the slip limiter, + turns "
           "left (0 without an allocation to the brakes)"),
])
FIRMWARE_METHODS = LOOP_METHODS
TELEMETRY_CHI2 = (0.5, 2.0)
"""The default ends of ``beta_telemetry``'s smoothstep in the disturbances' chi-square (:class:`EcuDesign`): on
the multi-body cars' drives of ``estimation_mb`` the ECU filter's estimate so conditioned is above ``kf-bias`` by
more than 0.005 deg RMS on 4 of 96 log-and-nominal pairs, its own on 41 (docs/estimators.md)."""


@dataclass(frozen=True)
class Calibration:
    """One calibratable scalar: value, unit, limits and where it lives in the design."""

    name: str
    value: float
    unit: str
    lower: float
    upper: float
    description: str
    owner: str
    """``controller``, ``noise`` (the filter's :class:`NoiseSettings`) or ``ecu``."""


_CONTROLLER_CAL = (
    ("k_beta", "rad/s", 0.01, 100.0, "model-following pole for sideslip (seed 003 K_beta)"),
    ("k_gamma", "rad/s", 0.01, 100.0, "model-following pole for yaw rate (seed 003 K_gamma)"),
    ("friction_margin", "-", 0.05, 1.5, "yaw-rate reference limit as a share of mu g / v in a held limit turn"),
    ("turn_in_margin", "-", 0.05, 1.5, "... in the first turn_in_time of a demand beyond the limit"),
    ("turn_in_time", "s", 0.0, 10.0, "time the reference limit stays at turn_in_margin"),
    ("turn_in_fall_time", "s", 0.001, 10.0, "time it then takes to move to friction_margin"),
    ("ay_roll_factor", "-", 0.5, 1.0, "the car's lateral acceleration per accelerometer reading (the body's roll out)"),
    ("yaw_priority", "-", 0.001, 1000.0, "weight of the yaw-rate row against sideslip when a command saturates"),
    ("steer_max", "rad", 0.0, 1.0, "road-wheel angle command limit"),
    ("yaw_moment_max", "N m", 0.0, 1e5, "largest yaw moment command"),
    ("yaw_rate_deadband", "rad/s", 0.0, 1.0, "yaw-rate error that activates the law (at low speed)"),
    ("yaw_rate_deadband_per_speed", "rad/s/(m/s)", 0.0, 0.1, "growth of the yaw-rate dead band with speed"),
    ("deadband_shrink", "-", 0.0, 1.0, "share by which the dead bands shrink at full friction use"),
    ("understeer_band", "-", 0.0, 1.0, "share of the reference band's smaller yaw rate by which it reaches towards 0"),
    ("understeer_demand", "-", 0.0, 0.99, "driver's demand per the reference's yaw-rate limit up to which the understeer band is whole"),
    ("beta_threshold", "rad", 0.0, 1.0, "estimated sideslip that activates the law"),
    ("beta_std_max", "rad", 0.0, 1.0, "sideslip-estimate std above which the sideslip criterion is ignored"),
    ("deactivate_ratio", "-", 0.0, 1.0, "hysteresis: share of the thresholds below which the law may end"),
    ("hold_time", "s", 0.001, 10.0, "time both errors stay below the off thresholds before the law ends"),
    ("release_use", "-", 0.001, 2.0, "friction use at and above which the law does not end"),
    ("blend_time", "s", 0.001, 10.0, "ramp time of the law's authority"),
    ("drive_cut", "-", 0.0, 1.0, "share of the driver's drive torque taken away at the law's full authority"),
    ("steer_authority", "rad", 0.0, 1.0, "largest steer correction added to the driver's road-wheel angle"),
    ("steer_authority_rate", "rad/s", 0.0, 100.0, "largest rate of the steer correction"),
    ("mu_max", "-", 0.05, 2.0, "friction assumed without evidence of less"),
    ("mu_min", "-", 0.01, 2.0, "smallest friction estimate"),
    ("saturation_ratio", "-", 0.0, 1.0, "saturated when |ay| is below this share of the linear demand"),
    ("saturation_ay_min", "m/s^2", 0.0, 20.0, "lateral-acceleration demand below which saturation is not judged"),
    ("demand_tau", "s", 0.001, 10.0, "lag of the linear lateral-acceleration demand"),
    ("rear_grip_share", "-", 0.0, 1.0, "share of the rear tyres' remaining grip the yaw moment may take"),
    ("rollover_share", "-", 0.0, 2.0, "reference lateral acceleration as a share of the quasi-static rollover threshold"),
    ("slip_max", "-", 0.0, 10.0, "rear wheel slip beyond which the yaw moment is cut"),
    ("slip_onset", "-", 0.0, 0.99, "share of slip_max where slip control starts to withdraw the yaw moment"),
    ("slip_lead_time", "s", 0.0, 1.0, "lag of the slip whose difference to the slip is slip control's prediction (how far ahead it looks)"),
    ("slip_cut_time", "s", 0.001, 10.0, "time the yaw-moment authority takes to fall to 0 while a rear wheel slips"),
    ("slip_recover_time", "s", 0.001, 100.0, "time it takes to come back once the slip is below slip_max"),
    ("ay_headroom", "m/s^2", 0.0, 20.0, "lateral acceleration above the measured one the yaw-rate reference may ask for"),
    ("ay_headroom_share", "-", 0.0, 10.0, "... plus this share of the measured one"),
    ("phase_beta", "rad", 0.0, 1e9, "half-width of the sideslip phase-plane region |beta + phase_tau beta'|"),
    ("phase_tau", "s", 0.0, 10.0, "weight of the sideslip rate in the phase-plane region"),
    ("geometric_share", "-", 0.0, 1.0, "share of the geometric sideslip l_r r / v the slide judged leaves out"),
    ("phase_gain_nz", "1/s^2", 0.0, 1e4, "yaw moment per unit phase-plane excess, as yaw acceleration (times I_z)"),
    ("phase_gain_steer", "-", 0.0, 100.0, "steer correction per unit phase-plane excess"),
    ("limit_demand_lo", "-", 0.0, 100.0,
     "driver's linear lateral-acceleration demand per rollover limit from which the reference moves to the lagged static one"),
    ("limit_demand_hi", "-", 0.0, 100.0, "... and at which it is the lagged static one"),
    ("guard_share", "-", 0.0, 10.0, "share of the yaw-rate dead band beyond which no command may oppose the error"),
    ("guard_width", "-", 1e-6, 10.0, "share of the dead band over which an opposing command fades out"),
    ("gust_deadband", "rad/s", 0.0, 1.0,
     "yaw- and course-rate error beyond which the gust channel acts in straight driving"),
    ("gust_gain", "1/s", 0.0, 1e3,
     "gust channel's yaw moment per rad/s of error beyond its band, as yaw acceleration (times I_z)"),
    ("gust_nz_max", "N m", 0.0, 1e5, "largest yaw moment of the gust channel"),
    ("gust_course_share", "-", 0.0, 1.0,
     "share of the kinematic sideslip rate in the gust channel's error (1: course rate)"),
    ("gust_tau", "s", 0.001, 10.0, "low-pass time constant of the gust channel's errors"),
    ("gust_demand", "m/s^2", 0.0, 20.0, "linear demand (and its change) below which the driver goes straight"),
    ("peak_ratio", "-", 0.1, 1.0, "lateral acceleration of a saturated car as a share of mu g"),
    ("mu_tau_down", "s", 0.001, 100.0, "time constant of the friction estimate falling"),
    ("mu_tau_slide", "s", 0.001, 100.0, "time constant of the friction estimate falling while the car slides out"),
    ("slide_rate_fast", "rad/s", 0.0, 10.0, "sideslip rate against the turn from which the fast fall applies"),
    ("slide_demand_steady", "-", 0.0, 10.0, "share of the lagged demand within which the demand now counts as held"),
    ("mu_tau_up", "s", 0.001, 100.0, "time constant of the friction estimate recovering"),
)
_NOISE_CAL = {
    "q_beta": ("rad^2/s", "process-noise intensity on beta'"),
    "q_yaw_rate": ("rad^2/s^3", "process-noise intensity on the yaw rate's derivative"),
    "q_yaw": ("rad^2/s", "process-noise intensity on the yaw angle's derivative"),
    "q_d1": ("rad^2/s^3", "process-noise intensity driving d1"),
    "q_d2": ("rad^2/s^5", "process-noise intensity driving d2"),
    "q_bias": ("rad^2/s^3", "process-noise intensity of the gyro-bias random walk"),
}


@dataclass(frozen=True)
class EcuDesign:
    """What runs on the ECU: a filter and a controller sharing one speed schedule, and the torque split."""

    filter: FilterDesign
    controller: TwoDofDesign
    torque_max: float
    """Per-motor torque limit [N m] of the yaw-moment split."""
    track_rear: float
    """Rear track [m]."""
    wheel_radius: float
    """Wheel radius [m]."""
    guard: GuardSettings = GuardSettings()
    """The input guard's timing (:mod:`toolkit.ecu.guard`)."""
    telemetry_chi2_on: float = TELEMETRY_CHI2[0]
    """``beta_telemetry`` is the estimate conditioned on zero disturbances while their normalised square
    ``d^T P_dd^-1 d`` is below this (:func:`kalman.telemetry_sideslip`) ..."""
    telemetry_chi2_full: float = TELEMETRY_CHI2[1]
    """... and the filter's own estimate from this, a smoothstep between."""
    allocation: AllocationDesign | None = None
    """How the law's yaw moment is shared between the rear motors and the friction brakes
    (:mod:`controllers.allocation`); None: the motors alone, the driver's brake pressure passed through (the
    ``motors`` mode of an allocation, to the bit)."""

    def __post_init__(self):
        if self.filter.method not in FIRMWARE_METHODS:
            raise ModelError(f"firmware export supports the Kalman-filter methods ({', '.join(FIRMWARE_METHODS)}), "
                             f"not '{self.filter.method}'")
        if not isinstance(self.controller.schedule, SpeedSchedule) or self.filter.schedule != self.controller.schedule:
            raise ModelError("the ECU's filter and controller must carry the same speed schedule")
        # the filter propagates with its model discretised on the schedule's grid for the control period
        tr = build_transition(self.filter, self.filter.schedule, self.filter.dt_nominal)
        if self.filter.transition != tr:
            object.__setattr__(self, "filter", dataclasses.replace(self.filter, transition=tr))
        if not 0.0 <= self.telemetry_chi2_on < self.telemetry_chi2_full:
            raise ModelError(f"ECU setting 'telemetry_chi2_full' ({self.telemetry_chi2_full!r}) must be above "
                             f"'telemetry_chi2_on' ({self.telemetry_chi2_on!r}), which must be at least 0")
        if not np.isfinite(self.controller.nz_max):
            raise ModelError("the controller's yaw_moment_max is not finite: give the vehicle max_motor_torque, "
                             "track_rear and wheel_radius (or set yaw_moment_max)")

    @property
    def brakes(self) -> bool:
        """Whether the law's yaw moment is shared with the friction brakes (an allocation not in ``motors`` mode)."""
        return self.allocation is not None and self.allocation.mode != "motors"

    @classmethod
    def from_designs(cls, filt: FilterDesign, ctl: TwoDofDesign, schedule: SpeedSchedule | None = None) -> "EcuDesign":
        """Attach ``schedule`` (default: built from the controller's nominal parameters) to both designs."""
        p = ctl.params
        for name in ("track_rear", "wheel_radius", "max_motor_torque"):
            p.require(name, model="firmware export")
        sched = schedule or SpeedSchedule.build(p)
        ctl = dataclasses.replace(ctl, schedule=sched, yaw_moment_max=float(ctl.nz_max))
        filt = dataclasses.replace(filt, schedule=sched)
        return cls(filt, ctl, float(p.max_motor_torque), float(p.track_rear), float(p.wheel_radius))

    @property
    def schedule(self) -> SpeedSchedule:
        s = self.controller.schedule
        if s is None:
            raise ModelError("an ECU design's controller reads its model from a speed schedule; this one has none")
        return s

    @property
    def layout(self) -> Layout:
        """The flat ECU state: the filter's parts (see :func:`kalman.layout`), then the control law's
        (:data:`controllers.two_dof.STATE`), the supervisor's (:data:`controllers.supervisor.STATE`) and the
        input guard's (:data:`toolkit.ecu.guard.STATE`)."""
        return state_layout(self.filter)

    @property
    def n_state(self) -> int:
        return self.layout.size

    def initial_state(self) -> np.ndarray:
        """What ``evstab_init`` sets: heading 0 and yaw rate 0 (the first usable fix sets the heading)."""
        return np.concatenate([kalman.initial_state(self.filter, 0.0, 0.0), control_start(self),
                               guard_mod.initial_state()])

    @property
    def min_speeds(self) -> tuple[float, float]:
        """Speeds [m/s] below which the filter and the controller read the schedule at that speed."""
        return float(self.filter.noise.min_speed), float(self.controller.min_speed)

    @property
    def transition(self) -> Transition:
        """The filter's transition table (:mod:`toolkit.estimation.transition`)."""
        t = self.filter.transition
        if t is None:
            raise ModelError("an ECU design's filter propagates with a tabulated transition; this one has none")
        return t

    @property
    def n_schedule_inputs(self) -> tuple[int, int]:
        """How many table rows the step reads: the filter's transition rows, the controller's schedule rows."""
        return len(self.transition.names), len(ROWS)

    def schedule_inputs(self, speed) -> np.ndarray:
        """The tables' rows at ``speed`` (scalar or array): the filter's transition rows at the filter's
        speed, then the schedule's rows (:data:`ROWS`) at the controller's: (..., sum of
        :attr:`n_schedule_inputs`)."""
        v = np.asarray(speed, float)
        e, c = self.min_speeds
        se = self.transition.table.values(np.fmax(v, e))
        sc = self.schedule.values(np.fmax(v, c))
        return np.stack(list(se) + list(sc), axis=-1)

    def calibration(self) -> tuple[Calibration, ...]:
        """The calibratable scalars of this design (the tables are :attr:`schedule`)."""
        c, nz, f = self.controller, self.filter.noise, self.filter
        out = [Calibration(k, float(getattr(c, k)), u, lo, hi, desc, "controller") for k, u, lo, hi, desc in
               _CONTROLLER_CAL]
        out.append(Calibration("torque_max", self.torque_max, "N m", 0.0, 1e4,
                               "per-motor torque limit of the yaw-moment split", "ecu"))
        for s in f.states:
            key = "q_" + s if s != "gyro_bias" else "q_bias"
            unit, desc = _NOISE_CAL[key]
            out.append(Calibration(key, float(getattr(nz, key)), unit, 0.0, 1e6, desc, "noise"))
        out.append(Calibration("gyro_std", nz.gyro_std, "rad/s", 1e-6, 1.0, "gyro noise standard deviation per sample",
                               "noise"))
        if f.hdop_noise:
            out.append(Calibration("gps_velocity_std", nz.gps_velocity_std, "m/s", 1e-4, 10.0,
                                   "GPS velocity noise per axis at HDOP 1 (course noise = this * HDOP / speed)",
                                   "noise"))
            out.append(Calibration("course_std_min", nz.course_std_min, "rad", 1e-6, 1.0,
                                   "smallest course standard deviation", "noise"))
        else:
            out.append(Calibration("course_std", nz.course_std, "rad", 1e-6, 1.0, "course standard deviation",
                                   "noise"))
        if f.gating:
            out.append(Calibration("gate", nz.gate, "-", 1.0, 1e4,
                                   "chi-square gate on the course innovation (normalised squared innovation)",
                                   "noise"))
        out.append(Calibration("telemetry_chi2_on", self.telemetry_chi2_on, "-", 0.0, 100.0,
                               "disturbances' chi-square below which beta_telemetry is conditioned on zero "
                               "disturbances", "ecu"))
        out.append(Calibration("telemetry_chi2_full", self.telemetry_chi2_full, "-", 0.01, 1000.0,
                               "... and from which it is the filter's own estimate (above telemetry_chi2_on)",
                               "ecu"))
        return tuple(out)

    def bind(self, values) -> "EcuDesign":
        """A copy whose calibration scalars are ``values`` (numbers or casadi symbols, in
        :meth:`calibration` order). Validation is skipped: symbols cannot be checked."""
        cal = self.calibration()
        if len(values) != len(cal):
            raise ModelError(f"expected {len(cal)} calibration values, got {len(values)}")
        by: dict[str, dict] = {"controller": {}, "noise": {}, "ecu": {}}
        for c, v in zip(cal, values):
            by[c.owner][c.name] = v
        noise = with_fields(self.filter.noise, **by["noise"])
        return with_fields(self, filter=with_fields(self.filter, noise=noise), controller=with_fields(self.controller, **by["controller"]),
                     **by["ecu"])


class _Rows:
    """A schedule already read at this step's speed: the rows come in as values (or symbols)."""

    def __init__(self, rows):
        self.rows = tuple(rows)

    def values(self, v, o=NUMPY):
        return self.rows


def with_schedule_rows(d: EcuDesign, sched) -> EcuDesign:
    """``d`` with its tables replaced by rows already read at this step's speeds (``sched``: the values of
    :meth:`EcuDesign.schedule_inputs`, numbers or symbols); None keeps the tables."""
    if sched is None:
        return d
    nf, nc = d.n_schedule_inputs
    tr = with_fields(d.transition, table=_Rows(sched[i] for i in range(nf)))
    return with_fields(d, filter=with_fields(d.filter, transition=tr),
                       controller=with_fields(d.controller, schedule=_Rows(sched[nf + i] for i in range(nc))))


def state_layout(f: FilterDesign) -> Layout:
    """The ECU state of a design with filter ``f`` (see :attr:`EcuDesign.layout`)."""
    return _state_layout(kalman.layout(f).signals)


@lru_cache(maxsize=64)
def _state_layout(filter_signals: tuple) -> Layout:
    return Layout("ECU state", [*filter_signals, *CONTROL_STATE.signals,
                                Signal("guard", "-", "the input guard's state", guard_mod.STATE.size)])


def before_guard(lay: Layout) -> slice:
    """The filter's and the controller's part of the ECU state ``lay``: everything before the input guard's."""
    return slice(0, lay.index("guard"))


def filter_part(lay: Layout) -> slice:
    """The filter's part of the ECU state ``lay`` (:func:`state_layout`): everything before the controller's."""
    return slice(0, lay.index("controller"))


def ecu_estimate(d: EcuDesign, z_est, u, o=NUMPY, with_course: bool = True, moving: bool = False):
    """The filter part of the step: ``(z_est, u) -> (z_est_next, estimates)``, estimates a dict of
    ``beta, yaw_rate, yaw, d1, d2, gyro_bias, beta_std, gps_used`` (0 for states the filter lacks) and
    ``beta_telemetry`` (:func:`kalman.telemetry_sideslip`)."""
    g = INPUTS.as_dict(u)
    valid = g["gps_valid"]
    u_est = kalman.INPUTS.pack(o=o, dt=g["dt"], speed=g["speed"], steer=g["steer"], yaw_moment=g["yaw_moment_applied"],
                               yaw_rate=g["yaw_rate"], fix=valid, course=valid * g["gps_course"], hdop=g["gps_hdop"],
                               sats=g["gps_sats"], ay=g["ay"])
    z_est_n, y = kalman.step(d.filter, z_est, u_est, o, with_course=with_course, moving=moving)
    est = kalman.OUTPUTS.as_dict(y)
    est["beta_telemetry"] = kalman.telemetry_sideslip(d.filter, z_est_n, d.telemetry_chi2_on,
                                                      d.telemetry_chi2_full, o)
    zero = 0.0 * g["speed"]
    for name, present in (("d1", "d1" in d.filter.states), ("d2", "d2" in d.filter.states),
                          ("gyro_bias", d.filter.bias)):
        if not present:
            est[name] = zero
    return z_est_n, est


FRESH_LAG = 1e3
"""[s] The step a fresh start gives the supervisor's lagged states (friction estimate, demand, slip authority;
:func:`ecu_control`)."""


def ecu_control(d: EcuDesign, z_ctl, u, est: dict, o=NUMPY, fresh=0.0):
    """The controller part of the step: ``(z_ctl, u, estimates) -> (z_ctl_next, y)``, ``y`` per
    :data:`OUTPUTS` (the estimates are passed through to it). ``z_ctl`` is the law's state
    (:data:`controllers.two_dof.STATE`) then the supervisor's (:data:`controllers.supervisor.STATE`):
    friction estimate, activation, authority (see :mod:`controllers.supervisor`).

    ``fresh`` 1 on the period the law (re)starts (:func:`restart`; the first period after ``evstab_init``):
    its lagged references, the supervisor's lagged demand, its friction estimate, the slip control's
    authority and the reference margin's turn timer start at their targets for that period's driver steer, speed, lateral acceleration and wheel
    speeds, so that a start at speed in a turn is read neither as a yaw-rate error of the whole turn, nor as
    a road of ``mu_max``, nor as rear wheels that do not slip."""
    g = INPUTS.as_dict(u)
    c = d.controller
    parts = CONTROL_STATE.unpack(z_ctl)
    z_law, z_sup = parts.controller, parts.supervisor
    sup_st = sup_mod.STATE.unpack(z_sup)
    vm = o.fmax(g["speed"], c.min_speed)
    # the car's lateral acceleration: the accelerometer reads the body's roll too (a_y + g phi in a turn)
    ay_car = g["ay"] * c.ay_roll_factor
    _, gamma_lin, _ = reference(c, vm, g["steer_cmd_driver"], g["mu"], o, limited=False)  # the linear demand
    # on a fresh start the supervisor's lagged states go to their targets at once (a step of FRESH_LAG s, far
    # beyond their time constants): the friction the car is using now, not mu_max
    lag_dt = o.if_else(fresh > 0.5, FRESH_LAG, g["dt"])
    mu_est, use, demand = sup_mod.friction_estimate(c, sup_st.mu_est, sup_st.ay_demand, g["speed"], ay_car,
                                                    est["yaw_rate"], gamma_lin, lag_dt, o, sup_st.oversteer)
    mu_ref = o.fmin(mu_est, g["mu"])
    # the reference's margin: turn_in_margin at a turn-in beyond the limit, friction_margin once it is held; the
    # law limits its reference with friction_margin, so it is passed the friction that makes the two agree
    beyond = o.if_else(o.fabs(gamma_lin) > yaw_rate_limit(c, vm, mu_ref, o), 1.0, 0.0)
    margin, limit_time = sup_mod.reference_margin(c, sup_st.limit_time, beyond, g["dt"], fresh, o)
    mu_ref = mu_ref * margin / c.friction_margin
    # the yaw rate the car's lateral acceleration can carry: a reference beyond |a_y| / v plus a
    # headroom asks for a growing slide (r > a_y / v means beta' < 0 in a left turn)
    mu_ref = o.fmin(mu_ref, (o.fabs(ay_car) * (1.0 + c.ay_headroom_share) + c.ay_headroom) / (c.friction_margin * G))
    law0 = ctl_mod.STATE.as_dict(z_law)
    beta_ss, gamma_ss, _ = reference(c, vm, g["steer_cmd_driver"], mu_ref, o)  # the law's own targets
    law0["beta_ref"] = o.if_else(fresh > 0.5, beta_ss, law0["beta_ref"])
    law0["yaw_rate_ref"] = o.if_else(fresh > 0.5, gamma_ss, law0["yaw_rate_ref"])
    law0["beta_linear"] = o.if_else(fresh > 0.5, beta_ss, law0["beta_linear"])
    law0["yaw_rate_linear"] = o.if_else(fresh > 0.5, gamma_ss, law0["yaw_rate_linear"])
    z_law = ctl_mod.STATE.pack(law0, o)
    law_st = ctl_mod.STATE.unpack(z_law)
    steer_flag = o.fmax(g["steer_limited"], sup_st.steer_saturated)
    nz_flag = o.fmax(g["yaw_moment_limited"], sup_st.yaw_moment_saturated)
    sig = ctl_mod.SIGNALS.pack(o=o, speed=g["speed"], steer_driver=g["steer_cmd_driver"], beta=est["beta"],
                               yaw_rate=est["yaw_rate"], d1=est["d1"], d2=est["d2"], mu=mu_ref, steer_limited=steer_flag,
                               yaw_moment_limited=nz_flag, limit_share=limit_share(c, g["speed"] * gamma_lin, o))
    nz_limit = sup_mod.yaw_moment_limit(c, mu_est, use, o)
    alloc = d.allocation
    if d.brakes and alloc is not None:
        # the brakes' share at the estimated friction, besides the motors' in a blend (controllers.allocation)
        brakes_limit = brake_yaw_capacity(alloc, mu_est)
        nz_limit = o.fmin(brakes_limit if alloc.mode == "brakes" else nz_limit + brakes_limit, c.nz_max)
    z_law_n, law_y = control_law(c, z_law, sig, o, nz_limit)
    law = ctl_mod.OUTPUTS.unpack(law_y)
    # the sideslip rate from the sensors, a_y / v - r (kinematics: it needs no tyre model)
    beta_rate = ay_car / vm - est["yaw_rate"]
    beta_slide = sup_mod.slide(c, est["beta"], est["yaw_rate"], vm, o)  # the sideslip less a turn's geometry
    sup_n, steer_cmd, nz_cmd, law_on = sup_mod.supervise(
        c, z_sup, g["speed"], law.yaw_rate_error, beta_slide, est["beta_std"], use,
        g["steer_cmd_driver"], law.steer, law.yaw_moment, nz_limit, g["dt"], o, beta_rate=beta_rate)
    # the slip control's authority goes to its target at once on a fresh start too (its growth term, with no
    # lag yet, reads the whole slip as growth: the cautious side)
    k_slip, slip_lag = sup_mod.slip_authority(c, sup_st.slip_authority, sup_st.slip_lag, g["speed"],
                                              g["wheel_speed_rl"], g["wheel_speed_rr"], d.wheel_radius,
                                              lag_dt, o)
    # the gust channel, while the driver goes straight, as the law's authority blends out
    straight = sup_mod.straight_share(c, g["speed"] * gamma_lin, demand, o)
    nz_gust, (gust_yaw_error, gust_rate) = sup_mod.gust_moment(
        c, (sup_st.gust_yaw_error, sup_st.gust_rate), law_st.yaw_rate_ref, est["yaw_rate"], beta_rate, straight,
        g["speed"], nz_limit, lag_dt, o)
    nz_cmd = nz_cmd + (1.0 - sup_n["blend"]) * nz_gust
    p_driver = o.fmax(g["brake_pressure_driver"], 0.0)
    if not d.brakes:
        pressures, nz_brakes = (p_driver,) * 4, 0.0 * mu_est
    else:
        # the brakes' share of the moment (controllers.allocation), each wheel within its grip at the estimated
        # friction and lateral acceleration, slip-limited; the motors' share below, slip-controlled as before
        omegas = tuple(g[f"wheel_speed_{w}"] for w in WHEELS)
        nz_cmd, pressures, nz_brakes = allocate(d.allocation, nz_cmd, est["yaw_rate"], g["speed"], ay_car, mu_est,
                                                omegas, p_driver, o)
    nz_cmd = nz_cmd * k_slip
    sup_n.update(mu_est=mu_est, ay_demand=demand, slip_authority=k_slip, slip_lag=slip_lag,
                 gust_yaw_error=gust_yaw_error, gust_rate=gust_rate, limit_time=limit_time)
    # the law's integrators run only while it has authority
    law_n = ctl_mod.STATE.as_dict(z_law_n)
    law_n["xi_beta"], law_n["xi_yaw_rate"] = law_n["xi_beta"] * law_on, law_n["xi_yaw_rate"] * law_on
    # the drive torque the rear motors may take from the rear tyres while the law acts against oversteer
    drive_share, sup_n["oversteer"] = sup_mod.drive_cut(c, sup_st.oversteer, sup_n["blend"], law.yaw_rate_error,
                                                         est["yaw_rate"], beta_slide, beta_rate, est["beta_std"], o)
    t_rl, t_rr = rear_torques(d, nz_cmd, o)
    out = OUTPUTS.pack(o=o, **{k: est[k] for k in ("beta", "yaw_rate", "yaw", "d1", "d2", "gyro_bias", "beta_std",
                                                   "gps_used", "beta_telemetry")},
                       steer_cmd=steer_cmd, yaw_moment_cmd=nz_cmd, torque_rl=t_rl, torque_rr=t_rr,
                       beta_ref=law.beta_ref, yaw_rate_ref=law.yaw_rate_ref, active=sup_n["blend"],
                       drive_share=drive_share, mu_est=mu_est,
                       fault_word=0.0 * mu_est, bad_samples=0.0 * mu_est, steer_correction=0.0 * mu_est,
                       **{f"brake_pressure_{w}": pr for w, pr in zip(WHEELS, pressures)},
                       yaw_moment_brakes=nz_brakes)
    z_next = CONTROL_STATE.pack(o=o, controller=ctl_mod.STATE.pack(law_n, o), supervisor=sup_mod.STATE.pack(sup_n, o))
    return z_next, out


def commanded_moment(d: EcuDesign, ys: dict):
    """The yaw moment the ECU's outputs ``ys`` ask of the actuators: the motors' and, with an allocation to the
    brakes, the brakes'."""
    return ys["yaw_moment_cmd"] + ys["yaw_moment_brakes"] if d.brakes else ys["yaw_moment_cmd"]


def limit_share(c: TwoDofDesign, demand, o=NUMPY):
    """The law's ``limit_share`` (:mod:`controllers.two_dof`): 0 while the driver's linear lateral-acceleration
    demand ``demand`` [m/s^2] is below ``limit_demand_lo`` times the rollover limit, 1 from ``limit_demand_hi``
    times it, linear between."""
    q = o.fabs(demand) / c.ay_limit
    return o.fmin(o.fmax((q - c.limit_demand_lo) / o.fmax(c.limit_demand_hi - c.limit_demand_lo, 1e-9), 0.0), 1.0)


CONTROL_STATE = Layout("ECU control state", [
    Signal("controller", "-", "the control law's state (controllers.two_dof.STATE)", ctl_mod.STATE.size),
    Signal("supervisor", "-", "the supervisor's state (controllers.supervisor.STATE)", sup_mod.STATE.size)])
"""The controller part of the ECU state: the law's, then the supervisor's."""


def rear_torques(d: EcuDesign, yaw_moment, o=NUMPY):
    """``(T_rl, T_rr)`` [N m]: the yaw part of the rear wheel torques for ``yaw_moment``, the torque
    difference (:func:`plants.model.torque_difference`) limited to ``torque_max``."""
    diff = o.fmin(o.fmax(torque_difference(yaw_moment, d.wheel_radius, d.track_rear), -d.torque_max), d.torque_max)
    return -diff, diff


def ecu_guard(d: EcuDesign, z, u, o=NUMPY, cal=None):
    """The input guard (:mod:`toolkit.ecu.guard`): ``(z, u) -> (guard part of z_next, clean u)``. ``cal``: the
    calibration values the step runs with (numbers or symbols; default the design's), checked against the
    limits :meth:`EcuDesign.calibration` declares."""
    lim = d.calibration()
    values = [c.value for c in lim] if cal is None else cal
    sup = z[d.layout.slot("supervisor")]
    zg_n, clean = guard_mod.guard(d.guard, z[d.layout.slot("guard")], INPUTS.as_dict(u), d.filter.dt_nominal,
                                  d.wheel_radius, o, [(v, c.lower, c.upper) for v, c in zip(values, lim)],
                                  d.track_rear, sup[sup_mod.STATE.index("blend")])
    return zg_n, INPUTS.pack(clean, o)


def _total(v, o):
    """The sum of a column, added pairwise (a chain of depth log2 n, not n: it is on every step's path)."""
    items = [v[i] for i in range(v.shape[0])] if o is CASADI else list(np.ravel(v))
    return guard_mod.tree(items, lambda a, b: a + b)


def restart(z_est, z_ctl, zg, start_est, start_ctl, o=NUMPY):
    """The filter's and the controller's state as the step takes them: their initial state (``start_est``,
    ``start_ctl``) on the period the guard restarts them, or where either is not finite (a NaN or an infinity
    anywhere makes the sum non-finite); returns ``(z_est, z_ctl, 1 where the state was not finite)``."""
    broken = 1.0 - (o.fabs(_total(z_est, o) + _total(z_ctl, o)) < 1e30)
    reset = o.fmax(guard_mod.STATE.unpack(zg).restart, broken) > 0.5
    return o.if_else(reset, start_est, z_est), o.if_else(reset, start_ctl, z_ctl), broken


def with_authority(y, u, zg, broken, o=NUMPY):
    """The outputs ``y`` with the guard's authority ``k`` applied (the steer command ``k`` of the law's
    and ``1 - k`` of the driver's, the steer correction, the yaw moment and the wheel torques ``k`` times the
    law's: exact at ``k = 1``; the steer correction is the law's steer less the driver's angle the ECU read,
    set here for every ECU kind) and its fault word and count."""
    gs = guard_mod.STATE.unpack(zg)
    k = gs.authority
    ys = OUTPUTS.as_dict(y)
    g = INPUTS.as_dict(u)
    driver = g["steer_cmd_driver"]
    ys["steer_correction"] = (ys["steer_cmd"] - driver) * k
    ys["steer_cmd"] = ys["steer_cmd"] * k + driver * (1.0 - k)
    for name in ("yaw_moment_cmd", "torque_rl", "torque_rr", "active", "yaw_moment_brakes"):
        ys[name] = ys[name] * k
    # the brakes: the ECU's pressures, or the driver's as the authority ramps out
    p_driver = o.fmax(g["brake_pressure_driver"], 0.0)
    for w in WHEELS:
        ys[f"brake_pressure_{w}"] = ys[f"brake_pressure_{w}"] * k + p_driver * (1.0 - k)
    ys["drive_share"] = 1.0 - (1.0 - ys["drive_share"]) * k
    ys["fault_word"] = gs.fault_word + broken * float(2 ** guard_mod.FAULT_BITS["state"])
    ys["bad_samples"] = gs.bad_samples
    return OUTPUTS.pack(ys, o)


def ecu_step(d: EcuDesign, z, u, sched=None, o=NUMPY, with_course: bool = True, moving: bool = False):
    """``(z, u) -> (z_next, y)``, ``u`` per :data:`INPUTS`, ``y`` per :data:`OUTPUTS`: the input guard
    (:func:`ecu_guard`), then :func:`ecu_core` on the inputs it passes.

    ``sched``: the values of :meth:`EcuDesign.schedule_inputs` at the guarded speed (numbers or symbols;
    callers that read the tables outside the step run :func:`ecu_guard` and :func:`ecu_core` in turn, as
    the exported C does); None reads the tables here. ``with_course=False`` leaves out the course update
    (exact on a step whose guarded ``gps_valid`` is 0), ``moving=True`` the standstill update (exact at a
    guarded speed of at least the filter's ``standstill_speed``; see :func:`kalman.step`).
    """
    lay = d.layout
    zg_n, u_c = ecu_guard(d, z, u, o)
    z = o.concat([z[before_guard(lay)], zg_n])
    return ecu_core(d, z, u_c, sched, o, with_course, moving)


def control_start(d: EcuDesign, o=NUMPY):
    """The controller's part of the initial state (:data:`CONTROL_STATE`) of ``d``, which may carry calibration
    symbols (the supervisor starts from ``mu_max``): what a restart sets."""
    law = ctl_mod.STATE.zeros()
    if o is NUMPY:
        return CONTROL_STATE.pack(controller=law, supervisor=np.asarray(sup_mod.initial_state(d.controller)))
    import casadi as ca
    return ca.vertcat(ca.DM(law), sup_mod.initial_state(d.controller, o))


def ecu_core(d: EcuDesign, z, u, sched=None, o=NUMPY, with_course: bool = True, moving: bool = False):
    """The step after the guard: ``(z, clean u) -> (z_next, y)``; ``z``'s guard part is the guard's new state,
    which it passes through."""
    d = with_schedule_rows(d, sched)
    lay = d.layout
    ctl = lay.span("controller", "supervisor")
    zg = z[lay.slot("guard")]
    z_est, z_ctl, broken = restart(z[filter_part(lay)], z[ctl], zg,
                                   kalman.initial_state(d.filter, 0.0, 0.0), control_start(d, o), o)
    z_est_n, est = ecu_estimate(d, z_est, u, o, with_course, moving)
    z_ctl_n, out = ecu_control(d, z_ctl, u, est, o, guard_mod.STATE.unpack(zg).restart)
    y = with_authority(out, u, zg, broken, o)
    # the guard compares the next period's applied yaw moment with this period's command (the motors' and the
    # brakes')
    ys = OUTPUTS.as_dict(y)
    zg = guard_mod.with_command(zg, commanded_moment(d, ys), o)
    return o.concat([z_est_n, z_ctl_n, zg]), y


def traced_guard(d: EcuDesign):
    """casadi SX function ``ecu_guard``: ``(z, u, cal) -> (z_next, u_clean)``, the input guard (:func:`ecu_guard`,
    the calibration values as inputs); of ``z_next`` only the guard's part differs from ``z``."""
    import casadi as ca
    lay = d.layout
    z, u = ca.SX.sym("z", d.n_state), ca.SX.sym("u", INPUTS.size)
    cal = ca.SX.sym("cal", len(d.calibration()))
    zg_n, u_c = ecu_guard(d, z, u, CASADI, [cal[i] for i in range(cal.shape[0])])
    zn = ca.vertcat(z[before_guard(lay)], zg_n)
    return ca.Function("ecu_guard", [z, u, cal], [zn, u_c], ["z", "u", "cal"], ["z_next", "u_clean"])


def traced_steps(d: EcuDesign, moving: bool = False):
    """casadi SX functions ``(z, u, sched, cal) -> (z_next, y)`` of :func:`ecu_core` (the step after the input
    guard, ``u`` the inputs it passed) without and with the course update; with ``moving`` a third, without
    the course and the standstill update (``ecu_nofix_moving``: the step of a period without a fix at a
    speed of at least the filter's ``standstill_speed``)."""
    import casadi as ca
    out = []
    variants = [("ecu_nofix", False, False), ("ecu_fix", True, False)]
    if moving:
        variants.append(("ecu_nofix_moving", False, True))
    for name, with_course, mv in variants:
        z, u = ca.SX.sym("z", d.n_state), ca.SX.sym("u", INPUTS.size)
        s, cal = ca.SX.sym("sched", sum(d.n_schedule_inputs)), ca.SX.sym("cal", len(d.calibration()))
        bound = d.bind([cal[i] for i in range(cal.shape[0])])
        zn, y = ecu_core(bound, z, u, [s[i] for i in range(s.shape[0])], CASADI, with_course=with_course, moving=mv)
        out.append(ca.Function(name, [z, u, s, cal], [zn, y], ["z", "u", "sched", "cal"], ["z_next", "y"]))
    return tuple(out)
