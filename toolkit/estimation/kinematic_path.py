"""The filter's kinematic sideslip path: where the tyres leave the linear model, the sideslip row of
:func:`toolkit.estimation.kalman.step` blends towards the kinematics ``beta' = a_y / v - r``, which need no
tyre model (:func:`blend`), by a weight from the measured lateral acceleration's departure from the model's
(:func:`weight`); the accelerometer's reading compensated for roll and road bank
(:func:`lateral_acceleration`) and, from a vibrating body, low-passed (:func:`accel_low_pass`). Written once
for numpy and casadi, like the filter step."""

from __future__ import annotations

import numpy as np

from evstab.plants import G
from evstab.plants.backend import CASADI, NUMPY
from evstab.plants.signals import Layout, Signal
from .core import column as _col, dot as _dot
from .spec import FilterDesign


KINEMATIC = Layout("kinematic path state", [
    Signal("dev", "m/s^2", "the departure of the lateral acceleration from the model's, lagged"),
    Signal("ay_level", "m/s^2", "the lateral acceleration's magnitude, peak-held"),
    Signal("roll", "rad", "the body's roll angle (roll gyro and static roll model)"),
    Signal("ay_offset", "m/s^2", "the lateral accelerometer's offset in straight driving (road bank, bias)"),
])
"""The kinematic sideslip path's part of the filter state (:func:`blend`)."""
KINEMATIC_LP = Layout("kinematic path state with the accelerometer's low-pass", list(KINEMATIC) + [
    Signal("ay_last", "m/s^2", "the last lateral acceleration read (its noise from the differences)"),
    Signal("ay_noise", "m^2/s^4", "the accelerometer's white-noise variance per sample, half the mean squared "
                                  "difference of successive readings"),
    Signal("ay_lp1", "m/s^2", "the lateral acceleration through the first of two lags"),
    Signal("ay_lp", "m/s^2", "... and through the second (the low-passed lateral acceleration)"),
    Signal("dep_lp1", "m/s^2", "the signed departure from the model's lateral acceleration, first lag"),
    Signal("dep_lp", "m/s^2", "... and second lag"),
    Signal("rate_lp1", "rad/s", "the kinematic sideslip rate a_y / v - r (gyro less its bias), first lag"),
    Signal("rate_lp", "rad/s", "... and second lag"),
])
"""The kinematic path's state where ``NoiseSettings.kinematic_ay_cutoff`` is set (:func:`accel_low_pass`)."""
RELEASE = Signal("w_yaw", "-", "the yaw-rate row's weight: the path's, peak-held and decaying (kinematic_yaw_release)")
KINEMATIC_RELEASE = Layout("kinematic path state with the yaw row's release", list(KINEMATIC) + [RELEASE])
KINEMATIC_LP_RELEASE = Layout("kinematic path state with the low-pass and the yaw row's release",
                              list(KINEMATIC_LP) + [RELEASE])


def kinematic_layout(d: FilterDesign) -> Layout:
    """The kinematic path's state layout of a design (:data:`KINEMATIC`, or :data:`KINEMATIC_LP` with the
    accelerometer's low-pass; each with the yaw row's weight where ``kinematic_yaw_release`` is set)."""
    lp, release = d.noise.kinematic_ay_cutoff > 0, d.noise.kinematic_yaw_release > 0
    return {(False, False): KINEMATIC, (True, False): KINEMATIC_LP, (False, True): KINEMATIC_RELEASE,
            (True, True): KINEMATIC_LP_RELEASE}[(lp, release)]


def roll_compensation(p) -> float:
    """The factor that turns the lateral accelerometer's reading into the car's lateral acceleration
    in the road plane in steady cornering (:attr:`plants.VehicleParams.roll_reading_factor`: the reading is
    ``a_y + g phi`` with the body's static roll ``phi``; 1 without the roll parameters)."""
    return p.roll_reading_factor


def static_roll_gain(p) -> float:
    """Steady-state roll per lateral acceleration [rad per m/s^2] (:attr:`plants.VehicleParams.roll_gradient`;
    0 without the roll parameters)."""
    k = p.roll_gradient
    return 0.0 if k is None else k


def lateral_acceleration(d: FilterDesign, g, ks, o):
    """The car's lateral acceleration in the road plane from the accelerometer, and the next roll
    estimate: the reading less the offset learnt in straight driving (road bank, bias) is
    ``a_y cos(phi) + g sin(phi)``. With a roll gyro (``roll_rate_ok``) ``phi`` is a complementary
    filter, ``phi' = p + (phi_static - phi) / kinematic_roll_tau``, which follows the body's roll
    dynamics (the static model alone misses up to 1.6 m/s^2 on the Vanagon's sine with dwell);
    without it, the static roll ``phi_static = k c (reading - offset)``
    (:func:`static_roll_gain`, :func:`roll_compensation`)."""
    nz = d.noise
    reading = g.ay - ks.ay_offset
    static = static_roll_gain(d.params) * roll_compensation(d.params) * reading
    if g.roll_rate_ok is None:
        roll = static
    else:
        filt = ks.roll + g.dt * (g.roll_rate + (static - ks.roll) / nz.kinematic_roll_tau)
        roll = g.roll_rate_ok * filt + (1.0 - g.roll_rate_ok) * static
    return (reading - G * o.sin(roll)) / o.cos(roll), roll


def blend(d: FilterDesign, A, B, q, x, uin, g, v_m, dyn, kin_state, o):
    """The sideslip row where the tyres have left the linear model: ``beta' = a_y / v - r`` (kinematics:
    no tyre model), blended in with the weight ``w`` from the measured lateral acceleration's
    (:func:`lateral_acceleration`: roll and road bank compensated) departure from the linear model's
    at the current estimate, ``a_model = v (beta'_model + r)``, through a first-order lag of
    ``kinematic_dev_tau``: ``w = 0`` up to ``kinematic_ay_on``, 1 from ``kinematic_ay_full``; and
    only while the lateral acceleration's peak-held magnitude is above ``kinematic_ay_quiet``.
    The row becomes ``(1 - w) row_model + w (a_y / v - r)``, its process noise
    ``(1 - w) q_beta + w q_beta_kinematic``; the yaw-rate row ``(1 - w_r) row_model`` with process noise
    ``(1 - w_r) q_yaw_rate + w_r q_yaw_rate_kinematic`` (a random walk the gyro pins), ``w_r`` the weight
    itself or, with ``kinematic_yaw_release``, its peak-held decay (:func:`weight`).
    Returns ``(A, B, q, kinematic drive, next state per KINEMATIC)``."""
    n = d.n
    ib, ir = d.index("beta"), d.index("yaw_rate")
    w, q, kin, state, lagged = weight(d, [A[ib, j] for j in range(n)], [B[ib, 0], B[ib, 1]], q, x, uin,
                                                 g, v_m, dyn, kin_state, o)
    w_r = yaw_weight(d, w, state)
    keep = 1.0 - w
    keep_r = keep if w_r is w else 1.0 - w_r
    if o is not CASADI:
        A, B = A.copy(), B.copy()
    # both lateral rows leave the tyre model: beta' from the kinematics, r' a random walk that the gyro
    # pins (left on the model, the gyro's innovations would reach the sideslip through a21)
    for i, k in ((ib, keep), (ir, keep_r)):
        for j in range(n):
            A[i, j] = A[i, j] * k
        B[i, 0], B[i, 1] = B[i, 0] * k, B[i, 1] * k
    # beta' takes -r from the yaw-rate state, except the share the low-passed measured rate carries
    A[ib, ir] = A[ib, ir] - (w if lagged is None else w - lagged)
    return A, B, q, kin, state


def yaw_weight(d: FilterDesign, w, state):
    """The yaw-rate row's weight: the path's ``w``, or with ``kinematic_yaw_release`` the peak-held one the
    path's next ``state`` carries."""
    return kinematic_layout(d).unpack(state).w_yaw if d.noise.kinematic_yaw_release > 0 else w


def transition(d: FilterDesign, E, Gu, w, dt, o, lagged=None, w_r=None):
    """:func:`blend` on a tabulated transition (:mod:`toolkit.estimation.transition`): the
    sideslip row of ``E`` and ``G`` scaled by ``1 - w``, the yaw-rate and heading rows (the heading's through
    the yaw rate's) by ``1 - w_r`` (the yaw row's weight, :func:`yaw_weight`; None: ``w``), and what the
    kinematics alone give added: ``-w dt`` where ``beta'`` takes ``-r``, ``w_r dt`` where ``psi'`` takes ``r``.
    Exact for weights 0 and 1; between them the blend of the discretisations differs from the discretisation
    of the blend by terms of ``(A dt)^2`` (``tests/toolkit/test_transition.py``), far below the path's own
    modelling error."""
    n = d.n
    ib, ir = d.index("beta"), d.index("yaw_rate")
    w_r = w if w_r is None else w_r
    keep = 1.0 - w
    keep_r = keep if w_r is w else 1.0 - w_r
    if o is not CASADI:
        E, Gu = E.copy(), Gu.copy()
    rows = [(ib, keep), (ir, keep_r)] + ([(d.index("yaw"), keep_r)] if "yaw" in d.states else [])
    for i, k in rows:
        for j in range(n):
            E[i, j] = E[i, j] * k
        Gu[i, 0], Gu[i, 1] = Gu[i, 0] * k, Gu[i, 1] * k
    E[ib, ir] = E[ib, ir] - (w if lagged is None else w - lagged) * dt
    if "yaw" in d.states:
        E[d.index("yaw"), ir] = E[d.index("yaw"), ir] + w_r * dt
    return E, Gu


def weight(d: FilterDesign, a_row, b_row, q, x, uin, g, v_m, dyn, kin_state, o):
    """The kinematic path's weight ``w`` (see :func:`blend`) from the model's sideslip row
    ``a_row`` (continuous ``A``) and ``b_row`` (``B``); returns ``(w, q, kinematic drive, next state, lagged)``,
    ``lagged`` the share of ``w`` whose ``-r`` the low-passed measured rate carries (None without the
    accelerometer's low-pass)."""
    nz, n = d.noise, d.n
    ib, ir = d.index("beta"), d.index("yaw_rate")
    lay_k = kinematic_layout(d)
    ks = lay_k.unpack(kin_state)
    ay, roll = lateral_acceleration(d, g, ks, o)
    a_model = v_m * (_dot(_col(a_row, o), x, o) + b_row[0] * uin[0] + b_row[1] * uin[1] + x[ir])
    lp, share = {}, None
    on, full = nz.kinematic_ay_on, nz.kinematic_ay_full
    if nz.kinematic_ay_cutoff > 0:
        lp, share, ay_seen, departure = accel_low_pass(d, ks, g, ay, a_model, v_m, x, o)
        if nz.kinematic_noise_sigmas > 0:
            shift = nz.kinematic_noise_sigmas * share * low_passed_noise(d, lp["ay_noise"], g.dt, o)
            on, full = on + shift, full + shift
    else:
        ay_seen, departure = ay, ay - a_model
    dev = ks.dev + (saturation_evidence(d, ay_seen, departure, o) - ks.dev) * o.fmin(g.dt / nz.kinematic_dev_tau, 1.0)
    # peak hold with an exponential decay: rises with |a_y| at once, falls with kinematic_quiet_tau
    level = o.fmax(o.fabs(ay_seen), ks.ay_level * (1.0 - o.fmin(g.dt / nz.kinematic_quiet_tau, 1.0)))
    w = o.fmin(o.fmax((dev - on) / (full - on), 0.0), 1.0) * dyn
    # no tyre saturates while the car hardly accelerates sideways: the path lets go however far the
    # estimate's model departs (a sideslip error left by a slide would otherwise hold it on)
    w = w * o.fmin(o.fmax(level / nz.kinematic_ay_quiet - 1.0, 0.0), 1.0)
    if g.ay_ok is not None:
        w = w * g.ay_ok
    if g.gyro_ok is not None:  # the kinematics integrate the gyro's yaw rate: not while it is found stuck
        w = w * g.gyro_ok
    # straight driving on the model (path off, yaw rate near zero): what the accelerometer reads is
    # the road's bank and its own bias; learnt through a lag
    straight = (o.fabs(g.yaw_rate - x[d.index("gyro_bias")]) < nz.kinematic_straight_rate) * (w <= 0.0) * dyn
    if g.ay_ok is not None:
        straight = straight * g.ay_ok
    offset = ks.ay_offset + straight * (g.ay - G * o.sin(roll) - ks.ay_offset) * o.fmin(
        g.dt / nz.kinematic_offset_tau, 1.0)
    keep = 1.0 - w
    w_r, keep_r = w, keep
    if nz.kinematic_yaw_release > 0:  # the yaw row's weight: the path's, peak-held, decaying with the release lag
        w_r = o.fmax(w, ks.w_yaw * (1.0 - o.fmin(g.dt / nz.kinematic_yaw_release, 1.0)))
        keep_r = 1.0 - w_r
        lp["w_yaw"] = w_r
    e_b, e_r = np.eye(n)[ib], np.eye(n)[ir]
    q = q * _col(1.0 - e_b - e_r, o) + _col(e_b, o) * (q[ib] * keep + nz.q_beta_kinematic * w) \
        + _col(e_r, o) * (q[ir] * keep_r + nz.q_yaw_rate_kinematic * w_r)
    if share is None:
        kin, lagged = _col(e_b, o) * (w * ay / v_m), None
    else:  # a noisy accelerometer: beta' = a_y / v - r from the measurements, both through the same lags
        kin = _col(e_b, o) * ((w * ay / v_m) * (1.0 - share) + (w * share) * lp["rate_lp"])
        lagged = w * share
    return w, q, kin, lay_k.pack(o=o, dev=dev, ay_level=level, roll=roll, ay_offset=offset, **lp), lagged


def saturation_evidence(d: FilterDesign, ay, departure, o=NUMPY):
    """What the kinematic path's departure reads at a measured lateral acceleration ``ay`` and its departure
    ``ay - a_model`` from the linear model's: ``|departure|``; with ``kinematic_overpredict`` ``k``, where the
    two have one sign, what the model asks beyond the measurement, ``|a_model| - |ay|``, in full and what the
    measurement has beyond the model (no tyre gives more than its linear force) times ``1 - k``;
    ``|departure|`` where they disagree in sign."""
    dep = o.fabs(departure)
    k = d.noise.kinematic_overpredict
    if k <= 0:
        return dep
    model = ay - departure
    same = model * ay >= 0.0
    over = o.fmax(o.fabs(model) - o.fabs(ay), 0.0)
    if k < 1:
        over = over + (1.0 - k) * o.fmax(o.fabs(ay) - o.fabs(model), 0.0)
    return same * over + (1.0 - same) * dep


def low_pass_alpha(d: FilterDesign, dt):
    """The gain per sample of each of the low-pass's two first-order lags (backward Euler at the corner
    frequency ``kinematic_ay_cutoff``)."""
    return dt / (dt + 1.0 / (2.0 * np.pi * d.noise.kinematic_ay_cutoff))


def low_passed_noise(d: FilterDesign, variance, dt, o=NUMPY):
    """The standard deviation of white noise of ``variance`` per sample after the low-pass's two lags: the sum
    of the squared impulse response ``a^2 (k + 1) b^k`` (``a`` :func:`low_pass_alpha`, ``b = 1 - a``) is
    ``a^4 (1 + b^2) / (1 - b^2)^3``, about ``a / 4`` for a corner far below the sample rate."""
    a = low_pass_alpha(d, dt)
    b2 = (1.0 - a) * (1.0 - a)
    c = 1.0 - b2
    return o.sqrt(o.fmax(variance, 0.0) * (a * a * a * a) * (1.0 + b2) / (c * c * c))


def accel_low_pass(d: FilterDesign, ks, g, ay, a_model, v_m, x, o):
    """What the kinematic path reads from a noisy accelerometer (``kinematic_ay_cutoff`` set).

    The accelerometer's white noise is estimated from successive readings (half the mean squared
    difference, through a lag of ``accel_noise_tau``). Where its standard deviation per sample is above
    ``accel_noise_on``, the path's decisions (the departure from the model's lateral acceleration, signed,
    and the peak-held level) and the kinematic sideslip rate ``a_y / v - r`` (gyro less its bias) go through
    two first-order lags of corner frequency ``kinematic_ay_cutoff`` (backward Euler: stable at any sample
    rate), fully from ``accel_noise_full``. Lagging the rate as a whole keeps the accelerometer and the gyro
    in step. A vibrating body's accelerometer (the Stanford GTI's: ~4 m/s^2 per sample at 40-100 Hz)
    would otherwise hold the path on; a quiet one (0.05 m/s^2) leaves the readings as they are, to the bit.
    Returns ``(next low-pass states, share of the low-passed signals, level signal, departure)``."""
    nz = d.noise
    diff = ay - ks.ay_last
    noise = ks.ay_noise + (0.5 * diff * diff - ks.ay_noise) * o.fmin(g.dt / nz.accel_noise_tau, 1.0)
    sd = o.sqrt(o.fmax(noise, 0.0))
    share = o.fmin(o.fmax((sd - nz.accel_noise_on) / (nz.accel_noise_full - nz.accel_noise_on), 0.0), 1.0)
    alpha = low_pass_alpha(d, g.dt)
    lp = {"ay_last": ay, "ay_noise": noise}
    lp["ay_lp1"] = ks.ay_lp1 + alpha * (ay - ks.ay_lp1)
    lp["ay_lp"] = ks.ay_lp + alpha * (lp["ay_lp1"] - ks.ay_lp)
    departure = ay - a_model
    lp["dep_lp1"] = ks.dep_lp1 + alpha * (departure - ks.dep_lp1)
    lp["dep_lp"] = ks.dep_lp + alpha * (lp["dep_lp1"] - ks.dep_lp)
    rate = ay / v_m - (g.yaw_rate - x[d.index("gyro_bias")] if d.bias else g.yaw_rate)
    lp["rate_lp1"] = ks.rate_lp1 + alpha * (rate - ks.rate_lp1)
    lp["rate_lp"] = ks.rate_lp + alpha * (lp["rate_lp1"] - ks.rate_lp)
    return lp, share, ay + share * (lp["ay_lp"] - ay), departure + share * (lp["dep_lp"] - departure)
