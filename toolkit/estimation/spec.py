"""Filter designs: which states, which noise, which features, per method.

A design is frozen configuration (scikit-learn style: construction stores, a
separate call computes). :func:`design_filter` returns a :class:`FilterDesign`
for a method name and a vehicle (the vehicle's *nominal* parameters, i.e. what a
designer would believe, are used: see :meth:`plants.VehicleParams.as_nominal`).

Methods
-------
The methods marked *as published* reproduce a source paper's estimator (:data:`AS_PUBLISHED`); the
others are evstab's own.

``dakf-paper`` (as published)
    Seed 003 exactly: states (beta, r, psi, d1, d2); random-walk disturbances on
    the beta and r equations (003 eq. 14-17); gyro every sample, course at fixes
    (003 eq. 18-20); constant measurement noise. Not observable (rank 4 of 5).
``dakf`` (default)
    Observable and bias-aware: (beta, r, psi, d1, d2, b_g); disturbances are
    first-order Gauss-Markov processes with correlation time ``disturbance_tau``
    (they can no longer hold a sideslip offset against a heading offset forever),
    a gyro-bias random walk, a zero-yaw-rate pseudo-measurement at standstill,
    course noise from HDOP and 1/speed, fixes with < 4 satellites dropped, and
    chi-square innovation gating. On logs (:func:`estimation_noise`): the sensor
    model's noise, process noise scaled by the course innovations, and the
    kinematic sideslip path at the limit (where the measured lateral acceleration
    leaves the linear model's, ``beta' = a_y / v - r`` takes over). In the ECU
    (``control=True``): :data:`CONTROL_NOISE`, neither of the two.
``amrkf``
    ``dakf`` plus seed 004's inter-sample residual prediction (eq. 28-29), weighted by how predictable
    the fixes' innovations are. As printed, it applies the last fix's gain again to the predicted
    residual between fixes, ``(1 - h K) / (h K)`` times the fix's own correction in all: the smaller
    the gain (consistent noise), the larger the over-correction. evstab scales it so that the
    corrections between two fixes add up to ``w`` times the fix's, with ``w`` 0 while the innovations'
    running lag-one correlation is below ``NoiseSettings.residual_corr_min`` (white innovations: the
    filter has used what they tell) and 1 at correlation 1 (a drift the model does not hold).
    ``residual_corr_fixes = 0`` gives the printed method.
``kf`` (as published)
    Three states (beta, r, psi), no disturbances, no bias (seed 001 / 003's "KF").
``kf-bias``
    ``kf`` plus a gyro-bias state.
``lob`` (as published)
    Seed 003's linear observer on (beta, r) with yaw rate and lateral acceleration.
``mbkf`` (as published)
    Seed 001's model-based filter: (beta, r, psi, b_gyro), gyro every sample and course at
    fixes, process noise through the steer input only (001 eq. 3, ``Q_d ~ B Q_c B^T T_s``)
    plus the heading and bias walks; no disturbances, gating or HDOP scaling.
``two-stage`` (as published)
    Seed 000's two-stage filter (:mod:`toolkit.estimation.two_stage`): KF1 heading and gyro
    bias from the gyro and the dual-antenna heading, KF2 body velocities and accelerometer
    biases from the accelerometers and the GPS velocity; sideslip = atan2(v_y, v_x).
``dual-antenna`` (as published)
    Seed 002's dual-antenna filter (:mod:`toolkit.estimation.dual_antenna`): lateral velocity,
    heading, total roll (bank + body roll) and the three sensor biases from the lateral
    accelerometer, yaw and roll gyros, GPS heading, roll and velocity direction.
``double-layer``
    Seed 004's double-layer estimator: layer 1 is ``dakf`` (004 uses ``amrkf``, whose inter-sample
    residual prediction as printed over-corrects with evstab's noise), layer 2
    (:mod:`toolkit.estimation.double_layer`) adds vx, vy and the roll angle from the accelerometers,
    the roll rate and pseudo-velocities from layer 1's sideslip.
``kkf`` (as published)
    Seed 001's kinematic filter (:mod:`toolkit.estimation.kkf`): heading and gyro bias from
    the integrated gyro and the course, the course update switched off while turning;
    sideslip = course - heading at each fix taken while turning.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.bicycle import lateral_coefficients
from evstab.plants.errors import ModelError
from evstab.plants.sensors import SensorConfig

if TYPE_CHECKING:
    from evstab.controllers.schedule import SpeedSchedule

    from .transition import Transition

LOOP_METHODS = ("dakf", "amrkf", "dakf-paper", "kf", "kf-bias")
"""Methods the ECU step runs (the stability loop and firmware export): the Kalman filters of
:mod:`toolkit.estimation.kalman`."""
METHODS = LOOP_METHODS + ("lob", "mbkf", "kkf", "two-stage", "dual-antenna", "double-layer")
AS_PUBLISHED = {"dakf-paper": "003", "kf": "003", "lob": "003", "mbkf": "001", "kkf": "001", "two-stage": "000",
                "dual-antenna": "002"}
"""The methods that reproduce a source paper's estimator as the paper publishes it, by the paper's number
(``docs/sources.md``): labelled references, reported beside evstab's own methods and not held to the rule
evstab's own are held to, that none is worse than ``kf-bias`` (the plain bias-aware filter) on a log where the
linear model holds. evstab's own: ``dakf``, ``amrkf``, ``double-layer`` and ``kf-bias`` itself."""


def method_help() -> str:
    """The ``--method`` help of ``evstab estimate``: the default, and the references as published by paper."""
    by: dict[str, list[str]] = {}
    for m, paper in AS_PUBLISHED.items():
        by.setdefault(paper, []).append(m)
    refs = "; ".join(f"{', '.join(ms)} ({paper})" for paper, ms in sorted(by.items(), reverse=True))
    return (f"estimator (default dakf; evstab's own: {', '.join(m for m in METHODS if m not in AS_PUBLISHED)}); "
            f"the source papers' estimators as published, references: {refs} (docs/sources.md)")


METHOD_COLUMNS = {"lob": ("ay",), "two-stage": ("ax", "ay", "gps_speed", "gps_heading"),
                  "dual-antenna": ("ay", "roll_rate", "gps_speed", "gps_heading"),
                  "double-layer": ("ax", "ay", "roll_rate", "gps_speed")}
"""Drive-log columns a method needs beyond the schema's required ones (``dual-antenna`` uses a third
antenna's ``gps_roll`` when the log has it, and runs on the heading alone, the common installation,
when it does not)."""
CHI2_1DOF_999 = 10.827566170662733
"""99.9 % quantile of the chi-square distribution with one degree of freedom."""


@dataclass(frozen=True, kw_only=True)
class NoiseSettings:
    """Noise intensities and tuning knobs of a filter (SI units).

    Process-noise intensities ``q_*`` are continuous-time spectral densities
    (variance per second of the white noise driving each state's derivative); the
    discrete covariance is ``q dt``. Measurement noises are standard deviations.
    """

    q_beta: float = 1.4e-5
    """[rad^2/s^3 ... per unit of beta'] white noise on beta'."""
    q_yaw_rate: float = 0.023
    q_yaw_rate_held: float = 0.0
    """[rad^2/s^3] The yaw rate's random walk below ``min_speed``, where the lateral model is held, if
    larger than ``q_yaw_rate``."""
    yaw_model_ay: float = 0.0
    """[m/s^2] The yaw-rate row's process noise is multiplied by ``1 + (v |r| / yaw_model_ay)^4`` (``v r`` the
    lateral acceleration of a steady turn, from the speed and the estimated yaw rate: no accelerometer noise
    in it). The linear tyre's force error grows with the square of the lateral acceleration, and with it
    the error of the yaw model, which a tight yaw row hands to the sideslip through the gyro's innovations.
    0 = off."""
    beta_model_std: float = 0.0
    """[rad] ``beta_std`` output only (the filter's covariance and estimate unchanged): the linear model's
    sideslip error in a turn, ``beta_model_std (v |r| / beta_model_ay)^2``, added in quadrature (the force
    error of a tyre's curve grows with the square of its slip angle); 0 = none."""
    beta_model_ay: float = 7.0
    """[m/s^2] The lateral acceleration ``v r`` at which that error is ``beta_model_std``."""
    beta_model_rel: float = 0.0
    """[-] ``beta_std`` output only: the linear model's sideslip error as this share of the estimated sideslip
    (a stiffness off by 10 % moves a steady turn's sideslip by about as much), added in quadrature."""
    yaw_model_steer: float = 0.0
    """[rad] The yaw-rate row's process noise is further multiplied by ``1 + (|steer| / yaw_model_steer)^4``: a
    large road-wheel angle brings what the single-track model leaves out (Ackermann geometry, the two front
    wheels' different slip angles, steering compliance), and in tight turns at low speed the yaw model is
    off although the lateral acceleration is small. 0 = off."""
    q_yaw: float = 1e-8
    q_d1: float = 0.02
    q_d2: float = 0.01
    q_bias: float = 1e-8
    excitation_floor: float = 1.0
    """Disturbance process noise is scaled by ``floor + |r_gyro| / excitation_rate``: model
    errors (stiffness) only act when the car turns, so in straight driving the disturbances
    are held and sideslip is pinned by the model. 1.0 = no scaling below the rate."""
    excitation_rate: float = 1e9
    """Yaw rate [rad/s] at which the disturbance noise doubles the floor (large = off)."""
    disturbance_tau: float = 10.0
    """Correlation time of the Gauss-Markov disturbances [s] (``dakf``, ``amrkf``)."""
    d1_init_std: float = 0.05
    """[rad/s] Standard deviation of ``d1`` at the start (the initial covariance)."""
    d2_init_std: float = 0.5
    """[rad/s^2] Standard deviation of ``d2`` at the start."""
    gyro_std: float = 0.004
    """Gyro white-noise standard deviation per sample [rad/s]."""
    course_std: float = np.deg2rad(0.15)
    """Course standard deviation [rad] when HDOP scaling is off (``dakf-paper``, ``kf``)."""
    gps_velocity_std: float = 0.056
    """Horizontal velocity noise per axis at HDOP 1 [m/s]; course std = this * HDOP / speed."""
    course_std_min: float = np.deg2rad(0.05)
    q_steer: float = 4e-5
    """[rad^2/s] white noise on the steer input (``mbkf``: its whole model uncertainty; about
    0.4 deg of steer error over a 1 s manoeuvre)."""
    heading_std: float = np.deg2rad(0.1)
    """[rad] dual-antenna heading noise per fix (seed 000: 0.1 deg; ``two-stage``)."""
    roll_std: float = np.deg2rad(0.3)
    """[rad] dual-antenna roll noise per fix (``dual-antenna``)."""
    antenna_height: float = 0.0
    """[m] GPS antenna height above the roll centre (``dual-antenna``; 002 eq. 6's h_a)."""
    accel_std: float = 0.05
    """[m/s^2] accelerometer white noise per sample (``two-stage``)."""
    q_velocity: float = 1e-3
    """[m^2/s^3] white noise on the body-velocity derivatives beyond the accelerometers' (``two-stage``:
    gravity through body roll and road bank, the lever arm)."""
    q_accel_bias: float = 1e-4
    """[m^2/s^5] accelerometer-bias random walk (``two-stage``)."""
    kkf_turn_rate: float = 0.035
    """[rad/s] (2 deg/s) ``kkf`` takes a fix as a heading measurement only below this yaw rate."""
    standstill_speed: float = 0.2
    """Below this speed [m/s] the car is standing: yaw rate is zero (pseudo-measurement)."""
    standstill_std: float = 1e-3
    standstill_rate_max: float = 0.05
    """The car counts as standing only while the gyro, less the bias estimate, also reads below this
    [rad/s]: a car spinning on the spot has wheels at rest, and forcing its yaw rate to zero would
    push the whole rotation into the bias estimate."""
    min_speed: float = 2.0
    """Below this speed [m/s] the lateral model is held (beta, r, d frozen; psi from the gyro)."""
    kinematic_ay_on: float = 0.5
    """[m/s^2] Departure of the measured lateral acceleration (roll-compensated) from the linear model's
    at which the kinematic sideslip rate starts to take over (filters with ``kinematic``)."""
    kinematic_ay_full: float = 1.0
    """[m/s^2] ... and at which it has taken over entirely."""
    kinematic_dev_tau: float = 0.15
    """[s] The departure counts through a first-order lag of this time constant: a slide sustains it, a
    delayed course fix that moves the estimate for a sample does not."""
    kinematic_ay_quiet: float = 1.0
    """[m/s^2] Below this peak-held lateral acceleration the kinematic path is off, and it may be fully on
    from twice it (no tyre is saturated while the car hardly accelerates sideways)."""
    kinematic_ay_cutoff: float = 0.0
    """[Hz] Corner frequency of the two first-order lags through which the kinematic path reads a noisy
    accelerometer (:func:`toolkit.estimation.kinematic_path.accel_low_pass`); 0 = no low-pass (the readings as
    they come, whatever their noise)."""
    kinematic_overpredict: float = 0.0
    """[0, 1] How little the kinematic path counts a departure where the car has more lateral acceleration than
    the linear model asks (a tyre beyond its linear range gives less force than the model, never more: that
    departure is a stiffness set too low or a sideslip error, often one the path itself left after a slide,
    which would then hold it on): such a departure counts ``1 - kinematic_overpredict`` of itself; where the
    model asks more than the car has, or the two disagree in sign, it counts in full. 0 (default): any
    departure in full; 1: over-prediction only."""
    kinematic_noise_sigmas: float = 0.0
    """Where the path reads the accelerometer through its low-pass (a vibrating body), both engagement
    thresholds (``kinematic_ay_on``, ``kinematic_ay_full``) are raised by this many standard deviations of
    the low-passed signal's noise (:func:`toolkit.estimation.kinematic_path.low_passed_noise`): a departure's
    magnitude averages 0.8 of that noise whatever the tyres do, so without it the vibration alone
    half-engages the path. 0 = the thresholds as set; a quiet accelerometer (below ``accel_noise_on``) is
    unaffected."""
    accel_noise_on: float = 0.3
    """[m/s^2] Estimated accelerometer noise (standard deviation per sample) above which the low-passed
    signals start to take over ..."""
    accel_noise_full: float = 0.6
    """[m/s^2] ... and at which they have taken over."""
    accel_noise_tau: float = 1.0
    """[s] Lag of the accelerometer-noise estimate."""
    kinematic_quiet_tau: float = 0.5
    """[s] Time constant with which that peak hold of ``|a_y|`` decays (a slide's ``a_y`` crosses zero
    between directions; the hold keeps the path on over the crossing)."""
    kinematic_roll_tau: float = 1.0
    """[s] Time constant with which the kinematic path's roll estimate leans on the static roll model
    against the integrated roll gyro (logs with ``roll_rate``)."""
    kinematic_offset_tau: float = 3.0
    """[s] Lag with which the kinematic path learns the lateral accelerometer's offset (road bank, bias)
    in straight driving."""
    kinematic_straight_rate: float = 0.02
    """[rad/s] Straight driving, for that offset: the yaw rate (gyro less its bias) below this."""
    kinematic_settle: float = 2.0
    """[s] The kinematic path waits this long after the first fix (the estimate settling), and again
    after a stretch with the gyro found stuck (``gyro_ok`` 0)."""
    q_beta_kinematic: float = 0.02
    """[rad^2/s] white noise on the kinematic sideslip rate (the accelerometer's errors: bank, roll
    left after the static compensation, noise, divided by the speed)."""
    q_yaw_rate_kinematic: float = 1.0
    """[rad^2/s^3] white noise on the yaw acceleration where the kinematic path has taken over (the yaw
    rate a random walk the gyro pins)."""
    kinematic_yaw_release: float = 0.0
    """[s] The yaw-rate row returns to the model through a first-order lag of this time constant after the
    kinematic path lets go (its weight there is the path's, peak-held and decaying; 0 = with the path at once).
    While the path was on, the sideslip's variance grew with ``q_beta_kinematic``; the model's yaw row, back at
    once, makes the gyro a sensor of that sideslip through ``a21`` (a 1 deg sideslip error moves the yaw
    acceleration by 0.4 rad/s^2 on the Stanford GTI), and a gyro that steps (an INS read at 200 Hz and held at
    1 kHz) then throws the sideslip by several degrees within milliseconds."""
    adapt_rate: float = 0.0
    """Innovation-adaptive process noise (``dakf``, ``amrkf``; 0 = off): the lateral states' process
    noise is multiplied by a scale ``s`` that every accepted course fix moves by
    ``log s += adapt_rate (min(NIS, adapt_nis_cap) - 1)`` (:func:`toolkit.estimation.kalman.step`)."""
    adapt_min: float = 0.3
    """Lower bound of the adaptive scale."""
    adapt_max: float = 30.0
    """Upper bound of the adaptive scale."""
    adapt_nis_cap: float = 9.0
    """NIS above this counts as this much in the adaptation (one outlier moves the scale by at most
    ``e^(adapt_rate (cap - 1))``)."""
    adapt_settle: float = 2.0
    """[s] The scale starts to adapt this long after the first fix (and again after the gyro was found
    stuck)."""
    disturbance_chi2_on: float = 0.0
    """Significance-weighted sideslip output (filters with the disturbance states ``d1``, ``d2``;
    ``disturbance_chi2_full`` 0 = off): the sideslip output is the estimate conditioned on zero
    disturbances, ``beta - P_bd P_dd^-1 d``, while the disturbance estimates are insignificant,
    and the filter's own estimate once they are, blended by a smoothstep of
    ``chi2 = d^T P_dd^-1 d`` from this value ..."""
    disturbance_chi2_full: float = 0.0
    """... to this one (:func:`toolkit.estimation.kalman.significant_sideslip`). The filter's state
    and ``beta_std`` are not changed."""
    residual_corr_fixes: float = 20.0
    """[fixes] The memory of the fix innovations' lag-one correlation ``rho`` that weighs ``amrkf``'s
    inter-sample residual prediction (:func:`toolkit.estimation.kalman._prediction_weight`): the
    corrections between two fixes add up to ``w(rho)`` times the last fix's own. 0 = seed 004 as
    printed (eq. 28-29 unweighted: ``(1 - h K) / (h K)`` times the fix's correction)."""
    residual_corr_min: float = 0.6
    """Lag-one correlation of the fix innovations up to which ``amrkf`` predicts no residual (white
    innovations: the estimate's spread over 20 fixes is 1 / sqrt(20) = 0.22; ``w`` rises linearly to 1
    at ``rho = 1``)."""
    gps_min_speed: float = 1.0
    """Course fixes below this ground speed [m/s] are not used."""
    gate: float = CHI2_1DOF_999
    max_rejects: int = 10
    """After this many consecutive gated fixes a gated one re-initialises the heading (re-lock)."""
    bias_cusum_k: float = 0.5
    """Allowance of the gyro-bias-step CUSUM on normalised course innovations (half the shift, in
    standard deviations, it is tuned to find: 1)."""
    bias_cusum_h: float = 10.0
    """Alarm threshold of that CUSUM (0 = off). With k = 0.5 and white N(0, 1) innovations the mean
    run to a false alarm is ~1.4e5 fixes per side (Siegmund's approximation; 4 h at 5 Hz each side);
    a 1-sigma shift is found after ~20 fixes."""
    bias_cusum_rate_max: float = 0.15
    """The CUSUM reads only fixes taken while the gyro, less the bias estimate, reads below this
    [rad/s] and ``|ay|`` below ``bias_cusum_ay_max``: in hard cornering and slides the linear model's
    innovations keep one sign for reasons other than the gyro (the soak found a spin reopening the
    bias again and again until the bias estimate was 100 deg/s off)."""
    bias_cusum_ay_max: float = 2.0
    """[m/s^2], see ``bias_cusum_rate_max``."""
    bias_learn_rate: float = 0.0
    """[rad/s] The gyro bias learns in full only while the gyro, less the bias estimate, reads below this, and
    not at all from twice it (filters with a bias state; 0 = always in full): its gain in the gyro and course
    updates is multiplied by ``clip(2 - |r| / bias_learn_rate, 0, 1)``, and in between it is a consider state
    (:func:`toolkit.estimation.core.scalar_update`: its estimate held, its variance and correlations kept
    right for the gain used). In a turn, a course innovation is as much the nominal model's sideslip error
    (tyres stiffer or softer than the file says) as the heading's drift; learnt there, the bias takes up the
    model's error and carries it into every later heading. On the Stanford GTI's limit drives the bias,
    learnt in every turn, swung by up to 0.8 deg/s from its true 0.17; held in turns, it is learnt on the
    straights and the correlations the turns built."""
    bias_settle_hold: float = 0.0
    """[s] Until this long after the first usable fix (before it too), the gyro update leaves the bias estimate
    as it is wherever the car turns (``v |r|`` above ``bias_settle_ay``): a consider state as with
    ``bias_learn_rate``. 0 = off. A filter started in a turn (a cold start at speed, an ECU reset) begins with
    its sideslip at 0 and its bias spread wide: the yaw model's prediction is then off by ``a21`` times the
    sideslip error, and the gyro update hands that to the bias (1-3 deg/s within the first second on the
    Stanford GTI's 12 m/s^2 turns, which later gated every fix). Where the car drives straight, the bias learns
    from the gyro from the first sample."""
    bias_settle_ay: float = 2.0
    """[m/s^2] see ``bias_settle_hold``."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (np.isfinite(v) and v >= 0):
                raise ModelError(f"noise setting '{f.name}' must be a finite number >= 0, got {v!r}")
        if self.beta_model_ay <= 0:
            raise ModelError(f"noise setting 'beta_model_ay' must be > 0 m/s^2, got {self.beta_model_ay!r}")
        if self.adapt_min <= 0:
            raise ModelError(f"noise setting 'adapt_min' must be > 0, got {self.adapt_min!r}")
        if self.adapt_max < self.adapt_min:
            raise ModelError(f"noise setting 'adapt_max' ({self.adapt_max!r}) must be >= 'adapt_min' "
                             f"({self.adapt_min!r})")
        if self.disturbance_chi2_full and self.disturbance_chi2_full <= self.disturbance_chi2_on:
            raise ModelError(f"noise setting 'disturbance_chi2_full' ({self.disturbance_chi2_full!r}) must be 0 (off) "
                             f"or above 'disturbance_chi2_on' ({self.disturbance_chi2_on!r})")
        if 0 < self.residual_corr_fixes < 1:
            raise ModelError(f"noise setting 'residual_corr_fixes' must be 0 (unweighted) or >= 1, got "
                             f"{self.residual_corr_fixes!r}")
        if not self.residual_corr_min < 1:
            raise ModelError(f"noise setting 'residual_corr_min' must be < 1, got {self.residual_corr_min!r}")
        if not self.kinematic_overpredict <= 1.0:
            raise ModelError(f"noise setting 'kinematic_overpredict' must be between 0 and 1, got "
                             f"{self.kinematic_overpredict!r}")
        if self.accel_noise_full <= self.accel_noise_on:
            raise ModelError(f"noise setting 'accel_noise_full' ({self.accel_noise_full!r}) must be above "
                             f"'accel_noise_on' ({self.accel_noise_on!r})")
        if self.accel_noise_tau <= 0:
            raise ModelError(f"noise setting 'accel_noise_tau' must be > 0 s, got {self.accel_noise_tau!r}")
        if self.disturbance_tau <= 0:
            raise ModelError(f"noise setting 'disturbance_tau' must be > 0 s, got {self.disturbance_tau!r}")


@dataclass(frozen=True)
class FilterDesign:
    """A frozen filter design: method, states, nominal vehicle, noise and features."""

    method: str
    states: tuple[str, ...]
    params: VehicleParams
    noise: NoiseSettings
    disturbance: str | None  # None, "random-walk" or "gauss-markov"
    bias: bool
    gating: bool
    hdop_noise: bool
    standstill_update: bool
    residual_prediction: bool
    latency: float = 0.0
    antenna_x: float = 0.0
    dt_nominal: float = 1e-3
    schedule: SpeedSchedule | None = None
    """A :class:`controllers.schedule.SpeedSchedule`: the lateral model from tables (firmware), or None (exact)."""
    steer_noise: bool = False
    """Process noise through the steer input (``NoiseSettings.q_steer``; ``mbkf``)."""
    kinematic: bool = False
    """Blend the kinematic sideslip rate ``a_y / v - r`` into the sideslip row where the measured lateral
    acceleration departs from the linear model's (the tyres saturated; :func:`toolkit.estimation.kalman.step`)."""
    transition: Transition | None = None
    """A :class:`toolkit.estimation.transition.Transition`: the ECU's filter propagates with its model
    discretised at export time on the schedule's grid for the control period (firmware); None: the
    4th-order Taylor series at the current speed every sample."""

    @property
    def n(self) -> int:
        return len(self.states)

    def index(self, name: str) -> int:
        return self.states.index(name)

    @property
    def latency_samples(self) -> int:
        return int(round(self.latency / self.dt_nominal))

    def initial_covariance(self) -> np.ndarray:
        sd = {"beta": np.deg2rad(2.0), "yaw_rate": 0.05, "yaw": np.pi, "d1": self.noise.d1_init_std,
              "d2": self.noise.d2_init_std, "gyro_bias": 0.01}
        return np.diag([sd[s] ** 2 for s in self.states])


CONTROL_NOISE = NoiseSettings()
"""The noise of the ECU's filter (the stability loop, the design job, firmware): cautious process noise
and fast disturbance states, the observer the 2-DOF law's disturbance rejection was designed and judged
with. On evstab's own logs its course innovations are smaller than it predicts (mean NIS 0.1-0.3)."""
LATERAL_STATES = ("beta", "yaw_rate", "d1", "d2")
"""The lateral model's states: the process noise the noise fit fits and the adaptive scale multiplies
(not the heading's or the gyro bias's)."""
KINEMATIC_METHODS = ("dakf", "amrkf", "double-layer")
"""The methods that estimate on logs with :func:`estimation_noise` and the kinematic sideslip path."""


def estimation_noise(sensors: SensorConfig | None = None) -> NoiseSettings:
    """The noise of ``dakf``, ``amrkf`` and ``double-layer`` on logs: the gyro and GPS noise the sensor
    model generates (``sensors``, a :class:`plants.sensors.SensorConfig`; default its defaults), process
    noise that keeps the course innovations consistent where the model is right (mean NIS inside its
    interval on evstab's own logs, every bundled vehicle), and innovation-adaptive scaling of it
    (``adapt_rate``) where the model is wrong; the kinematic path engages at a smaller departure than
    the ECU's, through a shorter lag (0.4 -> 0.8 m/s^2, 0.1 s, against 0.5 -> 1.0 m/s^2, 0.15 s), and it
    reads a vibrating accelerometer through a 5 Hz low-pass (``kinematic_ay_cutoff``; a quiet one as it
    comes), its thresholds raised by three standard deviations of what noise passes the low-pass
    (``kinematic_noise_sigmas``), with under half the ECU's sideslip noise where it has taken over
    (``q_beta_kinematic``), the yaw row loosens with the lateral acceleration and the road-wheel angle
    (``yaw_model_ay``, ``yaw_model_steer``), the bias is held in turns until a second after the first fix
    (``bias_settle_hold``), and ``beta_std`` carries the linear model's own error
    (``beta_model_std``, ``beta_model_rel``). These are what measured drives of a real car asked for
    (``studies/real_drives.py``); together they leave every cell of ``estimation_mb`` within 0.02 deg RMS."""
    s = sensors if sensors is not None else SensorConfig()
    q_d1, q_d2, tau = 8e-5, 4e-5, NoiseSettings.disturbance_tau
    # the disturbances start with the stationary spread of their Gauss-Markov processes, q tau / 2: a wider
    # prior lets the first fixes' heading drift (the bias not yet learnt) into them, and with them into beta
    return NoiseSettings(gyro_std=s.gyro_noise, gps_velocity_std=s.gps_velocity_noise, q_beta=1.4e-7,
                         q_yaw_rate=2.3e-4, q_yaw_rate_held=1.0, q_d1=q_d1, q_d2=q_d2, q_bias=5e-8,
                         d1_init_std=float(np.sqrt(q_d1 * tau / 2)), d2_init_std=float(np.sqrt(q_d2 * tau / 2)),
                         adapt_rate=0.3, kinematic_ay_on=0.4, kinematic_ay_full=0.8, kinematic_dev_tau=0.1,
                         kinematic_ay_cutoff=5.0, disturbance_chi2_on=2.0, disturbance_chi2_full=6.0,
                         kinematic_noise_sigmas=3.0, q_beta_kinematic=0.0075, yaw_model_ay=7.0, yaw_model_steer=0.1,
                         beta_model_std=np.deg2rad(0.5), beta_model_rel=0.1, bias_settle_hold=1.0)


def design_filter(method: str, params: VehicleParams, noise: NoiseSettings | None = None, *,
                  latency: float = 0.0, antenna_x: float = 0.0, dt: float = 1e-3,
                  nominal: bool = True, control: bool = False, kinematic: bool | None = None) -> FilterDesign:
    """Design a filter for ``params`` (its nominal version unless ``nominal=False``).

    ``control``: the ECU's filter (the stability loop, the design job, firmware export):
    :data:`CONTROL_NOISE` unless ``noise`` is given. Otherwise the methods of
    :data:`KINEMATIC_METHODS` estimate with :func:`estimation_noise` (unless ``noise`` is given).
    Those methods have the kinematic sideslip path, on logs and in the ECU; ``kinematic=False``
    leaves it out (``kinematic=True`` for another method is an error)."""
    if method not in METHODS:
        raise ModelError(f"unknown estimation method '{method}'; known: {', '.join(METHODS)}")
    if not (np.isfinite(latency) and 0 <= latency <= 0.5):
        raise ModelError(f"GPS latency must be between 0 and 0.5 s, got {latency!r}")
    p = params.as_nominal() if nominal else params
    if kinematic and method not in KINEMATIC_METHODS:
        raise ModelError(f"'{method}' has no kinematic sideslip path (the methods with one: "
                         f"{', '.join(KINEMATIC_METHODS)})")
    kinematic = (method in KINEMATIC_METHODS) if kinematic is None else bool(kinematic)
    if noise is None:
        # mbkf: the steer input carries the whole model uncertainty (001), no white noise on beta', r'
        noise = NoiseSettings(q_beta=0.0, q_yaw_rate=0.0) if method == "mbkf" else (
            estimation_noise() if method in KINEMATIC_METHODS and not control else CONTROL_NOISE)
    lat = ("beta", "yaw_rate", "yaw")
    if method == "dakf-paper":
        return FilterDesign(method, lat + ("d1", "d2"), p, noise, "random-walk", False, False, False, False,
                            False, latency, antenna_x, dt)
    if method in KINEMATIC_METHODS:
        return FilterDesign(method, lat + ("d1", "d2", "gyro_bias"), p, noise, "gauss-markov", True, True, True,
                            True, method == "amrkf", latency, antenna_x, dt, kinematic=kinematic)
    if method == "kf":
        return FilterDesign(method, lat, p, noise, None, False, False, False, False, False, latency, antenna_x, dt)
    if method == "mbkf":
        return FilterDesign(method, lat + ("gyro_bias",), p, noise, None, True, False, False, False, False,
                            latency, antenna_x, dt, steer_noise=True)
    if method == "dual-antenna":
        return FilterDesign(method, ("yaw", "gyro_bias"), p, noise, None, True, False, False, False, False,
                            latency, antenna_x, dt)
    if method == "two-stage":
        return FilterDesign(method, ("yaw", "gyro_bias"), p, noise, None, True, False, False, False, False,
                            latency, antenna_x, dt)
    if method == "kkf":
        return FilterDesign(method, ("yaw", "gyro_bias"), p, noise, None, True, False, True, False, False,
                            latency, antenna_x, dt)
    if method == "kf-bias":
        return FilterDesign(method, lat + ("gyro_bias",), p, noise, None, True, False, False, True, False,
                            latency, antenna_x, dt)
    return FilterDesign("lob", ("beta", "yaw_rate"), p, noise, None, False, False, False, False, False,
                        0.0, 0.0, dt)


def continuous_model(d: FilterDesign, v, ops, dynamic=True):
    """Continuous ``A`` (n x n) and ``B`` (n x 2, inputs steer and N_z) at speed ``v``.

    With ``dynamic`` False (below ``min_speed``) the lateral model is held: only
    ``psi' = r`` remains. ``dynamic`` may also be a 0/1 condition (a comparison, number
    or symbol): the lateral entries are then multiplied by it. (A product, not casadi's
    ``if_else``: casadi pushes later products into an ``if_else``, so every term of the
    discretisation would carry a selection.)
    """
    n = d.n
    A = ops.zeros(n, n)
    B = ops.zeros(n, 2)
    ib, ir = d.index("beta"), d.index("yaw_rate")
    if "yaw" in d.states:
        A[d.index("yaw"), ir] = 1.0
    if dynamic is False:
        return A, B
    if d.schedule is not None:
        a11, a12, a21, a22, b11, b21, b22 = d.schedule.values(v, ops)[:7]
    else:
        a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(d.params, v)
    gate = (lambda e: e) if dynamic is True else (lambda e: e * dynamic)
    A[ib, ib], A[ib, ir], A[ir, ib], A[ir, ir] = gate(a11), gate(a12), gate(a21), gate(a22)
    B[ib, 0], B[ir, 0], B[ir, 1] = gate(b11), gate(b21), gate(b22)
    if d.disturbance is not None:
        i1, i2 = d.index("d1"), d.index("d2")
        A[ib, i1] = gate(1.0)
        A[ir, i2] = gate(1.0)
        if d.disturbance == "gauss-markov":
            A[i1, i1] = gate(-1.0 / d.noise.disturbance_tau)
            A[i2, i2] = gate(-1.0 / d.noise.disturbance_tau)
    return A, B


def process_noise_diag(d: FilterDesign, symbolic: bool = False):
    """Process-noise intensities per state; with ``symbolic`` a list that may hold casadi symbols
    (a design whose intensities are decision variables of the tuning)."""
    q = {"beta": d.noise.q_beta, "yaw_rate": d.noise.q_yaw_rate, "yaw": d.noise.q_yaw, "d1": d.noise.q_d1,
         "d2": d.noise.q_d2, "gyro_bias": d.noise.q_bias}
    vals = [q[s] for s in d.states]
    return vals if symbolic else np.array(vals, float)


def gyro_row(d: FilterDesign) -> np.ndarray:
    h = np.zeros(d.n)
    h[d.index("yaw_rate")] = 1.0
    if d.bias:
        h[d.index("gyro_bias")] = 1.0
    return h
