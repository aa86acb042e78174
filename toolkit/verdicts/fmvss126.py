"""FMVSS 126 (GTR 8 / UN R13-H) electronic stability control test, as the regulation does it.

* Slowly increasing steer (SIS): 80 km/h, hand-wheel ramp at 13.5 deg/s, both
  directions; ``A`` is the hand-wheel angle giving 0.3 g, from a linear regression
  of the filtered lateral acceleration against hand-wheel angle over 0.1-0.375 g,
  averaged over the two directions.
* Sine with dwell: 0.7 Hz, 500 ms dwell from the second peak; amplitudes 1.5 A,
  2 A, 2.5 A, ... up to max(6.5 A, 270 deg), each capped at 300 deg; both directions;
  throttle released at steer start.
* Data processing: 12-pole phaseless Butterworth (6th order, forward-backward):
  10 Hz on the hand-wheel angle, 6 Hz on yaw rate and lateral acceleration;
  zeroing by the mean of the 0.5 s before the steer; BOS where the hand-wheel angle
  first reaches 5 deg; COS where it returns to zero after the dwell (linear
  interpolation).
* Criteria: yaw rate <= 35 % at COS + 1.0 s and <= 20 % at COS + 1.75 s of the
  first yaw-rate peak recorded after the hand-wheel angle changes sign (between
  its first and second peaks, i.e. the peak in the dwell's direction); for amplitudes >= 5 A, lateral displacement (double integral of the
  lateral acceleration from BOS) >= 1.83 m at BOS + 1.07 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal

from evstab.plants import G, VehicleParams
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import ramp_steer, sine_with_dwell

from ..loop.simulator import RolloverError, simulate, simulate_many
from evstab.plants.errors import DataError

SPEED = 80 / 3.6
"""[m/s] Both manoeuvres are driven at 80 km/h (S7.6, S7.9)."""
STEER_START = 3.0
"""[s] The sine with dwell begins this long after the run, and the ECU, start (as the envelope's step
steers, :data:`toolkit.verdicts.envelope.STEP_START`). The regulation's runs are driven with the stability
system on throughout, so its filter has settled before the steer: the kinematic sideslip path waits
``NoiseSettings.kinematic_settle`` (2 s) after the first GPS fix, and the gyro bias is learnt on the straight.
A steer 1 s after the ECU starts is a cold start, a different test: the filter's still unknown gyro bias then
takes up the wrong model's yaw-rate error (on the Escort with its +40 % file on mu 0.5, 3.7 deg/s within 0.35 s
of the steer)."""
YAW_RATIO_1_0_MAX = 35.0
"""[%] Yaw rate at COS + :data:`T_YAW_1_0` of the first peak, at most (S5.2.1)."""
YAW_RATIO_1_75_MAX = 20.0
"""[%] Yaw rate at COS + :data:`T_YAW_1_75` of the first peak, at most (S5.2.2)."""
T_YAW_1_0 = 1.0
"""[s] after COS, the first yaw-rate criterion's instant."""
T_YAW_1_75 = 1.75
"""[s] after COS, the second yaw-rate criterion's instant."""
LATERAL_DISPLACEMENT_MIN = 1.83
"""[m] at BOS + :data:`T_DISPLACEMENT`, for runs at :data:`DISPLACEMENT_FROM_A` x A and above
(vehicles up to 3,500 kg; S5.2.3)."""
T_DISPLACEMENT = 1.07
"""[s] after BOS, the lateral displacement's instant."""
DISPLACEMENT_FROM_A = 5.0
"""The displacement criterion applies to runs at this multiple of ``A`` and above."""
BOS_DEG = 5.0
"""[deg hand-wheel] BOS is where the filtered hand-wheel angle first reaches this (S7.11.6)."""
HANDWHEEL_FILTER_HZ = 10.0
"""[Hz] The 12-pole phaseless filter's cut-off on the hand-wheel angle (S7.11.3)."""
MOTION_FILTER_HZ = 6.0
"""[Hz] The same filter's cut-off on yaw rate and lateral acceleration (S7.11.3)."""
HANDWHEEL_RATE = np.deg2rad(13.5)
"""[rad/s hand-wheel] The slowly increasing steer's ramp (S7.6)."""
A_G = 0.3
"""``A`` is the hand-wheel angle for this lateral acceleration [g] (S7.6.1)."""
REGRESSION_FROM_G = 0.1
REGRESSION_TO_G = 0.375
"""[g] The window of the linear regression of lateral acceleration on hand-wheel angle (S7.6.1)."""
SIS_END_G = 0.55
SIS_END_FACTOR = 1.5
SIS_END_MAX_DEG = 270.0
"""The slowly increasing steer ends at :data:`SIS_END_FACTOR` x the hand-wheel angle the nominal linear
model needs for :data:`SIS_END_G` in steady state, and at most this [deg hand-wheel]
(:func:`sis_end_handwheel`)."""


def zero_phase(x: np.ndarray, fc: float, fs: float) -> np.ndarray:
    """12-pole phaseless Butterworth low-pass (6th order forward and backward)."""
    b, a = scipy.signal.butter(6, fc / (fs / 2.0))
    return scipy.signal.filtfilt(b, a, x)


@dataclass(frozen=True)
class SwdScore:
    bos: float
    cos: float
    yaw_peak: float
    """First yaw-rate peak after the hand-wheel changes sign, in the dwell's direction [rad/s]."""
    yaw_ratio_1_0: float
    """Yaw rate at COS + 1.0 s as percent of the first peak."""
    yaw_ratio_1_75: float
    lateral_displacement_m: float
    """Lateral displacement at BOS + 1.07 s in the direction of the first steer [m]."""

    def passes(self, amplitude_deg: float, a_deg: float) -> tuple[bool, list[str]]:
        failed = []
        if self.yaw_ratio_1_0 > YAW_RATIO_1_0_MAX:
            failed.append("yaw_ratio_1_0")
        if self.yaw_ratio_1_75 > YAW_RATIO_1_75_MAX:
            failed.append("yaw_ratio_1_75")
        if amplitude_deg >= DISPLACEMENT_FROM_A * a_deg - 1e-9 and self.lateral_displacement_m < LATERAL_DISPLACEMENT_MIN:
            failed.append("lateral_displacement")
        return not failed, failed


def _timing(t: np.ndarray, handwheel: np.ndarray):
    """What a sine-with-dwell run's scoring reads off the hand-wheel alone: the filtered hand-wheel less
    its pre-steer mean, the pre-steer window (mask or None), the first sample at 5 deg, the direction of
    the first steer and BOS."""
    fs = 1.0 / np.median(np.diff(t))
    hw = zero_phase(np.asarray(handwheel, float), HANDWHEEL_FILTER_HZ, fs)
    above = np.nonzero(np.abs(hw) >= np.deg2rad(BOS_DEG))[0]
    if len(above) == 0:
        raise DataError(f"no steer of {BOS_DEG:g} deg or more: not a sine-with-dwell run")
    k0 = above[0]
    pre = (t >= t[k0] - 0.5 - 0.25) & (t < t[k0] - 0.25)
    pre = pre if pre.sum() > 10 else None
    if pre is not None:
        hw = hw - hw[pre].mean()
    k0 = np.nonzero(np.abs(hw) >= np.deg2rad(BOS_DEG))[0][0]
    s = np.sign(hw[k0])
    bos = float(np.interp(np.deg2rad(BOS_DEG), [s * hw[k0 - 1], s * hw[k0]], [t[k0 - 1], t[k0]]))
    return fs, hw, pre, k0, s, bos


def displacement_map(t: np.ndarray, handwheel: np.ndarray):
    """The lateral displacement at BOS + 1.07 s in the direction of the first steer [m] as
    :func:`score_swd` computes it, as a function of the lateral acceleration [m/s^2] alone: the
    timing comes from the hand-wheel, so the function is linear in the acceleration (the design
    job's tuning applies it to the acceleration's derivatives too)."""
    t = np.asarray(t, float)
    return _displacement(t, *_timing(t, handwheel))


def _displacement(t: np.ndarray, fs, _hw, pre, _k0, s, bos):
    """:func:`displacement_map` from the run's timing (:func:`_timing`)."""
    sel = t >= bos
    ts = t[sel]

    def displacement(ay: np.ndarray) -> float:
        a = zero_phase(np.asarray(ay, float), MOTION_FILTER_HZ, fs)
        if pre is not None:
            a = a - a[pre].mean()
        a = a[sel]
        vel = np.concatenate([[0.0], np.cumsum(0.5 * (a[1:] + a[:-1]) * np.diff(ts))])
        disp = np.concatenate([[0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(ts))])
        return float(s * np.interp(bos + T_DISPLACEMENT, ts, disp))
    return displacement


def score_swd(t: np.ndarray, handwheel: np.ndarray, yaw_rate: np.ndarray, ay: np.ndarray) -> SwdScore:
    """Score one sine-with-dwell run (hand-wheel angle [rad], yaw rate [rad/s], lateral acceleration [m/s^2])."""
    t = np.asarray(t, float)
    timing = _timing(t, handwheel)
    fs, hw, pre, k0, s, bos = timing
    r = zero_phase(np.asarray(yaw_rate, float), MOTION_FILTER_HZ, fs)
    if pre is not None:
        r = r - r[pre].mean()
    k_min = k0 + int(np.argmin(s * hw[k0:]))  # the dwell
    after = np.nonzero(s * hw[k_min:] >= 0.0)[0]
    if len(after):
        j = k_min + after[0]
        cos = float(np.interp(0.0, [s * hw[j - 1], s * hw[j]], [t[j - 1], t[j]]))
    else:
        cos = float(t[k_min + int(np.argmin(np.abs(hw[k_min:])))])
    # the hand-wheel changes sign between its first and second peaks; the yaw-rate peak
    # that counts is the first one after that, in the dwell's direction (-s)
    k_first = k0 + int(np.argmax(s * hw[k0:k_min]))
    k_sign = k_first + int(np.argmax(s * hw[k_first:k_min] < 0.0))
    win = (t >= t[k_sign]) & (t <= cos + T_YAW_1_75)
    peak = float(np.max(-s * r[win]))
    ratio = (lambda tt: float(100.0 * (-s) * np.interp(tt, t, r) / peak))
    lat = _displacement(t, *timing)(ay)
    return SwdScore(bos, cos, peak, ratio(cos + T_YAW_1_0), ratio(cos + T_YAW_1_75), lat)


AMPLITUDE_FIRST_A = 1.5
"""The series starts at this multiple of ``A`` (S7.9.4) ..."""
AMPLITUDE_STEP_A = 0.5
"""... and grows by this multiple of ``A`` per run pair ..."""
AMPLITUDE_LAST_A = 6.5
AMPLITUDE_LAST_DEG = 270.0
"""... up to the larger of :data:`AMPLITUDE_LAST_A` x A and this [deg hand-wheel] ..."""
AMPLITUDE_CAP_DEG = 300.0
"""... each run at most this [deg hand-wheel]."""


def amplitudes(a_deg: float) -> list[float]:
    """1.5 A, 2 A, ... up to max(6.5 A, 270 deg); each capped at 300 deg [deg]."""
    top = max(AMPLITUDE_LAST_A * a_deg, AMPLITUDE_LAST_DEG)
    out, k = [], AMPLITUDE_FIRST_A
    while k * a_deg <= top + 1e-9:
        out.append(min(k * a_deg, AMPLITUDE_CAP_DEG))
        k += AMPLITUDE_STEP_A
    return sorted(set(out))


def sis_end_handwheel(p: VehicleParams) -> float:
    """Where the slowly increasing steer stops [rad hand-wheel]: the regulation steers "until a lateral
    acceleration of approximately 0.5 g is obtained" (S7.6). The ramp is open loop, so it ends at 1.5x
    the hand-wheel angle the nominal linear model needs for 0.55 g in steady state (2.2x its 0.375 g,
    the top of the regression window), and at most 270 deg."""
    ay = SIS_END_G * G
    delta = (p.wheelbase / SPEED ** 2 + p.understeer_gradient) * ay
    return float(min(np.deg2rad(SIS_END_MAX_DEG), SIS_END_FACTOR * delta * p.steering_ratio))


def a_from_ramp(handwheel: np.ndarray, ay: np.ndarray) -> float:
    """``A`` [deg hand-wheel] from one slowly increasing steer: the hand-wheel angle [rad] and lateral
    acceleration [m/s^2], both filtered and steered in the positive direction. The regression line
    of the acceleration on the hand-wheel angle through the samples between :data:`REGRESSION_FROM_G` and
    :data:`REGRESSION_TO_G` (up to where the acceleration first reaches the window's top), evaluated at :data:`A_G`."""
    hw, ay = np.asarray(handwheel, float), np.asarray(ay, float)
    lo, hi = REGRESSION_FROM_G * G, REGRESSION_TO_G * G
    sel = (ay >= lo) & (ay <= hi)
    k_end = np.argmax(ay >= hi) if np.any(ay >= hi) else len(ay)
    sel[k_end:] = False
    if sel.sum() < 10:
        raise DataError(f"the slowly increasing steer never reached {REGRESSION_TO_G:g} g")
    slope, icpt = np.polyfit(hw[sel], ay[sel], 1)
    return float(np.degrees((A_G * G - icpt) / slope))


def sis_maneuver(p: VehicleParams, direction: float = 1.0):
    """The slowly increasing steer in ``direction`` (+1 left, -1 right): from 1 s, the road-wheel
    angle of a hand-wheel turning at :data:`HANDWHEEL_RATE`, at :data:`SPEED`, up to
    :func:`sis_end_handwheel`."""
    end = sis_end_handwheel(p)
    return ramp_steer(SPEED, direction * HANDWHEEL_RATE / p.steering_ratio, start=1.0,
                      duration=1.0 + end / HANDWHEEL_RATE)


def find_a(p: VehicleParams, plant: str = "two-track", mu: float | None = None, controller=None,
           estimator: str = "dakf", seed: int = 0) -> float:
    """``A`` [deg hand-wheel] from the slowly increasing steer (:func:`a_from_ramp`), averaged over
    both directions."""
    p.require("steering_ratio", model="FMVSS 126")
    mu = p.mu if mu is None else mu
    vals = []
    for direction in (1.0, -1.0):
        man = sis_maneuver(p, direction)
        r = simulate(p, plant, man, disturbances=Disturbances(friction=Friction(mu=mu)), seed=seed,
                     controller=controller, estimator=estimator)
        fs = 1.0 / r.meta["dt"]
        ay = direction * zero_phase(r.truth["ay"], MOTION_FILTER_HZ, fs)
        hw = direction * zero_phase(r.commands.get("steer_driver", r.commands["steer"]) * p.steering_ratio,
                                    HANDWHEEL_FILTER_HZ, fs)
        try:
            vals.append(a_from_ramp(hw, ay))
        except DataError as exc:
            raise DataError(f"{p.name}: {exc} on mu = {mu}") from None
    return float(np.mean(vals))


def series_maneuver(p: VehicleParams, amplitude_deg: float):
    """The series' sine with dwell of hand-wheel amplitude ``amplitude_deg`` [deg] (+ steers left first) for
    ``p``: at :data:`SPEED`, the steer :data:`STEER_START` s after the run, and the ECU, start."""
    return sine_with_dwell(SPEED, np.deg2rad(amplitude_deg) / p.steering_ratio, start=STEER_START)


def run_series(p: VehicleParams, controller="none", estimator: str = "dakf", mu: float | None = None,
               plant: str = "two-track", seed: int = 0, a_deg: float | None = None, quick: bool = False,
               design=None, compiled: bool = True):
    """The FMVSS 126 sine-with-dwell series at 80 km/h.

    Parameters
    ----------
    p : VehicleParams
        The vehicle (needs ``steering_ratio``); on a ``commonroad-mb`` plant, what the ECU believes.
    controller : str
        ``none`` (the car alone), ``yaw-pi``, ``two-dof`` or ``two-dof-true``, run in the stability
        loop (:func:`toolkit.loop.closed_loop.loop_step`).
    estimator : str or FilterDesign
        The ECU's filter (``dakf`` default).
    mu : float, optional
        Road friction [-]; default the vehicle's. The ECU is not told it.
    plant : str
        ``two-track`` (default), ``bicycle``, ``bicycle-roll`` or ``commonroad-mb:N``.
    seed : int
        Seeds the sensor noise.
    a_deg : float, optional
        ``A`` [deg hand-wheel]; default from the slowly increasing steer (:func:`find_a`).
    quick : bool
        Only the first two amplitudes at or above 5 A.
    design : TwoDofDesign or EcuDesign, optional
        The controller design (default the paper's gains for ``p``) or a design folder's ECU.
    compiled : bool
        One compiled rollout per run (False: the numpy evaluation of the same step).

    Returns
    -------
    a_deg : float
        ``A`` [deg hand-wheel].
    rows : list of dict
        One per run: amplitude [deg hand-wheel], direction, yaw-rate ratios [%] at COS + 1.0 and
        1.75 s, lateral displacement [m], pass, failed criteria, rollover time [s] (NaN: none).
    verdict : dict
        ``pass`` and the failed criteria over the series, with what was run.
    """
    mu = p.mu if mu is None else mu
    a_deg = find_a(p, plant, mu, seed=seed) if a_deg is None else a_deg
    amps = amplitudes(a_deg)
    if quick:
        amps = [x for x in amps if x >= DISPLACEMENT_FROM_A * a_deg - 1e-9][:2]
    rows, failed_all = [], set()
    runs = [(amp, direction, label, series_maneuver(p, direction * amp))
            for amp in amps for direction, label in ((1.0, "left"), (-1.0, "right"))]
    dist = Disturbances(friction=Friction(mu=mu))
    if compiled and controller != "none":  # the whole series through the compiled loop in one call
        results = simulate_many(p, plant, [r[3] for r in runs], disturbances=dist, seed=seed, controller=controller,
                                estimator=estimator, design=design)
    else:
        results = []
        for *_, man in runs:
            try:
                results.append(simulate(p, plant, man, disturbances=dist, seed=seed, compile=compiled,
                                        controller=None if controller == "none" else controller,
                                        estimator=estimator, design=design))
            except RolloverError as exc:
                results.append(exc)
    for (amp, direction, label, man), r in zip(runs, results):
        if isinstance(r, RolloverError):  # fails the run: no criterion can be read off a car on its roof
            failed_all.add("rollover")
            nan = float("nan")
            rows.append({"amplitude_deg": amp, "direction": label, "yaw_ratio_1_0": nan, "yaw_ratio_1_75": nan,
                         "lateral_displacement_m": nan, "pass": False, "failed": "rollover", "rollover_s": r.t})
            continue
        if isinstance(r, Exception):
            raise r
        hw = man.steer(np.arange(int(round(man.duration / 1e-3))) * 1e-3) * p.steering_ratio
        t, yaw_rate, ay = r.t, r.truth["yaw_rate"], r.truth["ay"]
        sc = score_swd(t, hw[:len(t)], yaw_rate, ay)
        ok, failed = sc.passes(amp, a_deg)
        failed_all.update(failed)
        rows.append({"amplitude_deg": amp, "direction": label, "yaw_ratio_1_0": sc.yaw_ratio_1_0,
                     "yaw_ratio_1_75": sc.yaw_ratio_1_75, "lateral_displacement_m": sc.lateral_displacement_m,
                     "pass": ok, "failed": " ".join(failed), "rollover_s": float("nan")})
    verdict = {"pass": not failed_all, "failed_criteria": sorted(failed_all), "A_deg": a_deg, "mu": mu,
               "controller": controller,
               "estimator": estimator, "vehicle": p.name, "speed_kmh": SPEED * 3.6}
    if controller == "two-dof":
        from evstab.controllers.two_dof import TwoDofDesign
        d = design if design is not None else TwoDofDesign(p.as_nominal())
        d = getattr(d, "controller", d)  # an EcuDesign's controller
        verdict["design"] = {k: getattr(d, k) for k in ("k_beta", "k_gamma", "yaw_priority", "reference_tau",
                                                        "friction_margin", "disturbance_filter_tau")}
    return a_deg, rows, verdict
