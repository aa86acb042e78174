"""The stability controller's supervision: when the 2-DOF law may act, with how much authority, on
how much friction. Written once for numpy and casadi, like the law (:mod:`controllers.two_dof`).

A stability controller must do no harm: in linear driving the ECU passes the driver through, and
the model-following law of seed 003 acts only when the car needs it.

* **Friction on board** (:func:`friction_estimate`). The ECU is not told the road. It compares
  the measured lateral acceleration with the linear model's demand for the driver's steer,
  ``a_lin = v gamma_ss(delta)`` (the smaller of the demand now and lagged by ``demand_tau``, and
  only while both and the car's lateral acceleration have one sign: through a reversal of the steer
  the car is behind the demand without being saturated): when the demand is at least
  ``saturation_ay_min`` and the car delivers less than ``saturation_ratio`` of it, the tyres are
  saturated and the friction is what
  the car delivers, ``|a_y| / (peak_ratio g)`` (a saturated car sustains about 0.95 of mu g); the
  estimate falls to that with time constant ``mu_tau_down``, otherwise it recovers towards
  ``mu_max`` with ``mu_tau_up`` (not while the drive cut's oversteer latch holds), and it is never
  below what the car is using right now. The lateral acceleration is the accelerometer's reading less
  the body's roll (``ay_roll_factor``). The
  reference model's friction limit (seed 003 eq. 23-24 with ``|r_ref| <= k mu g / v``) uses
  ``min(mu_est, mu input)``; the ``mu`` input is an optional road sensor (``mu_max`` when there is
  none). ``k`` is ``turn_in_margin`` at a turn-in beyond the limit and ``friction_margin`` once the
  turn is held (:func:`reference_margin`). Friction use ``|a_y| / (mu_est g)`` shrinks the dead bands below.
* **Activation with hysteresis** (:func:`supervise`). Active when the yaw-rate error (the law's: to the
  band between the linear car and the lagged static reference, both friction-limited; see
  :mod:`controllers.two_dof`) exceeds ``(yaw_rate_deadband + yaw_rate_deadband_per_speed
  v) (1 - deadband_shrink use)``, or the estimated sideslip exceeds ``beta_threshold`` (only when the
  estimate is trustworthy: ``beta_std < beta_std_max``; the sideslip the ECU passes here is the slide,
  less the geometric sideslip ``l_r r / v`` of a turn, :func:`toolkit.ecu.step.ecu_control`); inactive again once both are below
  ``deactivate_ratio`` of their thresholds for ``hold_time`` while the friction use is below
  ``release_use``. The law's authority blends in and out over ``blend_time``; while the blend weight is 0 the commands are exactly the driver's steer and no
  yaw moment, and the law's integrators are held at 0.
* **Sideslip guard** (:func:`phase_plane_excess`): beyond the region ``|beta + phase_tau beta'| <=
  phase_beta`` of the sideslip phase plane (``beta'`` from the accelerometer and gyro), the law is
  active and a yaw moment and steer correction proportional to the excess act against the slide,
  ahead of yaw-rate tracking.
* **Slip control** (:func:`slip_authority`): the yaw moment is withdrawn while a rear wheel slips
  beyond ``slip_max``, so it never spins or locks a rear wheel.
* **Gust channel** (:func:`gust_moment`): while the driver goes straight and the law is off, a yaw
  moment on the yaw-rate and course-rate errors (gyro and accelerometer) where both see the car leave
  the driver's path, beyond a narrow band, rejects a crosswind or a split-friction pull, which stay
  inside the law's activation band. It reads no sideslip estimate (a lateral force the model does not
  know makes that estimate wrong), and no single wrong sensor makes it act.
* **Drive cut** (:func:`drive_cut`): while the law acts against oversteer, the driver's drive torque
  (the speed hold's, from the rear motors) is cut by ``drive_cut`` times the law's authority, the torque
  intervention of an ESC: the rear tyres' grip goes to the side force and the yaw moment. The
  ``drive_share`` output says how much of it the ECU lets through.
* **Steer authority**: the law's steer correction (its steer minus the driver's) is limited to
  ``steer_authority`` and its rate to ``steer_authority_rate``, as an active front steering
  superposition gear allows; the ECU itself knows when it limited a command (its own limit flags
  feed the law's anti-windup, besides the actuators' flags).
"""

from __future__ import annotations

from evstab.plants import G
from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal

STATE = Layout("supervisor state", [
    Signal("active", "-", "1 while the law is switched on"),
    Signal("hold", "s", "time both errors have been below their off thresholds"),
    Signal("blend", "-", "blend weight of the law's authority, 0-1"),
    Signal("steer_correction", "rad", "applied steer correction"),
    Signal("mu_est", "-", "friction estimate"),
    Signal("steer_saturated", "-", "the ECU's own steer limit flag of the last period"),
    Signal("yaw_moment_saturated", "-", "the ECU's own yaw-moment limit flag of the last period"),
    Signal("ay_demand", "m/s^2", "the linear model's lateral-acceleration demand, lagged"),
    Signal("slip_authority", "-", "the yaw moment's authority left by the rear wheels' slip, 0-1"),
    Signal("slip_lag", "-", "the worse rear wheel's slip, lagged"),
    Signal("gust_yaw_error", "rad/s", "the gust channel's yaw-rate error, low-passed"),
    Signal("gust_rate", "rad/s", "the kinematic sideslip rate a_y / v - r, low-passed for the gust channel"),
    Signal("oversteer", "-", "1 from the period the law acts against oversteer until its authority is out"),
    Signal("limit_time", "s", "time the driver's linear demand has been beyond the reference's limit"),
])
"""Supervisor state: activation flag, time both errors have been below their off thresholds [s],
blend weight of the law's authority [0-1], applied steer correction [rad], friction estimate [-],
the ECU's own limit flags of the last period, the linear model's lateral-acceleration demand
through a first-order lag of ``demand_tau`` (the car's own response time: a car in a transient
is behind the steady-state demand without being saturated) [m/s^2], the yaw moment's
authority left by the rear wheels' slip [0-1], the worse rear wheel's slip through a lag of ``slip_lead_time`` [-],
the gust channel's low-passed errors, the oversteer latch of the drive cut (:func:`drive_cut`), the time the
driver's linear demand has been beyond the reference's limit (:func:`reference_margin`) [s]."""


def initial_state(d, o=NUMPY):
    """The supervisor's state at the start: a list of numbers, or with ``o`` CASADI a column (``mu_max`` may be
    a calibration symbol)."""
    v = STATE.pack(o=o, active=0.0, hold=0.0, blend=1.0 if d.always_active else 0.0, steer_correction=0.0,
                   mu_est=d.mu_max if o is not NUMPY else float(d.mu_max), steer_saturated=0.0,
                   yaw_moment_saturated=0.0, ay_demand=0.0, slip_authority=1.0, slip_lag=0.0, gust_yaw_error=0.0,
                   gust_rate=0.0, oversteer=0.0, limit_time=0.0)
    return list(v) if o is NUMPY else v


def friction_estimate(d, mu_est, demand, speed, ay, yaw_rate, gamma_ss_unlimited, dt, o=NUMPY, oversteer=0.0):
    """``(mu_next, use, demand_next)``: the friction estimate after this period, the friction use
    ``|a_y| / (mu g)`` and the lagged linear demand. ``ay`` is the car's lateral acceleration (the
    ECU passes the accelerometer's reading less the body's roll, :attr:`TwoDofDesign.ay_roll_factor`).

    Where the car is saturated the estimate falls towards what it delivers with ``mu_tau_down``, and with
    ``mu_tau_slide`` while the car slides out of a held turn: its ``yaw_rate`` beyond what its lateral
    acceleration carries (``(r - a_y / v) sign(a_y)``) by more than ``slide_rate_fast``, and the linear demand
    now within ``slide_demand_steady`` of the lagged one. That is a road turned slippery under a car in a
    turn, where a slow estimate keeps the law's friction-limited reference high while the rear axle goes;
    through a steer reversal the yaw rate leads the lateral acceleration as much without a slide.

    The estimate does not recover while ``oversteer`` (the drive cut's latch, :func:`drive_cut`) is set: a car
    that slows in a held turn asks less of the linear model and stops reading as saturated while it still
    slides, and a recovering estimate would lift the reference above what the car holds."""
    k = 1.0 - o.exp(-dt / d.demand_tau)
    now = speed * gamma_ss_unlimited
    demand_next = demand + (now - demand) * k
    a = o.fabs(ay)
    delivered = a / (d.peak_ratio * G)
    # the demand judged: the smaller of the linear demand now and lagged, on the lagged one's side (0 where
    # they differ in sign), and only while the car turns that way too: through a reversal of the steer
    # the car is behind both without being saturated
    a_lin = o.fmax(o.fmin(o.if_else(demand_next >= 0.0, now, -now), o.fabs(demand_next)), 0.0)
    saturated = (a_lin > d.saturation_ay_min) * (a < d.saturation_ratio * a_lin) * (ay * demand_next > 0.0)
    target = o.if_else(saturated > 0.5, delivered, d.mu_max)
    # the car slides out: it yaws faster than its lateral acceleration carries (beta' against the turn) while
    # the driver holds the turn (the demand now within slide_demand_steady of the lagged one; through a
    # reversal the yaw rate leads the lateral acceleration without a slide)
    slide_rate = (yaw_rate - ay / o.fmax(speed, 1.0)) * o.if_else(ay >= 0.0, 1.0, -1.0)
    steady = o.fabs(now - demand_next) <= d.slide_demand_steady * o.fabs(demand_next)
    down = o.if_else((slide_rate > d.slide_rate_fast) * steady > 0.5, d.mu_tau_slide, d.mu_tau_down)
    tau = o.if_else(target < mu_est, down, d.mu_tau_up)
    rise = o.if_else(target > mu_est, 1.0 - oversteer, 1.0)
    mu_next = mu_est + (target - mu_est) * o.fmin(dt / tau, 1.0) * rise
    mu_next = o.fmin(o.fmax(o.fmax(mu_next, delivered), d.mu_min), d.mu_max)
    use = o.fmin(a / (o.fmax(mu_next, d.mu_min) * G), 1.0)
    return mu_next, use, demand_next



def reference_margin(d, limit_time, beyond, dt, fresh=0.0, o=NUMPY):
    """``(margin, limit_time_next)``: the reference's yaw-rate limit as a share of ``mu g / v`` this period, and
    the time the driver's linear demand has been beyond the limit (``beyond`` 1: ``|gamma_lin|`` above
    ``friction_margin mu g / v``). ``turn_in_margin`` for the first ``turn_in_time`` of such a turn, then
    linearly to ``friction_margin`` over ``turn_in_fall_time``; the time restarts from 0 once the demand is
    within the limit. A transient turn-in reaches the tyres' peak without a steady slide (FMVSS 126's
    lateral displacement needs the reference there), while a steady turn at the peak drifts out. On a
    fresh start (``fresh`` 1) in a turn beyond the limit the turn is taken as held (the steady margin)."""
    full = d.turn_in_time + d.turn_in_fall_time
    t = o.if_else(beyond > 0.5, o.fmin(limit_time + dt, full), 0.0)
    t = o.if_else(fresh * beyond > 0.5, full, t)
    fall = o.fmin(o.fmax((t - d.turn_in_time) / d.turn_in_fall_time, 0.0), 1.0)
    return d.turn_in_margin + (d.friction_margin - d.turn_in_margin) * fall, t


def yaw_moment_limit(d, mu_est, use, o=NUMPY):
    """The yaw moment [N m] the rear motors may make this period: ``rear_grip_share`` of what the rear
    tyres' friction circle leaves after the lateral force, ``mu W_r / 2 sqrt(1 - use^2)`` per wheel
    (``W_r = m g l_f / L``; both axles at the car's friction use ``|a_y| / (mu g)``), times the rear
    track (a torque difference ``+-F`` at the two wheels makes ``F t_r``); never above ``nz_max``."""
    p = d.params
    w_rear = p.mass * G * p.lf / (p.lf + p.lr)
    spare = o.sqrt(o.fmax(1.0 - use * use, 0.0))
    return o.fmin(d.rear_grip_share * mu_est * 0.5 * w_rear * spare * p.track_rear, d.nz_max)


def slip_authority(d, k, slip_lag, speed, omega_rl, omega_rr, wheel_radius, dt, o=NUMPY):
    """The yaw moment's authority after this period, 0-1: slip control of the rear motors, on the slip
    of the worse rear wheel, ``|omega R_w - v| / max(v, 3 m/s)`` (spinning under the drive torque or
    locking under the brake torque the yaw moment adds).

    The slip predicted ``slip_lead_time`` ahead from its growth sets a target
    authority that is 1 up to ``slip_onset`` x ``slip_max`` and falls linearly to 0 at ``slip_max``:
    the moment is withdrawn while the slip grows, before it reaches the bound (a cut that starts at
    the bound comes too late for a motor with a finite torque rate and a wheel that, once its tyre
    saturates, spins up within tens of milliseconds). The authority falls towards the target at up to
    ``1 / slip_cut_time`` per second and recovers at up to ``1 / slip_recover_time``.

    The growth is the slip minus its first-order lag of time constant ``slip_lead_time``
    (``slip_lag``, the state): for a slip that grows at a steady rate that difference is the rate
    times the time constant, the prediction ``slip_lead_time`` ahead, and unlike a difference of two
    samples it does not amplify the wheel-speed sensors' noise. Returns ``(authority_next,
    slip_lag_next)``."""
    ref = o.fmax(speed, 3.0)
    slip = o.fmax(o.fabs(omega_rl * wheel_radius - speed), o.fabs(omega_rr * wheel_radius - speed)) / ref
    predicted = slip + o.fmax(slip - slip_lag, 0.0)
    lag_next = slip_lag + (slip - slip_lag) * o.fmin(dt / d.slip_lead_time, 1.0)
    onset = d.slip_onset * d.slip_max
    target = o.fmin(o.fmax((d.slip_max - predicted) / o.fmax(d.slip_max - onset, 1e-9), 0.0), 1.0)
    step = o.fmin(o.fmax(target - k, -dt / d.slip_cut_time), dt / d.slip_recover_time)
    return o.fmin(o.fmax(k + step, 0.0), 1.0), lag_next


def straight_share(d, demand_now, demand_lagged, o=NUMPY):
    """How straight the driver goes, 0-1: 1 while the linear lateral-acceleration demand and its change
    ``|a_now| + |a_now - a_lagged|`` are below ``gust_demand``, falling linearly to 0 at twice it."""
    x = (o.fabs(demand_now) + o.fabs(demand_now - demand_lagged)) / o.fmax(d.gust_demand, 1e-9)
    return o.fmin(o.fmax(2.0 - x, 0.0), 1.0)


def gust_moment(d, lags, yaw_rate_ref, yaw_rate, beta_rate, straight, speed, nz_limit, dt, o=NUMPY):
    """``(nz, lags_next)``: the gust channel's yaw moment [N m] and its low-passed errors
    ``(yaw-rate error, kinematic sideslip rate)``.

    Two errors from two sensors, each against the rate of turn the driver's steer asks of the linear
    model: the yaw-rate error ``e_r = r_ref - r`` (the gyro) and the course-rate error ``e_c = r_ref -
    a_y / v = e_r - beta'`` (the accelerometer, with the kinematic sideslip rate ``beta' = a_y / v -
    r``), both through first-order lags of ``gust_tau``. The channel acts only while both are beyond
    ``gust_deadband`` on one side: a push that turns the car and moves it sideways off the driver's
    path shows in both, a wrong gyro or accelerometer in one. It then acts on ``e = e_r -
    gust_course_share beta'`` beyond the band: ``I_z gust_gain`` times the excess, times
    :func:`straight_share`, within ``gust_nz_max`` and the rear tyres' ``nz_limit``; 0 below
    ``min_speed``. Positive errors: the car turns right of the path the driver asks for, a positive
    (left) moment."""
    k = o.fmin(dt / d.gust_tau, 1.0)
    e_r = lags[0] + (yaw_rate_ref - yaw_rate - lags[0]) * k
    rate = lags[1] + (beta_rate - lags[1]) * k
    e_c = e_r - rate
    band = d.gust_deadband
    e = e_r - d.gust_course_share * rate
    # the two agree: one sign, and the smaller beyond half the band (whole from the band on)
    least = o.fmin(o.fabs(e_r), o.fabs(e_c))
    agree = o.fmin(o.fmax(2.0 * least / o.fmax(band, 1e-12) - 1.0, 0.0), 1.0) * (e_r * e_c > 0.0)
    excess = agree * (e - o.fmin(o.fmax(e, -band), band))
    nz = d.params.yaw_inertia * d.gust_gain * excess * straight * (speed >= d.min_speed)
    lim = o.fmin(d.gust_nz_max, nz_limit)
    return o.fmin(o.fmax(nz, -lim), lim), (e_r, rate)


def slide(d, beta, yaw_rate, speed, o=NUMPY):
    """The sideslip [rad] the sideslip threshold and the phase plane judge: ``beta`` less the part of it the
    geometry of a turn explains, ``geometric_share l_r r / v`` (the rear axle follows a path inside the CG's: a
    car at 40 km/h turning at 35 deg/s has 4 deg of sideslip at its CG with its rear tyres hardly slipping),
    taken only where it has the sideslip's sign and at most the sideslip itself, so that it can shrink the
    sideslip judged, never grow it or change its sign (a slide has a sideslip against the turn, which keeps
    all of it). ``speed`` above 0."""
    geometric = d.geometric_share * d.params.lr * yaw_rate / speed
    return beta - o.fmin(o.fmax(geometric, o.fmin(beta, 0.0)), o.fmax(beta, 0.0))


def phase_plane_excess(d, beta, beta_rate, trusted, o=NUMPY):
    """How far [rad] the car is outside the sideslip phase-plane region
    ``|beta + phase_tau beta'| <= phase_beta`` (signed, 0 inside).

    ``beta'`` is the kinematic sideslip rate ``a_y / v - r`` from the accelerometer and gyro, which
    holds at the limit where the tyre model does not; the estimated sideslip counts only while the
    estimate is trustworthy (``trusted``: ``beta_std < beta_std_max``), otherwise the region is a
    bound on the sideslip rate alone. Beyond it the car is sliding away (a growing slide reaches the
    boundary before the sideslip itself is large), and the controller puts sideslip first."""
    s = trusted * beta + d.phase_tau * beta_rate
    return s - o.fmin(o.fmax(s, -d.phase_beta), d.phase_beta)


def drive_cut(d, oversteer, blend, yaw_rate_error, yaw_rate, beta, beta_rate, beta_std, o=NUMPY):
    """``(drive_share, oversteer_next)``: the share of the driver's drive torque the ECU lets through, and the
    oversteer latch.

    The latch is set on the first period the law has authority (``blend`` > 0, this period's) and the car
    oversteers: it yaws beyond the reference band (the law's ``yaw_rate_error`` against the yaw rate), is
    outside the phase-plane region (:func:`phase_plane_excess`), or its sideslip ``beta`` (:func:`slide`) is
    beyond ``beta_threshold`` while the estimate is trusted; it holds until the law's authority is out. The
    share is ``1 - drive_cut x blend`` while it is set, 1 otherwise (and 1 with ``always_active``, the
    paper's law). The speed hold's drive torque comes from the rear motors, and what they take from the
    rear tyres' grip the rear axle lacks against the slide. A car that understeers keeps its drive (cutting
    it would move load to the front axle: lift-off oversteer). Held, not judged each period: the yaw-rate
    error crosses the band's edge with the gyro's noise in a slide, and a cut judged each period would
    switch the drive on and off at 1 kHz."""
    trusted = beta_std < d.beta_std_max
    excess = phase_plane_excess(d, beta, beta_rate, trusted, o)
    over = o.fmax(o.fmax(yaw_rate_error * yaw_rate < 0.0, o.fabs(excess) > 0.0),
                  trusted * (o.fabs(beta) > d.beta_threshold))
    latch = o.if_else(blend > 0.0, o.fmax(oversteer, over), 0.0)
    cut = 0.0 if d.always_active else d.drive_cut
    return 1.0 - cut * blend * latch, latch


def supervise(d, z, speed, yaw_rate_error, beta, beta_std, use, steer_driver, steer_law, nz_law, nz_limit, dt,
              o=NUMPY, beta_rate=None):
    """``(z_next, steer_cmd, nz_cmd, law_on)``: the commands after supervision, and whether the law's
    integrators may run (0: hold them at 0). ``z`` per :data:`STATE`; ``z_next`` a dict of the entries
    this function updates (the friction and slip entries come from :func:`friction_estimate` and
    :func:`slip_authority`). ``beta_rate``: the kinematic sideslip rate [rad/s] for the phase-plane
    guard (None: no guard)."""
    zs = STATE.unpack(z)
    active, hold, blend, corr = zs.active, zs.hold, zs.blend, zs.steer_correction
    thr_r = (d.yaw_rate_deadband + d.yaw_rate_deadband_per_speed * o.fabs(speed)) * (1.0 - d.deadband_shrink * use)
    trusted = beta_std < d.beta_std_max
    excess = 0.0 * speed if beta_rate is None else phase_plane_excess(d, beta, beta_rate, trusted, o)
    on = (o.fabs(yaw_rate_error) > thr_r) + trusted * (o.fabs(beta) > d.beta_threshold) + (o.fabs(excess) > 0.0)
    quiet = (o.fabs(yaw_rate_error) < d.deactivate_ratio * thr_r) * (
        1.0 - trusted * (o.fabs(beta) >= d.deactivate_ratio * d.beta_threshold)) * (use < d.release_use)
    fast = speed >= d.min_speed
    hold_next = o.if_else(active > 0.5, o.if_else(quiet > 0.5, hold + dt, 0.0), 0.0)
    stay = (active > 0.5) * (hold_next < d.hold_time)
    active_next = o.if_else(fast > 0.5, o.if_else(on + stay > 0.5, 1.0, 0.0), 0.0)
    if d.always_active:
        active_next, hold_next = 1.0 + 0.0 * speed, 0.0 * speed
    step = dt / d.blend_time
    blend_next = o.fmin(o.fmax(blend + o.if_else(active_next > 0.5, step, -step), 0.0), 1.0)
    if d.always_active:
        blend_next = 1.0 + 0.0 * speed
    # yaw guard: while the yaw-rate error is beyond guard_share of its dead band, no command may push the yaw
    # rate further from the reference (the law's sideslip and disturbance channels, fed by estimates that
    # fail at the limit, can ask for that): such a command fades out over the next guard_width of the band
    # (dropped at one error, it would switch between all and nothing as the gyro's noise moves the error
    # across it); b21 > 0 and b22 > 0: a left steer or a positive moment turns the car left
    beyond = o.fmin(o.fmax((o.fabs(yaw_rate_error) - d.guard_share * thr_r) / o.fmax(d.guard_width * thr_r, 1e-9),
                           0.0), 1.0)
    want = steer_law - steer_driver
    want = o.if_else(want * yaw_rate_error < 0.0, (1.0 - beyond) * want, want)
    nz_law = o.if_else(nz_law * yaw_rate_error < 0.0, (1.0 - beyond) * nz_law, nz_law)
    # sideslip first beyond the phase-plane region: a yaw moment and a steer correction that turn the
    # car against the slide (beta' = a_y / v - r: more yaw rate, less sideslip rate), added after the
    # yaw guard so that it cannot drop them
    want = want + d.phase_gain_steer * excess
    nz_law = o.fmin(o.fmax(nz_law + d.phase_gain_nz * d.params.yaw_inertia * excess, -nz_limit), nz_limit)
    # the steer correction within the superposition's authority and rate
    limited = o.fmin(o.fmax(want, -d.steer_authority), d.steer_authority)
    rate = d.steer_authority_rate * dt
    corr_next = o.fmin(o.fmax(limited, corr - rate), corr + rate)
    steer_sat = o.if_else(o.fabs(corr_next - want) > 1e-9 * o.fmax(1.0, o.fabs(want)), 1.0, 0.0)
    nz_sat = o.if_else(o.fabs(nz_law) >= nz_limit * (1.0 - 1e-9), 1.0, 0.0)
    steer_cmd = steer_driver + blend_next * corr_next
    nz_cmd = blend_next * nz_law
    law_on = o.if_else(blend_next > 0.0, 1.0, 0.0)
    corr_next = corr_next * law_on  # inactive: the correction restarts from 0
    z_next = {"active": active_next, "hold": hold_next, "blend": blend_next, "steer_correction": corr_next,
              "steer_saturated": steer_sat, "yaw_moment_saturated": nz_sat}
    return z_next, steer_cmd, nz_cmd, law_on
