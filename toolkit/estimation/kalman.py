"""The multi-rate Kalman filter step, written once for numpy and casadi.

One call advances one IMU sample:

1. rediscretise the model at the current speed with a 4th-order Taylor series of
   ``e^(A dt)`` (no matrix exponential per step; truncation error below 1e-9 for
   ``|A| dt < 0.05``, i.e. above ~1 m/s at 1 kHz) and predict;
2. gyro update every sample (scalar, Joseph form);
3. zero-yaw-rate pseudo-measurement at standstill (wheels at rest and the gyro quiet; designs
   that have it);
4. course update when a usable fix is present (>= 4 satellites, speed above
   ``gps_min_speed``): innovation wrapped to (-pi, pi], noise from HDOP and 1/speed
   (or constant), chi-square gate, optional latency compensation (the fix is compared
   with the course predicted ``latency`` s earlier); the first usable fix initialises
   the heading, and so does a fix after ``max_rejects`` gated ones in a row (the heading
   was lost: a spin, a stuck gyro; see below);
   with a gyro-bias state, a two-sided CUSUM on the normalised innovations of accepted
   fixes watches for a gyro bias step and, when it alarms, reopens the bias variance;
5. seed 004's inter-sample residual prediction between fixes (``amrkf``).

Sensor faults: the optional 11th input ``gyro_ok`` (default 1) gates the gyro update
(0 while a monitor has found the gyro stuck: the yaw rate then comes from the model
and the course fixes). Why a re-lock initialises the heading instead of accepting the
fix: ``max_rejects`` consecutive fixes far outside their expected spread mean the
heading estimate is lost (sideslip is physically bounded, heading is not); an ordinary
update would hand part of a possibly huge innovation to the sideslip and the
disturbances, and the sideslip-heading split is only slowly observable (the soak found
this: sideslip errors of 40-50 deg for a minute after a spin).

The filter state is one flat vector (``x``, ``P`` column-major, counters, the
residual-prediction memory, the latency buffer) so the same step runs in a numpy
loop or inside a compiled casadi ``mapaccum``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from evstab.plants.backend import CASADI, NUMPY
from evstab.plants.errors import ModelError
from evstab.plants.signals import Layout, Signal
from . import kinematic_path as kpath
from .core import column as _col, diag as _diag, dot as _dot, predict_delta, scalar_update
from .spec import LATERAL_STATES, FilterDesign, continuous_model, gyro_row, process_noise_diag

INPUTS = Layout("filter inputs", [
    Signal("dt", "s", "time since the previous sample"),
    Signal("speed", "m/s", "vehicle speed from the non-driven wheels"),
    Signal("steer", "rad", "front road-wheel angle, + left"),
    Signal("yaw_moment", "N m", "direct yaw moment applied, + turns left"),
    Signal("yaw_rate", "rad/s", "gyro yaw rate"),
    Signal("fix", "-", "1 on a sample with a new GPS fix"),
    Signal("course", "rad", "GPS course over ground (read only where fix = 1)"),
    Signal("hdop", "-", "horizontal dilution of precision of the fix"),
    Signal("sats", "-", "satellites used in the fix"),
    Signal("ay", "m/s^2", "lateral acceleration, + left"),
    Signal("gyro_ok", "-", "0 while a monitor has found the gyro stuck (absent: always 1)", optional=True),
    Signal("ax", "m/s^2", "longitudinal acceleration", optional=True),
    Signal("gps_speed", "m/s", "GPS ground speed", optional=True),
    Signal("heading", "rad", "dual-antenna GPS heading", optional=True),
    Signal("heading_valid", "-", "1 where the heading is measured", optional=True),
    Signal("roll_rate", "rad/s", "roll gyro", optional=True),
    Signal("gps_roll", "rad", "total roll from a third antenna", optional=True),
    Signal("gps_roll_valid", "-", "1 where gps_roll is measured", optional=True),
    Signal("ay_ok", "-", "0 where the log has no lateral acceleration (absent: 1)", optional=True),
    Signal("roll_rate_ok", "-", "1 where roll_rate is measured (absent: 0)", optional=True),
])
"""The Kalman step reads the first 11 (``gyro_ok`` optional); the rest feed other methods (``two-stage``)."""
OUTPUTS = Layout("filter outputs", [
    Signal("beta", "rad", "sideslip at the CG"),
    Signal("yaw_rate", "rad/s", "yaw rate"),
    Signal("yaw", "rad", "yaw angle, wrapped to (-pi, pi]"),
    Signal("beta_std", "rad", "standard deviation of the sideslip estimate"),
    Signal("d1", "rad/s", "disturbance on the sideslip equation"),
    Signal("d2", "rad/s^2", "disturbance on the yaw-rate equation"),
    Signal("gyro_bias", "rad/s", "gyro bias"),
    Signal("gps_used", "-", "1 when this sample's fix was used"),
    Signal("nis", "-", "normalised innovation squared of the course fix"),
    Signal("bias_alarm", "-", "1 when the gyro-bias CUSUM alarmed"),
    Signal("course_resid", "-", "course innovation over its predicted standard deviation"),
    Signal("gyro_resid", "rad/s", "gyro innovation before its update"),
    Signal("gyro_var", "rad^2/s^2", "its predicted variance (h P h^T + r)"),
    Signal("course_var", "rad^2", "the course innovation's predicted variance (NaN without a usable fix)"),
    Signal("noise_scale", "-", "the process noise's innovation-adaptive scale (1 where the model holds; at its "
           "bound, the model is wrong)"),
    Signal("vx", "m/s", "body longitudinal velocity"),
    Signal("vy", "m/s", "body lateral velocity"),
    Signal("roll", "rad", "roll angle"),
])
"""Entries a method does not estimate are NaN. ``course_resid``: NaN without a usable fix;
``gyro_resid``: seed 001's second residual (for :mod:`toolkit.estimation.diagnostics`)."""


def outputs(o, like, **values):
    """The output vector of a filter step: ``values`` by name, NaN for the entries not given."""
    return OUTPUTS.pack(values, o, like=like, fill=float("nan"))


INIT_MAX = 60.0
"""Cap of the filter state's ``init`` entry (1 + seconds since the first fix)."""


def watches_bias(d: FilterDesign) -> bool:
    """Whether the design runs the gyro-bias-step CUSUM (a bias state and gated fixes)."""
    return bool(d.bias and d.gating)


def layout(d: FilterDesign) -> Layout:
    """The parts of the flat filter state."""
    return _layout(d.states, watches_bias(d), d.latency_samples, kpath.kinematic_layout(d).size if d.kinematic else 0,
                   adapts(d), weighs_prediction(d))


def weighs_prediction(d: FilterDesign) -> bool:
    """Whether the design weighs its inter-sample residual prediction by the fixes' innovation
    correlation (``amrkf``; ``NoiseSettings.residual_corr_fixes`` 0 is the printed, unweighted method)."""
    return bool(d.residual_prediction and d.noise.residual_corr_fixes > 0)


def adapts(d: FilterDesign) -> bool:
    """Whether the design scales its process noise by the course innovations (``NoiseSettings.adapt_rate``)."""
    return bool(d.noise.adapt_rate > 0 and d.hdop_noise)


@lru_cache(maxsize=64)
def _layout(states: tuple[str, ...], cusum: bool, nb: int, kinematic: int, adaptive: bool,
            weighs: bool) -> Layout:
    n = len(states)
    return Layout("filter state", [
        Signal("x", "-", f"the state ({', '.join(states)})", n),
        Signal("P", "-", "its covariance, column-major", n * n),
        Signal("rejects", "-", "gated fixes in a row"),
        Signal("eps", "rad", "the last course innovation (inter-sample residual prediction)"),
        Signal("init", "s", "0 until the heading is initialised by a fix, then 1 + the seconds since (at most INIT_MAX)"),
        Signal("gain", "-", "the gain of the last accepted fix", n),
        Signal("cusum", "-", "the gyro-bias CUSUM sums", 2 if cusum else 0),
        Signal("buf", "rad", "the predicted course of the last samples (latency)", nb),
        Signal("kin", "-", "the kinematic path's state (kinematic_path.KINEMATIC or KINEMATIC_LP)", kinematic),
        Signal("qscale", "-", "the process noise's innovation-adaptive scale", 1 if adaptive else 0),
        Signal("rcor", "-", "the accepted fixes' normalised innovations: the last, and the running means of "
                            "its products with the one before and of its square (residual prediction)",
               3 if weighs else 0),
    ])


def initial_state(d: FilterDesign, yaw0: float = 0.0, yaw_rate0: float = 0.0, bias=None) -> np.ndarray:
    """The filter state a run starts from; ``bias``: ``(value, std)`` [rad/s] of the gyro bias as a calibration
    gives it (a design with a bias state), instead of 0 and the design's initial spread."""
    lay = layout(d)
    z = lay.zeros()
    x = np.zeros(d.n)
    x[d.index("yaw")] = yaw0
    x[d.index("yaw_rate")] = yaw_rate0
    P = d.initial_covariance()
    if bias is not None:
        if not d.bias:
            raise ModelError(f"'{d.method}' has no gyro-bias state to start from a calibration")
        ib = d.index("gyro_bias")
        x[ib], P[ib, ib] = float(bias[0]), float(bias[1]) ** 2
    z[lay.slot("x")] = x
    z[lay.slot("P")] = P.ravel(order="F")
    z[lay.slot("buf")] = yaw0
    z[lay.slot("qscale")] = 1.0
    if weighs_prediction(d):
        z[lay.slot("rcor")] = (0.0, 0.0, 1.0)  # white innovations of unit variance
    return z


def discretize(A, dt, o, n):
    """``F = e^(A dt)`` and ``Gam = int_0^dt e^(A s) ds`` by 4th-order Taylor series."""
    E, Gam = discretize_delta(A, dt, o, n)
    return o.eye(n) + E, Gam


def discretize_delta(A, dt, o, n):
    """``E = F - I`` (without forming ``I + ...``) and ``Gam``.

    The filter propagates with ``E``: at 1 kHz ``F``'s diagonal is ``1 - O(1e-3)``, and
    storing it rounds away the small part's low digits (in float32 firmware, most of
    them); ``x + E x`` and ``P + E P + P E^T + E P E^T`` keep them.
    """
    M = A * dt
    M2 = M @ M
    M3 = M2 @ M
    M4 = M3 @ M
    E = M + M2 * 0.5 + M3 * (1.0 / 6.0) + M4 * (1.0 / 24.0)  # products, not divisions, in the generated code
    Gam = (o.eye(n) + M * 0.5 + M2 * (1.0 / 6.0) + M3 * (1.0 / 24.0) + M4 * (1.0 / 120.0)) * dt
    return E, Gam


def transition_matrix(d: FilterDesign, v: float, dt: float) -> np.ndarray:
    """``F`` the filter propagates with at speed ``v`` over ``dt`` (numbers, for the analyses): the
    design's transition table (:mod:`toolkit.estimation.transition`) as :func:`step` reads it, or
    the Taylor series of the model at ``v``."""
    if d.transition is not None:
        nz = d.noise
        E, _ = d.transition.matrices(max(v, nz.min_speed), dt, 1.0 if v >= nz.min_speed else 0.0)
        return np.eye(d.n) + E
    A, _ = continuous_model(d, v, NUMPY)
    return discretize(A, dt, NUMPY, d.n)[0]


def wrap(a, o):
    return o.arctan2(o.sin(a), o.cos(a))


def step(d: FilterDesign, z, u, o=NUMPY, with_course: bool = True, moving: bool = False):
    """One sample of the filter: ``(z, u) -> (z_next, y)`` with ``u`` per :data:`INPUTS`.

    ``with_course=False`` leaves out the course-update code; it gives exactly the
    result of the full step on a sample without a fix (``u[5] = 0``), so callers may
    use it there to save the work (the compiled runner switches between the two).

    ``moving=True`` leaves out the standstill update: exact when the speed input is at least
    ``standstill_speed`` (the update's gate is 0 then, and a zero gate leaves ``x`` and ``P`` as they
    were), so the exported C calls that variant there.
    """
    n, lay, nz = d.n, layout(d), d.noise
    zs = lay.unpack(z)
    x = zs.x
    P = o.reshape(zs.P, n, n)
    rejects, eps, init, gain = zs.rejects, zs.eps, zs.init, zs.gain
    g = INPUTS.unpack(u)
    dt, v, steer, nzm, gyro, fix, course, hdop, sats = g.dt, g.speed, g.steer, g.yaw_moment, g.yaw_rate, g.fix, \
        g.course, g.hdop, g.sats
    gyro_ok = g.gyro_ok  # None: always working (callers without the entry)
    ib, ir, iy = d.index("beta"), d.index("yaw_rate"), d.index("yaw")

    # 1. predict with the model rediscretised at this speed
    dyn = v >= nz.min_speed
    v_m = o.fmax(v, nz.min_speed)
    tr = d.transition
    tabulated = tr is not None
    if tr is not None:  # the ECU: the model discretised at export on the schedule's grid (toolkit.estimation.transition)
        if d.steer_noise:
            raise ModelError(f"'{d.method}': a tabulated transition has no steer noise")
        rows = tr.table.values(v_m, o)
        E, Gu = tr.matrices(v_m, dt, dyn, o, rows=rows)
    else:
        A, B = continuous_model(d, v_m, o, dynamic=dyn)
    uin = o.stack([steer, nzm])
    q = _col(process_noise_diag(d, symbolic=o is CASADI), o)
    if adapts(d):
        scaled = np.array([1.0 if s in LATERAL_STATES else 0.0 for s in d.states])
        q = q * (_col(1.0 - scaled, o) + _col(scaled, o) * zs.qscale)
    if nz.q_yaw_rate_held > 0:
        # the lateral model held: nothing but the gyro says how the yaw rate moves (a spin on the spot
        # goes to the yaw rate, not the bias)
        e_r = np.eye(n)[ir]
        q = q + _col(e_r, o) * ((1.0 - dyn) * o.fmax(nz.q_yaw_rate_held - q[ir], 0.0))
    # the yaw row's model error grows with the lateral acceleration, here v r, and with the road-wheel angle
    # (NoiseSettings.yaw_model_ay, yaw_model_steer): each multiplies its noise by 1 + (its measure / its scale)^4
    for scale, measure in ((nz.yaw_model_ay, v_m * o.fabs(x[ir])), (nz.yaw_model_steer, o.fabs(steer))):
        if scale > 0:
            q = q + _col(np.eye(n)[ir], o) * (q[ir] * _fourth(measure * (1.0 / scale)))
    kin = None
    if d.kinematic:
        # not while the estimate settles after the first fix (a departure then is not the tyres)
        settled = dyn * (init > 1.0 + nz.kinematic_settle)
        if tr is not None:
            a_c, b_c = tr.continuous(rows, dyn, o)
            w_kin, q, kin, kin_state, lagged = kpath.weight(
                d, [a_c.get((ib, j), 0.0) for j in range(n)], [b_c.get((ib, k), 0.0) for k in (0, 1)], q, x, uin,
                g, v_m, settled, zs.kin, o)
            E, Gu = kpath.transition(d, E, Gu, w_kin, dt, o, lagged, kpath.yaw_weight(d, w_kin, kin_state))
        else:
            A, B, q, kin, kin_state = kpath.blend(d, A, B, q, x, uin, g, v_m, settled, zs.kin, o)
    if not tabulated:
        E, Gam = discretize_delta(A, dt, o, n)
    if d.disturbance is not None:
        excite = nz.excitation_floor + o.fabs(gyro) / nz.excitation_rate
        mask = np.zeros(n)
        for s in ("d1", "d2"):
            mask[d.index(s)] = 1.0
        q = q * (_col(1.0 - mask, o) + _col(mask, o) * excite)
    if tabulated:
        w = Gu @ uin if kin is None else Gu @ uin + kin * dt  # the kinematic drive to first order
    else:
        w = Gam @ (B @ uin if kin is None else B @ uin + kin)
    x, P = predict_delta(x, P, E, _diag(q * dt, o), o, n, w=w)
    if d.steer_noise:  # seed 001: process noise enters through the steer input, Q_d ~ b q b^T dt
        b_st = B[:, 0]
        P = P + (b_st @ b_st.T if o is CASADI else np.outer(b_st, b_st)) * (nz.q_steer * dt)

    # 2. gyro, every sample
    learn = _bias_learning(d, x, P, gyro, o)
    hg = _col(gyro_row(d), o)
    gyro_resid = gyro - _dot(hg, x, o)
    x, P, gyro_var, _ = scalar_update(x, P, hg, gyro_resid, nz.gyro_std**2, o, n, gate=gyro_ok,
                                      scale=_settling_bias(d, x, v_m, init, learn, o))

    # 3. standstill: the yaw rate is zero
    if d.standstill_update and not moving:
        hs = _col(np.eye(n)[ir], o)
        # 0/1 (comparisons: see continuous_model on if_else); wheels at rest and the gyro quiet
        rate = gyro - x[d.index("gyro_bias")] if d.bias else gyro
        quiet = o.fabs(rate) < nz.standstill_rate_max
        if gyro_ok is not None:  # without a working gyro the wheels alone say the car stands
            quiet = gyro_ok * quiet + (1.0 - gyro_ok)
        still = (v < nz.standstill_speed) * quiet
        x, P, _, _ = scalar_update(x, P, hs, 0.0 - x[ir], nz.standstill_std**2, o, n, gate=still)

    # 4. course fix
    hc = o.zeros(n)
    hc[ib] = 1.0
    hc[iy] = 1.0
    if d.antenna_x:
        hc[ir] = d.antenna_x / v_m
    pred_now = _dot(hc, x, o)
    nb = d.latency_samples
    if nb > 0:
        buf = zs.buf
        pred = buf[nb - 1]
    else:
        pred = pred_now
    innov = wrap(course - pred, o)
    if d.hdop_noise:
        sd = o.fmax(nz.gps_velocity_std * hdop / o.fmax(v, nz.gps_min_speed), nz.course_std_min)
        r_c = sd * sd
    else:
        r_c = nz.course_std**2
    if with_course:
        xc, Pc, S, K = scalar_update(x, P, hc, innov, r_c, o, n, scale=learn)
        nis = innov * innov / S
        resid = innov / o.sqrt(S)
        usable = (fix > 0.5) * (sats >= 4) * (v >= nz.gps_min_speed)
        if d.gating:
            inside = nis < nz.gate
            accept = usable * inside
            # max_rejects gated fixes in a row and this one gated too: the heading is lost, re-lock
            relock = usable * (1.0 - inside) * (rejects >= nz.max_rejects)
            rejects = o.if_else(accept + relock > 0.5, 0.0, o.if_else(usable > 0.5, rejects + 1.0, rejects))
        else:
            accept, relock = usable, 0.0
        acc = accept > 0.5
        # the first usable fix initialises the heading: yaw takes the whole innovation, its
        # variance becomes the fix's (no part of a possibly huge heading error reaches beta);
        # a re-lock does the same
        first = o.fmax((usable > 0.5) * (init < 0.5), relock)
        ey = _col(np.eye(n)[iy], o)
        x_first = x + ey * innov
        keep = _col(1.0 - np.eye(n)[iy], o)
        P_first = P * o.outer(keep, keep) + o.outer(ey, ey) * r_c
        x, P = o.if_else(acc, xc, x), o.if_else(acc, Pc, P)
        x, P = o.if_else(first > 0.5, x_first, x), o.if_else(first > 0.5, P_first, P)
        if watches_bias(d):
            calm = (o.fabs(gyro - x[d.index("gyro_bias")]) < nz.bias_cusum_rate_max) * \
                (o.fabs(g.ay) < nz.bias_cusum_ay_max)
            P, cusum, alarm = _bias_watch(d, zs.cusum, resid, accept * calm, relock, P, o)
        init = o.fmax(init, usable)
        if adapts(d):
            qscale = _adapt(d, zs.qscale, nis, accept * (init > 1.0 + nz.adapt_settle), o)

    else:  # no fix on this sample: nothing of the course update happens
        acc, first, usable = False, 0.0 * v, 0.0 * v
        accept, nis, K, S = 0.0 * v, 0.0 * v, gain, 0.0 * v
        resid = 0.0 * v
        if adapts(d):
            qscale = zs.qscale
        if watches_bias(d):
            cusum, alarm = zs.cusum, 0.0 * v

    extra = {}
    # 5. inter-sample residual prediction (seed 004 eq. 28-29) between fixes
    if d.residual_prediction:
        # q = h A_d (I - L h) h^+ with the gain of the last fix; h^+ = h^T / (h h^T)
        r_ = hc / _dot(hc, hc, o) - gain
        qd = _dot(hc, r_ + E @ r_, o)
        eps_next = o.if_else(acc, innov, qd * eps)
        gain_next = o.if_else(acc, K, gain)
        weight = 1.0  # seed 004 as printed
        if weighs_prediction(d):
            extra["rcor"] = _residual_correlation(d, zs.rcor, resid, accept, o)
            # the corrections between two fixes add up to the weight times the last fix's own (a geometric
            # series of qd ~ 1 - hK: the paper's, unweighted, add up to (1 - hK) / (hK) times it)
            hk = _dot(hc, gain, o)
            weight = _prediction_weight(d, extra["rcor"], o) * hk / o.fmax(1.0 - hk, 1e-3)
        x = o.if_else(acc, x, x + gain * (weight * qd * eps))
        eps, gain = eps_next, gain_next

    if "yaw" in d.states:
        # the heading kept within (-pi, pi]: a continuous angle loses float32's resolution as it grows (at
        # 600 rad, an hour in circles, its spacing is 6e-5 rad, a third of a 1 kHz step of 0.17 rad/s);
        # every use of it is a wrapped course innovation, so nothing else changes (one step moves it by
        # less than 2 pi, so one shift is enough)
        iy_ = d.index("yaw")
        yaw = x[iy_]
        yaw = o.if_else(yaw > np.pi, yaw - 2.0 * np.pi, o.if_else(yaw <= -np.pi, yaw + 2.0 * np.pi, yaw))
        x = o.concat([x[:iy_], o.stack([yaw]), x[iy_ + 1:]])  # the heading's element alone
    if nb > 0:
        buf_next = o.concat([pred_now, buf[0:nb - 1]]) if nb > 1 else o.stack([pred_now])
    if watches_bias(d):
        extra["cusum"] = cusum
    if nb > 0:
        extra["buf"] = buf_next
    if d.kinematic:
        extra["kin"] = kin_state
    if adapts(d):
        extra["qscale"] = qscale
    # init: 0 until the first usable fix, then 1 + the seconds since (capped)
    init = o.if_else(init > 0.5, o.fmin(init + dt, INIT_MAX), init)
    if gyro_ok is not None:  # a gyro found stuck restarts the settling (kinematic path, noise adaptation)
        init = o.if_else(init > 0.5, init * gyro_ok + (1.0 - gyro_ok), init)
    z_next = lay.pack(o=o, x=x, P=o.flatten(P), rejects=rejects, eps=eps, init=init, gain=gain, **extra)
    nan = float("nan")
    est: dict[str, object] = {s: x[d.index(s)] for s in ("d1", "d2", "gyro_bias") if s in d.states}
    if adapts(d):
        est["noise_scale"] = qscale
    beta = significant_sideslip(d, x, P, o) if conditions_sideslip(d) else x[ib]
    var_b = o.fmax(P[ib, ib], 0.0)
    if nz.beta_model_std > 0:
        # the linear model's own error in a turn, which the filter's covariance does not hold
        var_b = var_b + nz.beta_model_std * nz.beta_model_std * _fourth(v_m * o.fabs(x[ir]) * (1.0 / nz.beta_model_ay))
    if nz.beta_model_rel > 0:
        var_b = var_b + (nz.beta_model_rel * x[ib]) * (nz.beta_model_rel * x[ib])
    y = outputs(o, v, beta=beta, yaw_rate=x[ir], yaw=x[iy], beta_std=o.sqrt(var_b), **est,
                gps_used=o.fmax(accept, first), nis=o.if_else(usable > 0.5, nis, nan),
                bias_alarm=alarm if watches_bias(d) else 0.0 * v, course_resid=o.if_else(usable > 0.5, resid, nan),
                gyro_resid=gyro_resid, gyro_var=gyro_var, course_var=o.if_else(usable > 0.5, S, nan))
    return z_next, y


def _fourth(a):
    """``a^4`` as two products (no power in the generated code)."""
    return (a * a) * (a * a)


BIAS_UNKNOWN = 0.5
"""While the gyro bias's standard deviation is above this share of its initial spread (a cold start, a start in
a turn), it learns in full whatever the yaw rate: an unknown bias is then the largest error there is; it is
below it within seconds of the first straight (:func:`_bias_learning`)."""


def _bias_learning(d: FilterDesign, x, P, gyro, o):
    """The gain scale of this sample's gyro and course updates (``NoiseSettings.bias_learn_rate``): 1 on every
    state but the gyro bias, ``clip(2 - |gyro - bias| / bias_learn_rate, 0, 1)`` on the bias, or 1 there too
    while the bias is unknown (its standard deviation from its initial spread to :data:`BIAS_UNKNOWN` of it,
    linearly to the rate's factor); None where the bias always learns (no bias state, or the setting 0)."""
    if not (d.bias and d.noise.bias_learn_rate > 0):
        return None
    ib = d.index("gyro_bias")
    f = o.fmin(o.fmax(2.0 - o.fabs(gyro - x[ib]) / d.noise.bias_learn_rate, 0.0), 1.0)
    spread = float(np.sqrt(d.initial_covariance()[ib, ib]))
    unknown = o.fmin(o.fmax((o.sqrt(o.fmax(P[ib, ib], 0.0)) / spread - BIAS_UNKNOWN) / (1.0 - BIAS_UNKNOWN), 0.0), 1.0)
    return _bias_gain(d, o.fmax(f, unknown), o)


def _bias_gain(d: FilterDesign, f, o):
    """The gain scale that multiplies the gyro bias's gain by ``f`` and every other state's by 1."""
    e = np.eye(d.n)[d.index("gyro_bias")]
    return _col(1.0 - e, o) + _col(e, o) * f


def _settling_bias(d: FilterDesign, x, v_m, init, learn, o):
    """The gain scale of this sample's gyro update: ``learn`` (:func:`_bias_learning`) with the bias's entry 0
    while the heading settles (``init`` below ``1 + bias_settle_hold``: before the first fix and the seconds
    after it) in a turn (``v |r|`` above ``bias_settle_ay``), ``NoiseSettings.bias_settle_hold``; ``learn`` as
    it is where that is off."""
    nz = d.noise
    if not (d.bias and nz.bias_settle_hold > 0):
        return learn
    hold = (init < 1.0 + nz.bias_settle_hold) * (v_m * o.fabs(x[d.index("yaw_rate")]) > nz.bias_settle_ay)
    held = _bias_gain(d, 1.0 - hold, o)
    return held if learn is None else learn * held


def conditions_sideslip(d: FilterDesign) -> bool:
    """Whether the design's sideslip output is significance-weighted (:func:`significant_sideslip`)."""
    return bool(d.noise.disturbance_chi2_full > 0 and "d1" in d.states and "d2" in d.states)


def significant_sideslip(d: FilterDesign, x, P, o, chi2_on=None, chi2_full=None):
    """The sideslip output of a filter with disturbance states: the estimate conditioned on zero
    disturbances where the disturbance estimates are insignificant, the estimate itself where they are.

    Conditioning the Gaussian posterior on the pseudo-measurement ``d = 0`` gives
    ``beta_0 = beta - P_bd P_dd^-1 d``: what the filter would say of the sideslip if the linear model
    were exactly right, with everything it learnt from the measurements kept. Where the model is
    right the disturbance states hold only course noise, which ``beta_0`` drops; where it is wrong
    (tyres beyond their linear range, a wrong cornering stiffness) the disturbances are large against
    their spread, ``chi2 = d^T P_dd^-1 d`` grows, and the output returns to ``beta`` by a smoothstep
    of ``chi2`` between ``disturbance_chi2_on`` and ``disturbance_chi2_full``. The filter's recursion
    and its covariance are untouched (``beta_std`` stays the filter's, which bounds the conditioned
    estimate's spread too).

    ``chi2_on``, ``chi2_full``: the smoothstep's ends where they are not the design's (the ECU's telemetry
    output, :func:`telemetry_sideslip`: numbers or calibration symbols; a span below 1e-9 is taken as 1e-9,
    a step, so that no calibration makes the output non-finite)."""
    nz = d.noise
    if chi2_on is None:
        chi2_on, span = nz.disturbance_chi2_on, nz.disturbance_chi2_full - nz.disturbance_chi2_on
    else:
        span = o.fmax(chi2_full - chi2_on, 1e-9)
    ib, i1, i2 = d.index("beta"), d.index("d1"), d.index("d2")
    a, b, c = P[i1, i1], P[i1, i2], P[i2, i2]
    det = o.fmax(a * c - b * b, 1e-30)  # P_dd is positive definite; the floor (float32 has it) keeps a degenerate one finite
    d1, d2 = x[i1], x[i2]
    g1, g2 = (c * d1 - b * d2) / det, (a * d2 - b * d1) / det  # P_dd^-1 d
    chi2 = d1 * g1 + d2 * g2
    s = o.fmin(o.fmax((chi2 - chi2_on) / span, 0.0), 1.0)
    w = s * s * (3.0 - 2.0 * s)
    return x[ib] - (1.0 - w) * (P[ib, i1] * g1 + P[ib, i2] * g2)


def telemetry_sideslip(d: FilterDesign, z, chi2_on, chi2_full, o):
    """The sideslip of the filter state ``z`` (a step's ``z_next``) conditioned on zero disturbances while they
    are insignificant (:func:`significant_sideslip` with the smoothstep from ``chi2_on`` to ``chi2_full``);
    the estimate itself for a design without both disturbance states. The ECU's second sideslip output, for
    logs and telemetry: the law reads the filter's own estimate."""
    zs = layout(d).unpack(z)
    if not ("d1" in d.states and "d2" in d.states):
        return zs.x[d.index("beta")]
    return significant_sideslip(d, zs.x, o.reshape(zs.P, d.n, d.n), o, chi2_on, chi2_full)


def _residual_correlation(d: FilterDesign, rcor, nu, accept, o):
    """The next ``rcor`` (see :func:`layout`): at an accepted fix, the running means (over about
    ``residual_corr_fixes`` fixes) of ``nu nu_prev`` and ``nu^2`` move towards this fix's values, and
    ``nu`` becomes the last innovation; otherwise nothing changes."""
    a = accept * (1.0 / d.noise.residual_corr_fixes)
    last, cross, square = rcor[0], rcor[1], rcor[2]
    return o.stack([last + accept * (nu - last), cross + a * (nu * last - cross), square + a * (nu * nu - square)])


def _prediction_weight(d: FilterDesign, rcor, o):
    """The weight ``w`` of the inter-sample correction: 0 while the fixes' innovations are white (the filter
    has already used what they tell), rising linearly to 1 as their lag-one correlation
    ``rho = mean(nu nu_prev) / mean(nu^2)`` goes from ``residual_corr_min`` to 1 (the residual the
    next fix will show is predictable: a drift the model does not hold)."""
    nz = d.noise
    rho = rcor[1] / o.fmax(rcor[2], 1e-6)
    return o.fmin(o.fmax((rho - nz.residual_corr_min) / (1.0 - nz.residual_corr_min), 0.0), 1.0)


def _adapt(d: FilterDesign, qscale, nis, accept, o):
    """Covariance matching on one scale factor of the process noise: at every accepted fix
    ``log s <- log s + adapt_rate (min(NIS, adapt_nis_cap) - 1)``, ``s`` kept within
    ``[adapt_min, adapt_max]``. With a consistent filter the NIS averages 1 and the scale only
    wanders; innovations larger than predicted (a model error, a manoeuvre the model gets wrong)
    raise it within a few fixes, smaller ones lower it over tens of fixes."""
    nz = d.noise
    step = o.exp(nz.adapt_rate * accept * (o.fmin(nis, nz.adapt_nis_cap) - 1.0))
    return o.fmin(o.fmax(qscale * step, nz.adapt_min), nz.adapt_max)


def _bias_watch(d: FilterDesign, cusum, nu, accept, relock, P, o):
    """Two-sided CUSUM on the normalised innovations ``nu`` of accepted fixes (N(0, 1) while
    the model holds): ``g+ = max(0, g+ + nu - k)``, ``g- = max(0, g- - nu - k)``. A gyro bias
    step makes the heading drift one way between fixes, so the innovations keep one sign;
    when either sum passes ``h`` the bias variance is raised to at least its initial value
    (the filter relearns the bias in seconds instead of minutes; raising a diagonal entry
    keeps ``P`` positive definite) and both sums restart, as they do on a re-lock.
    Returns ``(P, cusum_next, alarm)``."""
    nz, n = d.noise, d.n
    k, h = nz.bias_cusum_k, nz.bias_cusum_h
    gp = o.fmax(cusum[0] + (nu - k) * accept, 0.0)
    gm = o.fmax(cusum[1] + (-nu - k) * accept, 0.0)
    alarm = o.fmax(gp > h, gm > h) * float(h > 0)
    ib = d.index("gyro_bias")
    eb = _col(np.eye(n)[ib], o)
    P = P + o.outer(eb, eb) * (alarm * o.fmax(float(d.initial_covariance()[ib, ib]) - P[ib, ib], 0.0))
    keep = (1.0 - alarm) * (1.0 - relock)
    cusum_next = o.stack([gp * keep, gm * keep])
    return P, cusum_next, alarm
