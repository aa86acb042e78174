"""The ECU's input guard: every input checked before the step uses it.

Each period, before the filter and the law see anything, :func:`guard` checks the inputs of
:data:`toolkit.ecu.step.INPUTS`:

* ``dt``: used only if ``0 < dt <= dt_max`` and within ``dt_band`` of the nominal period (half of it either
  side by default); otherwise the nominal period (a clock that jumps back, stalls or runs at another rate must
  not scale the filter's and the law's integration);
* each physical signal (:data:`CHECKS`) against its physical range (a NaN or an infinity fails the
  range, whatever the compiler's comparison of it) and, while it is not in fault, against a
  plausible change since its last good value: ``|x - last| <= rate * dt + step`` (the yaw rate: ``rate *
  (dt + held)``, ``held`` the time it has read one value, so a CAN signal moves on in one step after its
  message interval). A sample that fails is replaced by the signal's last good value and counted
  (``bad_samples``);
* the yaw rate against the lateral acceleration: one that has read the same value for ``stuck_time`` while
  ``|a_y - v r|`` exceeds ``consistency_ay + consistency_rate v`` (above ``consistency_speed``) is stuck: it
  fails its check and reads as ``a_y / v`` (a stuck sensor passes every range and rate test, and the law would
  chase the yaw rate it no longer reports);
* the yaw rate against the rear wheels and the lateral acceleration, two out of three (``vote_rate``; None: no
  vote), while the car goes nearly straight and the law and the motors have been quiet for ``vote_settle``:
  one that differs from the wheels' ``(w_rr - w_rl) R / t_r`` by more than ``vote_rate`` and from ``a_y / v`` by
  more than the consistency band, while ``a_y / v`` is nearer the wheels than half that difference, is offset:
  it fails its check and reads as ``a_y / v`` (an offset gyro moves like a live one and passes the rate test).
  The wheels and ``a_y / v`` are low-passed (``vote_tau``: a sample of wheel-speed noise must not outvote a live
  gyro), the gyro is not (the offset is outvoted on its first sample, before the law starts on the yaw error it
  makes). The vote rests while the law acts or the motors make a yaw moment: their torque difference makes the
  rear wheels slip apart;
* the driver's angle against the road wheels': with the law passive for ``steer_settle`` (a superposition gear
  then adds nothing), ``steer_cmd_driver`` and ``steer`` more than ``steer_agree`` plus ``steer_agree_share`` of
  the angle apart are both replaced by their last good values (an offset on either moves plausibly; which one
  is wrong, nothing tells, so both are named);
* a speed sample that fails reads as the rear wheels' mean speed times the wheel radius where both wheel
  speeds are in range (the motors' yaw-moment torque speeds one wheel as much as it slows the other), else
  as the last good value; a speed in fault then takes the law's authority only while the wheels cannot
  stand in for it (it is named in the fault word all the same);
* a course fix whose course, HDOP or satellite count is not finite, or whose HDOP is not positive,
  is dropped (``gps_valid`` 0), and so is a stuck one: a course equal to the bit to the last fix whose course
  changed while the gyro says the car has turned by more than ``course_stuck_turn`` since (a receiver's or a
  gateway's repeated message: each fix is plausible by itself, and the filter would pull the heading back),
  and so is one whose course has moved from the last good fix's by more than the lateral acceleration turned
  the car's velocity since (``integral of a_y / v``, the course's rate) plus ``course_jump`` (a receiver's jump
  or offset; within ``course_jump_window`` of that fix, above ``consistency_speed``; in a GPS fault each fix is
  compared with the one before, so that a course that has moved on for good is taken back);
* the applied yaw moment against the ECU's own command: with the command within ``moment_quiet`` for
  ``vote_settle`` (the motors' lag decayed), more than ``vote_yaw_moment`` applied is a moment the ECU did not
  ask for (an offset the filter would take for the motors'): it fails its check and reads as its last good value
  (the step keeps its command in the guard's state for the next period, :func:`with_command`);
* ``mu`` out of range reads as no sensor (:data:`MU_NO_SENSOR`); a wheel speed out of range as no sensor
  (``speed / wheel radius``: slip control off at a rear wheel, the brakes' slip limiter at any); the driver's brake
  pressure out of range as its last good value (named, not degrading: the brakes pass it on).

A signal that fails for ``latch_time`` in a row is in fault (the GPS: :data:`GPS_LATCH_FIXES` bad fixes in a
row, recovering after :data:`GPS_RECOVER_FIXES` good ones): its bit in ``fault_word``
(:data:`FAULT_BITS`) is set, and while it lasts the signal is read for range only (a value that
has moved on for good is taken back once it is in range; the yaw rate also for being stuck). It recovers after ``recover_time`` of
good samples in a row (hysteresis). While a signal the law depends on (:data:`DEGRADING`) is in
fault, the law's authority ``k`` ramps to 0 over ``ramp_time`` (steer command to the driver's,
yaw moment to 0); at the recovery the filter and the law restart from their initial state (a restart at
speed: the next course fix sets the heading), and ``restart_hold`` later the authority ramps back to 1
over ``ramp_time``. On clean inputs nothing of this changes a value: ``k`` is exactly 1,
every signal passes as it came.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants.backend import NUMPY
from evstab.plants.errors import ModelError
from evstab.plants.signals import Layout, Signal


@dataclass(frozen=True)
class Check:
    """The plausibility of one physical input: range ``[lower, upper]`` and a change per period of at most
    ``rate * dt + step`` from its last good value (``rate`` None: no rate check)."""

    name: str
    lower: float
    upper: float
    rate: float | None
    step: float
    bit: int
    degrading: bool


CHECKS = (
    # 120 m/s and 50 m/s^2 (5 g): no car's wheel-speed signal moves more than that
    Check("speed", -20.0, 120.0, 50.0, 1.0, 1, True),
    # road-wheel angle: 1 rad is beyond any steering rack's travel; 5 rad/s is ~4,300 deg/s at the hand
    # wheel (ratio 15), three times what a driver or an EPS motor achieves
    Check("steer", -1.0, 1.0, 5.0, 0.01, 2, True),
    # a +-300 deg/s yaw-rate sensor; 30 rad/s^2 of yaw acceleration is beyond a spinning car's (~10), and
    # the step allows a CAN signal's quantisation (1.28 deg/s) and gyro noise
    Check("yaw_rate", -5.3, 5.3, 30.0, 0.1, 3, True),
    # +-5 g; a vibrating body's accelerometer moves 4 m/s^2 per sample (5.7 m/s^2 between two): 20 m/s^2 from
    # the last good value is 3.5 of those, and 500 m/s^3 of jerk more than a car's (a kerb strike's ~100)
    Check("ay", -50.0, 50.0, 500.0, 20.0, 4, True),
    Check("steer_cmd_driver", -1.0, 1.0, 5.0, 0.01, 6, True),
    # the motors' torque difference can step from one period to the next
    Check("yaw_moment_applied", -1e5, 1e5, None, 0.0, 7, True),
    # -10 to 300 bar (a sensor's zero shift reads a little below 0; no car's master cylinder reaches 300 bar); the
    # driver brakes in one step
    Check("brake_pressure_driver", -1e6, 3e7, None, 0.0, 13, False),
)
"""The physical inputs checked for range and rate, with their fault bit and whether a fault in them takes
the law's authority."""
DEGRADING = tuple(c.name for c in CHECKS if c.degrading) + ("dt", "calibration")
FAULT_BITS = {"dt": 0, **{c.name: c.bit for c in CHECKS}, "gps": 5, "mu": 8, "wheel_speed_rl": 9,
              "wheel_speed_rr": 10, "state": 11, "calibration": 12, "wheel_speed_fl": 14, "wheel_speed_fr": 15}
"""Bit of each signal in ``fault_word`` (``state``: the ECU state was found non-finite and restarted;
``calibration``: a calibration scalar outside the limits the A2L declares)."""
MU_NO_SENSOR = 10.0
"""What an out-of-range ``mu`` reads as: no road-friction sensor (any value above the design's ``mu_max``)."""
GPS_LATCH_FIXES = 3
GPS_RECOVER_FIXES = 5
"""The GPS is in fault after this many bad fixes in a row (its fixes come at 5-10 Hz, not every period) and
recovers after ``GPS_RECOVER_FIXES`` good ones."""
WHEEL_SPEED_MAX = 500.0
"""[rad/s] Largest plausible wheel speed (about 600 km/h on a 0.33 m wheel)."""


@dataclass(frozen=True)
class GuardSettings:
    """Timing of the input guard."""

    dt_max: float = 0.1
    """[s] Largest period used as given; above it, or at or below 0, the nominal period."""
    dt_band: float | None = 0.5
    """A period outside ``[1 - dt_band, 1 + dt_band]`` times the nominal one is not used either: the nominal
    period stands in, and 50 ms of such periods are a fault of ``dt`` (a 1 kHz task whose clock reports 2 ms
    would double the filter's and the law's integration; task jitter stays well inside). None: no band, every
    period up to ``dt_max`` used as given (``evstab replay`` of a log recorded at another rate than the design's
    period: :func:`toolkit.firmware.replay.for_log_periods`)."""
    latch_time: float = 0.05
    """[s] A signal failing its checks this long in a row is in fault."""
    recover_time: float = 0.2
    """[s] ... and recovers after this long of good samples in a row. At the limit the law's absence is what
    harms: a 0.5 s NaN in the yaw rate, speed or driver's steer from the first steer of an ISO 3888-1 lane
    change at 100 km/h on mu 0.5 (compact-ev, two-track, seeds 0 and 1) peaks at 2.27-2.52 deg of sideslip with
    0.2 s, 3.75-8.5 deg with 1 s (the car alone 2.41)."""
    ramp_time: float = 0.2
    """[s] The law's authority ramps between 1 and 0 over this time."""
    restart: bool = True
    """Restart the filter and the law when the last fault recovers (False: they go on from where the held
    inputs left them)."""
    restart_hold: float = 0.0
    """[s] After a restart the authority stays at 0 this long before it ramps back. 0: at once. Holding it
    for the restarted filter to settle (its first course fix and the kinematic path's 2 s wait) spun the car
    in that lane change (about 90 deg with 2.5 s): at the limit a law on a settling filter does less harm
    than no law."""

    stuck_time: float = 0.02
    """[s] A yaw rate that has read the same value, to the bit, this long is held (a 1 kHz gyro's noise moves it
    every period; a CAN signal at 100 Hz holds each value 10 ms, a quantised one in a steady turn for as long as
    the turn lasts)."""
    consistency_ay: float = 0.3
    """[m/s^2] The yaw rate agrees with the lateral acceleration when ``|a_y - v r| <= consistency_ay +
    consistency_rate v`` ..."""
    consistency_rate: float = 0.02
    """[rad/s] ... (``a_y - v r = v beta'``: a car that does not slide turns its velocity with its body;
    the ``v`` term takes a CAN signal's 1.28 deg/s quantisation, 0.022 rad/s, and the sideslip rate of a lane
    change). A held yaw rate that disagrees is stuck: it fails its check and reads as ``a_y / v``. A live
    one may disagree (a slide: ``beta'`` is what the law is there for), a held one that agrees is a quantised
    signal in a steady turn."""
    consistency_speed: float = 5.0
    """[m/s] Below this speed the agreement is not checked (``a_y / v`` says little at walking pace)."""
    vote_rate: float | None = 0.05
    """[rad/s] (None: no vote.) While the law is passive, a yaw rate that differs from the rear wheels'
    ``(w_rr - w_rl) R / t_r`` by more than this, and from ``a_y / v`` by more than the consistency band, where
    ``a_y / v`` is nearer the wheels than half that difference, is offset (a slide separates ``a_y / v`` from the
    yaw rate by ``beta'``, and the wheels turn with the body; a wheel that slips separates the wheels, not
    ``a_y``). 0.05 outvotes a 0.1 rad/s offset on its first sample. Without wheel-speed sensors the wheels read a
    yaw rate of 0: the vote then holds on a straight road only ..."""
    vote_tau: float = 0.02
    """[s] ... the wheels' yaw rate and ``a_y / v`` taken low-passed with this time constant (first order): a
    sample of wheel-speed noise must not outvote a live gyro (0.05 rad/s of noise per wheel speed reads as
    0.014 rad/s of yaw rate, 0.002 low-passed); they lag the gyro by ``vote_tau`` times the yaw acceleration
    in a transient (0.01 rad/s at 0.5 rad/s^2) ..."""
    vote_settle: float = 0.2
    """[s] ... it starts once the law has been passive and the motors' yaw moment within ``vote_yaw_moment`` this
    long (the low-passed wheels remember the slip a torque difference made) ..."""
    vote_ay: float = 1.0
    """[m/s^2] ... it starts only while the car goes nearly straight (``|a_y|`` below this and the wheels' yaw rate
    below ``vote_rate``: at the limit a wheel that slips can side with ``a_y / v`` against a live gyro) ..."""
    vote_yaw_moment: float = 200.0
    """[N m] ... and it rests while the applied yaw moment exceeds this (the motors' torque difference makes the
    rear wheels slip apart by more than their yaw rate)."""
    steer_agree: float | None = 0.0087
    """[rad] While the law has been passive for ``steer_settle``, the driver's angle (``steer_cmd_driver``) and the
    road-wheel angle (``steer``) agree within this plus ``steer_agree_share`` of the road-wheel angle (0.5 deg
    plus 10 %: the column's twist and a variable-ratio rack); apart, both are replaced by their last good values
    (a superposition gear adds nothing while the law is passive, so the two are the same angle). None: not
    checked (a steer-by-wire servo lags the driver by its time constant times the steer rate) ..."""
    steer_agree_share: float = 0.1
    """... (the share) ..."""
    steer_settle: float = 0.2
    """[s] ... the time the law must have been passive (its correction has ramped out and the gear followed)."""
    course_stuck_turn: float = 0.035
    """[rad] A fix's course equal to the bit to that of the last fix whose course changed is stuck when the
    gyro's heading has moved by more than this since (2 deg: a receiver that quantises its course to 2 deg or
    finer changes it before the heading has moved that far, whatever the turn) ..."""
    course_stuck_tau: float = 1.0
    """[s] ... the heading change integrated with a leak of this time constant, so that a gyro bias cannot build
    it up on a long straight (a bias ``b`` reaches ``b course_stuck_tau`` at most: 0.003 rad for 3 mrad/s)."""
    course_jump: float = 0.087
    """[rad] A fix whose course has moved from the last good fix's by more than the lateral acceleration turned the
    car's velocity since (``integral of a_y / v``: the course's rate, whatever the car's sideslip does), by more
    than this plus ``course_jump_velocity * hdop / v``, is dropped (a receiver's jump or offset: 5 deg; between two
    5 Hz fixes an accelerometer 0.5 m/s^2 off at 5 m/s turns the integral by 1.1 deg, and a fix describing an
    instant 0.1 s earlier than it arrives by about 1 deg in a transient at the limit) ..."""
    course_jump_velocity: float = 0.3
    """[m/s] ... (the fixes' own noise: 0.3 m/s is 5 standard deviations of the difference of two fixes with
    0.04 m/s per axis) ..."""
    course_jump_window: float = 1.0
    """[s] ... while the last good fix is no older than this (the integral's error grows with its time: after an
    outage the next fix is taken), above ``consistency_speed``. While the GPS is in fault each fix is compared with
    the fix before it, so that a course that has moved on for good is taken back after ``GPS_RECOVER_FIXES``."""
    moment_quiet: float = 50.0
    """[N m] The applied yaw moment is offset when the ECU has commanded at most this for ``vote_settle`` and the
    motors report more than ``vote_yaw_moment`` (their lag has long decayed: a 3,000 N m command that ended
    0.2 s ago is 55 N m with a 50 ms lag); a command the ECU did not make, which the filter would take for the
    motors' own."""

    def __post_init__(self):
        if self.steer_agree is not None and not (np.isfinite(self.steer_agree) and self.steer_agree > 0):
            raise ModelError(f"guard setting 'steer_agree' must be None (not checked) or a finite number > 0, got "
                             f"{self.steer_agree!r}")
        if self.vote_rate is not None and not (np.isfinite(self.vote_rate) and self.vote_rate > 0):
            raise ModelError(f"guard setting 'vote_rate' must be None (no vote) or a finite number > 0, got "
                             f"{self.vote_rate!r}")
        if self.dt_band is not None and not 0.0 < self.dt_band < 1.0:
            raise ModelError(f"guard setting 'dt_band' must be None (no band) or between 0 and 1, got {self.dt_band!r}")
        for k in ("dt_max", "latch_time", "recover_time", "ramp_time", "restart_hold", "stuck_time",
                  "consistency_ay", "consistency_rate", "consistency_speed", "course_stuck_turn",
                  "course_stuck_tau", "course_jump", "course_jump_velocity", "course_jump_window", "moment_quiet",
                  "vote_tau", "vote_settle", "vote_ay", "vote_yaw_moment", "steer_agree_share",
                  "steer_settle"):
            v = getattr(self, k)
            if not (np.isfinite(v) and (v > 0 or (k == "restart_hold" and v == 0))):
                raise ModelError(f"guard setting '{k}' must be a finite number > 0, got {v!r}")


_SIGNALS = [c.name for c in CHECKS] + ["dt", "gps", "mu", "wheel_speed_rl", "wheel_speed_rr", "calibration",
                                       "wheel_speed_fl", "wheel_speed_fr"]
STATE = Layout("ECU guard state", [
    *[Signal(f"last_{c.name}", "-", f"last good {c.name}") for c in CHECKS],
    *[Signal(f"bad_{s}", "s", f"time {s} has failed its checks in a row (the GPS: fixes)") for s in _SIGNALS],
    *[Signal(f"good_{s}", "s", f"time {s} has passed its checks in a row (the GPS: fixes)") for s in _SIGNALS],
    *[Signal(f"fault_{s}", "-", f"1 while {s} is in fault") for s in _SIGNALS],
    Signal("raw_yaw_rate", "rad/s", "the yaw rate as it came on the last period"),
    Signal("yaw_outvoted", "-", "1 while the rear wheels and the lateral acceleration outvote the yaw rate"),
    Signal("vote_wheels", "rad/s", "the rear wheels' yaw rate, low-passed with vote_tau"),
    Signal("vote_kinematic", "rad/s", "a_y / v, low-passed with vote_tau"),
    Signal("vote_quiet", "s", "time the motors and the law have been quiet for the vote (saturates at twice "
           "vote_settle)"),
    Signal("passive_time", "s", "time the law has been passive (saturates at twice steer_settle)"),
    Signal("last_course", "rad", "course of the last fix whose course changed"),
    Signal("course_seen", "-", "1 once a fix has been read"),
    Signal("course_turn", "rad", "the gyro's heading change since that fix (leaking with course_stuck_tau)"),
    Signal("course_anchor", "rad", "course of the last good fix (in a GPS fault: of the last fix read)"),
    Signal("course_moved", "rad", "the integral of a_y / v since that fix"),
    Signal("course_age", "s", "time since that fix (saturates at twice course_jump_window)"),
    Signal("course_anchored", "-", "1 once a fix has been taken as the anchor"),
    Signal("last_yaw_moment_cmd", "N m", "the yaw moment the ECU commanded on the last period"),
    Signal("moment_quiet_time", "s", "time the ECU has commanded at most moment_quiet (saturates at twice "
           "vote_settle)"),
    Signal("held_yaw_rate", "s", "time the yaw rate has read the same value"),
    Signal("started", "-", "1 once a period has run (the first has no last good values to compare with)"),
    Signal("authority", "-", "the law's authority (1: full, 0: the driver passed through)"),
    Signal("degraded", "-", "1 while an input the law depends on is in fault and nothing stands in for it"),
    Signal("restart", "-", "1 on the period the filter and the law restart"),
    Signal("hold", "s", "time left before the authority may ramp back after a restart"),
    Signal("bad_samples", "-", "samples replaced since start"),
    Signal("fault_word", "-", "bit per signal in fault (FAULT_BITS)"),
])
"""The guard's part of the ECU state."""


def with_command(zg, yaw_moment_cmd, o=NUMPY):
    """The guard's state ``zg`` after a period with the ECU's final ``yaw_moment_cmd`` kept in it (the next period
    compares the applied yaw moment with it)."""
    st = STATE.as_dict(zg)
    st["last_yaw_moment_cmd"] = yaw_moment_cmd
    return STATE.pack(st, o)


def tree(items: list, op):
    """``op`` over ``items`` pairwise (depth log2 n): the generated C's dependent chain stays short."""
    items = list(items)
    while len(items) > 1:
        items = [op(items[i], items[i + 1]) if i + 1 < len(items) else items[i] for i in range(0, len(items), 2)]
    return items[0]


def initial_state() -> np.ndarray:
    z = STATE.zeros()
    z[STATE.index("authority")] = 1.0
    return z


def guard(s: GuardSettings, z, g: dict, dt_nominal: float, wheel_radius: float, o=NUMPY, calibration=(),
          track_rear: float = 0.0, law_blend=0.0):
    """One period of the guard: ``(z, inputs) -> (z_next, clean inputs)``, inputs a dict of
    :data:`toolkit.ecu.step.INPUTS` (numbers or casadi symbols). ``calibration``: ``(value, lower, upper)``
    of each calibration scalar (values numbers or symbols): one outside its limits (or not finite) is a fault
    (``calibration``), which takes the law's authority until every value is back inside. ``track_rear`` [m]: the
    rear track the wheels' yaw rate is read with (0: no vote on the yaw rate); ``law_blend``: the law's
    authority of the last period (the supervisor's blend; the vote rests above 0)."""
    st = STATE.as_dict(z)
    nxt = dict(st)
    clean = dict(g)
    bad = {}
    # the period first: everything below integrates with it
    dt = g["dt"]
    dt_ok = (dt > 0.0) * (dt <= s.dt_max)
    if s.dt_band is not None:
        dt_ok = dt_ok * (dt >= (1.0 - s.dt_band) * dt_nominal) * (dt <= (1.0 + s.dt_band) * dt_nominal)
    dt_c = o.if_else(dt_ok, dt, dt_nominal)
    clean["dt"] = dt_c
    bad["dt"] = 1.0 - dt_ok
    first = 1.0 - st["started"]
    nxt["started"] = 1.0 + 0.0 * dt_c
    # the yaw rate's hold: how long it has read one value (a CAN signal between its messages, or a stuck sensor)
    r_raw = g["yaw_rate"]
    same = (r_raw == st["raw_yaw_rate"]) * (1.0 - first)
    held = (st["held_yaw_rate"] + dt_c) * same
    nxt["raw_yaw_rate"] = o.if_else(o.fabs(r_raw) < 1e30, r_raw, 0.0)
    nxt["held_yaw_rate"] = o.fmin(held, 2.0 * s.stuck_time)
    oks = {}
    for c in CHECKS:
        x, last, fault = g[c.name], st[f"last_{c.name}"], st[f"fault_{c.name}"]
        ok = (x >= c.lower) * (x <= c.upper)
        if c.rate is not None:
            # against the last good value; not while in fault (a signal that moved on for good comes back), nor
            # on the first period (an ECU that starts at speed); the yaw rate's change over the time it held
            # its last value (a CAN signal moves on in one step after its message interval)
            span = dt_c + st["held_yaw_rate"] if c.name == "yaw_rate" else dt_c
            near = o.fabs(x - last) <= c.rate * span + c.step
            ok = ok * o.fmax(near, o.fmax(fault, first))
        oks[c.name] = ok
        clean[c.name] = o.if_else(ok, x, last)
    v = o.fabs(clean["speed"])
    passive = law_blend <= 0.0  # the law had no authority last period (both cross-checks below rest otherwise)
    if s.steer_agree is not None:
        # the driver's angle against the road wheels': with the law passive long enough for the superposition
        # gear's correction to be gone, the road-wheel angle is the driver's; apart, neither is taken (which of
        # the two sensors is wrong, nothing tells: both are replaced by their last good values and named)
        nxt["passive_time"] = o.if_else(passive, o.fmin(st["passive_time"] + dt_c, 2.0 * s.steer_settle), 0.0)
        settled = passive * (st["passive_time"] >= s.steer_settle - 0.25 * dt_nominal)
        band = s.steer_agree + s.steer_agree_share * o.fabs(clean["steer"])
        apart = settled * (v >= s.consistency_speed) * (o.fabs(g["steer_cmd_driver"] - g["steer"]) > band)
        for name in ("steer", "steer_cmd_driver"):
            oks[name] = oks[name] * (1.0 - apart)
            clean[name] = o.if_else(oks[name], g[name], st[f"last_{name}"])
    # the applied yaw moment against the ECU's own command: with the command quiet for vote_settle the motors' lag
    # has decayed, and a yaw moment beyond vote_yaw_moment is one the ECU did not ask for (an offset the filter would
    # take for the motors' own); it fails its check and reads as its last good value
    cmd_quiet = o.fabs(st["last_yaw_moment_cmd"]) <= s.moment_quiet
    nxt["moment_quiet_time"] = o.if_else(cmd_quiet, o.fmin(st["moment_quiet_time"] + dt_c, 2.0 * s.vote_settle), 0.0)
    unasked = cmd_quiet * (st["moment_quiet_time"] >= s.vote_settle - 0.25 * dt_nominal) * \
        (o.fabs(g["yaw_moment_applied"]) > s.vote_yaw_moment)
    oks["yaw_moment_applied"] = oks["yaw_moment_applied"] * (1.0 - unasked)
    clean["yaw_moment_applied"] = o.if_else(oks["yaw_moment_applied"], g["yaw_moment_applied"],
                                            st["last_yaw_moment_applied"])
    # the yaw rate against the lateral acceleration: a held one that disagrees is stuck
    disagree = (o.fabs(clean["ay"] - v * r_raw) > s.consistency_ay + s.consistency_rate * v) * \
        (v >= s.consistency_speed)
    stuck = (held >= s.stuck_time - 0.25 * dt_nominal) * disagree
    wl, wr = g["wheel_speed_rl"], g["wheel_speed_rr"]
    wheels_ok = (wl >= -WHEEL_SPEED_MAX) * (wl <= WHEEL_SPEED_MAX) * (wr >= -WHEEL_SPEED_MAX) * (wr <= WHEEL_SPEED_MAX)
    if track_rear > 0 and s.vote_rate is not None:
        # two out of three while the law is passive: the gyro far from the wheels' yaw rate and from a_y / v, which
        # is nearer the wheels than half the gyro's distance from them (an offset gyro). The wheels and a_y / v
        # low-passed with vote_tau: a wheel-speed sample's noise (0.05 rad/s per wheel reads 0.014 rad/s of yaw
        # rate) would outvote a live gyro for a sample; the gyro itself as it comes, so that an offset is seen on
        # its first sample, before the supervisor starts the law on the yaw error it makes
        r_wheels = (o.if_else(wheels_ok, wr, 0.0) - o.if_else(wheels_ok, wl, 0.0)) * (wheel_radius / track_rear)
        lag = dt_c / (s.vote_tau + dt_c)
        f_wheels = st["vote_wheels"] + lag * (r_wheels - st["vote_wheels"])
        f_kin = st["vote_kinematic"] + lag * (clean["ay"] / o.fmax(v, s.consistency_speed) - st["vote_kinematic"])
        nxt["vote_wheels"], nxt["vote_kinematic"] = f_wheels, f_kin
        gap = o.fabs(r_raw - f_wheels)  # NaN for a NaN gyro: every comparison below is then false
        quiet_now = (o.fabs(clean["yaw_moment_applied"]) <= s.vote_yaw_moment) * passive
        nxt["vote_quiet"] = o.if_else(quiet_now, o.fmin(st["vote_quiet"] + dt_c, 2.0 * s.vote_settle), 0.0)
        quiet = quiet_now * (st["vote_quiet"] >= s.vote_settle - 0.25 * dt_nominal)
        straight = (o.fabs(clean["ay"]) < s.vote_ay) * (o.fabs(f_wheels) < s.vote_rate)
        # the gyro beyond the consistency band from a_y / v
        apart = (v * o.fabs(f_kin - r_raw) > s.consistency_ay + s.consistency_rate * v) * (v >= s.consistency_speed)
        start = quiet * straight * (gap > s.vote_rate) * (o.fabs(f_kin - f_wheels) < 0.5 * gap)
        # once outvoted it stays so while it is still half as far from the wheels (the law would start on the
        # offset, and the vote rests while the law acts)
        keep = st["yaw_outvoted"] * (gap > 0.5 * s.vote_rate)
        outvoted = wheels_ok * apart * o.fmax(start, keep)
        nxt["yaw_outvoted"] = outvoted
        stuck = o.fmax(stuck, outvoted)
    oks["yaw_rate"] = oks["yaw_rate"] * (1.0 - stuck)
    # a stuck yaw rate reads as the one the lateral acceleration gives (a_y / v: the car's velocity turns with its
    # body while it does not slide; the last good value of a stuck sensor is the stuck value); any other sample
    # not taken as the last good value
    kinematic = clean["ay"] / o.fmax(v, s.consistency_speed)
    clean["yaw_rate"] = o.if_else(oks["yaw_rate"], g["yaw_rate"], o.if_else(stuck, kinematic, st["last_yaw_rate"]))
    # a speed sample not taken reads as the rear wheels' mean speed where both are in range (the motors' torque
    # difference speeds one as much as it slows the other)
    from_wheels = 0.5 * (o.if_else(wheels_ok, wl, 0.0) + o.if_else(wheels_ok, wr, 0.0)) * wheel_radius
    clean["speed"] = o.if_else(oks["speed"], g["speed"], o.if_else(wheels_ok, from_wheels, st["last_speed"]))
    for c in CHECKS:
        nxt[f"last_{c.name}"] = clean[c.name]
        bad[c.name] = 1.0 - oks[c.name]
    # a course fix with a non-finite course, HDOP or satellite count, or HDOP <= 0, is not a fix
    fix = g["gps_valid"] > 0.5
    fix_ok = (o.fabs(g["gps_course"]) < 1e30) * (g["gps_hdop"] > 0.0) * (g["gps_hdop"] < 1e30) * \
        (o.fabs(g["gps_sats"]) < 1e30)
    # nor is a stuck one: its course equal to the bit to that of the last fix whose course changed, while the
    # gyro's heading has moved on since (a NaN course compares unequal, and never becomes the last course)
    same = (g["gps_course"] == st["last_course"]) * st["course_seen"]
    stuck_fix = same * (o.fabs(st["course_turn"]) > s.course_stuck_turn)
    read = fix * fix_ok
    changed = read * (1.0 - same)
    nxt["last_course"] = o.if_else(changed > 0.5, g["gps_course"], st["last_course"])
    nxt["course_seen"] = o.fmax(st["course_seen"], read)
    turn = st["course_turn"] * o.fmax(1.0 - dt_c / s.course_stuck_tau, 0.0) + clean["yaw_rate"] * dt_c
    nxt["course_turn"] = o.if_else(changed > 0.5, 0.0, o.fmin(o.fmax(turn, -10.0), 10.0))
    # nor is one whose course has moved from the last good fix's by more than the lateral acceleration turned the
    # car's velocity since (a_y / v is the course's rate, whatever the sideslip does): a receiver's jump or offset
    moved = o.fmin(o.fmax(st["course_moved"] + kinematic * dt_c, -np.pi), np.pi)
    age = st["course_age"] + dt_c
    diff = g["gps_course"] - st["course_anchor"] - moved
    diff = o.if_else(diff > np.pi, diff - 2.0 * np.pi, o.if_else(diff < -np.pi, diff + 2.0 * np.pi, diff))
    limit = s.course_jump + s.course_jump_velocity * g["gps_hdop"] / o.fmax(v, s.consistency_speed)
    jumped = read * st["course_anchored"] * (age <= s.course_jump_window) * (v >= s.consistency_speed) * \
        (o.fabs(diff) > limit)
    taken = read * (1.0 - stuck_fix)
    fix_ok = fix_ok * (1.0 - stuck_fix) * (1.0 - jumped)
    clean["gps_valid"] = fix * fix_ok
    clean["gps_course"] = o.if_else(fix * fix_ok, g["gps_course"], 0.0)
    clean["gps_hdop"] = o.if_else(fix_ok, g["gps_hdop"], 1.0)
    clean["gps_sats"] = o.if_else(fix_ok, g["gps_sats"], 0.0)
    clean["gps_speed"] = o.if_else(o.fabs(g["gps_speed"]) < 1e30, g["gps_speed"], 0.0)
    bad["gps"] = fix * (1.0 - fix_ok)
    checks = [(v >= lo) * (v <= hi) for v, lo, hi in calibration]
    bad["calibration"] = 1.0 - tree(checks, lambda a, b: a * b) if checks else 0.0 * dt_c
    mu_ok = (g["mu"] >= 0.0) * (g["mu"] <= MU_NO_SENSOR)
    clean["mu"] = o.if_else(mu_ok, g["mu"], MU_NO_SENSOR)
    bad["mu"] = 1.0 - mu_ok
    for side in ("rl", "rr", "fl", "fr"):
        w = g[f"wheel_speed_{side}"]
        w_ok = (w >= -WHEEL_SPEED_MAX) * (w <= WHEEL_SPEED_MAX)
        clean[f"wheel_speed_{side}"] = o.if_else(w_ok, w, clean["speed"] / wheel_radius)
        bad[f"wheel_speed_{side}"] = 1.0 - w_ok
    words = []
    for name in _SIGNALS:
        b, fault = bad[name], st[f"fault_{name}"]
        if name == "gps":  # counted in fixes: the samples between two fixes say nothing
            bad_t = o.if_else(fix, (st["bad_gps"] + 1.0) * b, st["bad_gps"])
            good_t = o.if_else(fix, (st["good_gps"] + 1.0) * (1.0 - b), st["good_gps"])
            fault_n = o.if_else(fault > 0.5, 1.0 - (good_t >= GPS_RECOVER_FIXES - 0.5), bad_t >= GPS_LATCH_FIXES - 0.5)
            nxt["bad_gps"] = o.fmin(bad_t, 2.0 * GPS_LATCH_FIXES)
            nxt["good_gps"] = o.fmin(good_t, 2.0 * GPS_RECOVER_FIXES)
        else:
            bad_t = (st[f"bad_{name}"] + dt_c) * b
            good_t = (st[f"good_{name}"] + dt_c) * (1.0 - b)
            # in fault from latch_time of failures in a row, until recover_time of good samples in a row; a
            # quarter period short of each, so that float32 and float64 sums of the periods decide alike
            margin = 0.25 * dt_nominal
            fault_n = o.if_else(fault > 0.5, 1.0 - (good_t >= s.recover_time - margin), bad_t >= s.latch_time - margin)
            # the timers saturate: a drive of any length keeps them exact where they are compared
            nxt[f"bad_{name}"] = o.fmin(bad_t, 2.0 * s.latch_time)
            nxt[f"good_{name}"] = o.fmin(good_t, 2.0 * s.recover_time)
        nxt[f"fault_{name}"] = fault_n
        words.append(fault_n * float(2 ** FAULT_BITS[name]))
    word = tree(words, lambda a, b: a + b)
    # the course's anchor: a good fix, or any fix read while the GPS is in fault (from the fix that latches it)
    anchor = o.fmax(taken * (1.0 - jumped), taken * nxt["fault_gps"])
    nxt["course_anchor"] = o.if_else(anchor > 0.5, g["gps_course"], st["course_anchor"])
    nxt["course_moved"] = o.if_else(anchor > 0.5, 0.0, moved)
    nxt["course_age"] = o.if_else(anchor > 0.5, 0.0, o.fmin(age, 2.0 * s.course_jump_window))
    nxt["course_anchored"] = o.fmax(st["course_anchored"], anchor)
    # a speed in fault takes the authority only where the wheels cannot stand in for it
    # (both wheel speeds in range now and neither in fault: the same hysteresis as the speed's own)
    stand_in = wheels_ok * (1.0 - nxt["fault_wheel_speed_rl"]) * (1.0 - nxt["fault_wheel_speed_rr"])
    spare = {"speed": 1.0 - stand_in}
    was = st["degraded"]
    now = tree([nxt[f"fault_{name}"] * spare.get(name, 1.0) for name in DEGRADING], o.fmax)
    nxt["degraded"] = now
    step = dt_c / s.ramp_time
    restart = was * (1.0 - now) * float(s.restart)
    # the first period after evstab_init is a start too: an ECU reset at speed restarts as a recovery does
    nxt["restart"] = o.fmax(restart, first)
    nxt["hold"] = o.if_else(restart > 0.5, s.restart_hold, o.fmax(st["hold"] - dt_c, 0.0))
    down = o.fmax(now, nxt["hold"] > 0.25 * dt_nominal)  # the quarter period: float32 and float64 alike
    nxt["authority"] = o.fmin(o.fmax(st["authority"] + o.if_else(down > 0.5, -step, step), 0.0), 1.0)
    n_bad = tree([bad[name] for name in _SIGNALS], lambda a, b: a + b)
    nxt["bad_samples"] = o.fmin(st["bad_samples"] + (n_bad > 0.5), 1e7)
    nxt["fault_word"] = word
    return STATE.pack(nxt, o), clean
