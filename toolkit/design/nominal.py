"""Nominal vehicle files for the CommonRoad multi-body cars: ``evstab derive-nominal``.

A designer who gets a multi-body car gets its data sheet, not a bicycle model. This
module makes the :class:`~plants.VehicleParams` a designer would write for
``commonroad-mb:N``:

* masses, inertias and geometry exactly from the package's set (yaw inertia ``I_z``,
  ``l_f = a``, ``l_r = b``, tracks, wheel radius and inertia, sprung mass, CG height);
* roll about the roll axis by the parallel-axis theorem, ``I_x = I_Phi_s + m_s h^2``
  with ``h`` the sprung CG's height above the roll axis (:func:`plants.commonroad_mb.roll_arm`);
  roll stiffness and damping of the suspension (springs ``K_s t^2 / 2`` less the auxiliary
  torsion stiffness ``K_ts`` per axle, in series with the tyres' ``K_zt t^2 / 2``);
* the **cornering stiffness a bicycle model should use**, identified by an output-error
  fit (:func:`identify_cornering_stiffness`): the linear bicycle of seed 003 eq. 1-2, driven
  by the multi-body car's own road-wheel angle, fitted to its yaw rate and lateral
  acceleration (what a test car's gyro and accelerometer measure) in small-steer runs (a
  step and two sines, 1 m/s^2 of lateral acceleration) at several speeds. It differs from
  the tyre's slope times static load because the multi-body tyre has camber thrust and the
  suspension is compliant. The sprung mass's sideslip is not fitted: it carries the body's
  roll-coupled lateral motion, which no bicycle stiffness reproduces (fitting it as well
  pulls the stiffness up by half and the steady-state yaw rate off by 5-12 %);
* what the sets do not have, as stated assumptions: the steering ratio
  (:data:`STEERING_RATIO`) and the rear in-wheel motors' torque (:data:`MOTOR_ACCEL`).

``[meta] source`` says how each number was made.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.optimize

from evstab.plants import VehicleParams, commonroad_mb, get_plant
from evstab.plants.bicycle import lateral_matrices
from evstab.plants.errors import ParameterError
from evstab.plants.maneuvers import Maneuver
from evstab.plants.params import G, parse_vehicle_toml

STEERING_RATIO = 16.0
"""Hand-wheel to road-wheel ratio assumed for every set (not in the CommonRoad data)."""
MOTOR_ACCEL = 0.35
"""Rear in-wheel motors sized for 0.35 g at the rear axle: ``T_max = 0.35 m g R_w / 2`` per motor
(not in the CommonRoad data; an in-wheel motor of the class of compact-ev's)."""
FIT_SPEEDS_KMH = (40.0, 60.0, 80.0, 100.0)
FIT_AY = 1.0
"""Lateral acceleration [m/s^2] of the identification runs (linear range of the tyres)."""
DT = 1e-3


@dataclass(frozen=True)
class StiffnessFit:
    """Result of :func:`identify_cornering_stiffness`."""

    front: float
    """Cornering stiffness per front tyre [N/rad]."""
    rear: float
    """Cornering stiffness per rear tyre [N/rad]."""
    yaw_rate_rms_rel: float
    """RMS yaw-rate residual over the RMS yaw rate, mean over the runs [-]."""
    ay_rms_rel: float
    """RMS lateral-acceleration residual over the RMS lateral acceleration, mean over the runs [-]."""
    beta_rms_rel: float
    """Not fitted: RMS sideslip error of the fitted bicycle over the RMS sideslip, all runs [-]."""
    tire_slope_front: float
    """The tyre's own slope times static load, per front tyre [N/rad] (for comparison)."""
    tire_slope_rear: float


def geometry(set_id: int, cornering_stiffness_front: float, cornering_stiffness_rear: float, *,
             name: str | None = None, source: str = "") -> VehicleParams:
    """The set's masses, inertias and geometry as :class:`VehicleParams` with the given stiffness."""
    s = commonroad_mb.mb_set(set_id)
    q = s.namespace()
    h = commonroad_mb.roll_arm(q)
    k_f, k_r = commonroad_mb.axle_roll_stiffness(q)
    return VehicleParams(
        name=name or f"commonroad-{set_id}", source=source,
        mass=q.m, yaw_inertia=q.I_z, lf=q.a, lr=q.b,
        cornering_stiffness_front=float(cornering_stiffness_front),
        cornering_stiffness_rear=float(cornering_stiffness_rear),
        sprung_mass=q.m_s, roll_inertia=q.I_Phi_s + q.m_s * h * h,
        roll_damping=0.5 * (q.K_sdf * q.T_f ** 2 + q.K_sdr * q.T_r ** 2),
        roll_stiffness=k_f + k_r, roll_stiffness_front_share=k_f / (k_f + k_r), roll_arm=h, cg_height=q.h_cg,
        track_front=q.T_f, track_rear=q.T_r, width=q.w, wheel_radius=q.R_w, wheel_inertia=q.I_y_w,
        longitudinal_stiffness=q.tire.p_kx1 * q.m * G / 4.0, mu=1.0,
        steering_ratio=STEERING_RATIO, max_motor_torque=MOTOR_ACCEL * q.m * G * q.R_w / 2.0)


def _fit_maneuver(speed: float, amplitude: float) -> Maneuver:
    """1 s straight, a 0.15 s ramp to ``amplitude`` held 2.5 s, 1.5 s straight, then two periods
    each of a 0.5 Hz and a 1 Hz sine (the dynamics as well as the steady state)."""
    def steer(t):
        t = np.asarray(t, float)
        step = amplitude * np.clip((t - 1.0) / 0.15, 0.0, 1.0) * (t < 3.65) \
            + amplitude * np.clip((3.8 - t) / 0.15, 0.0, 1.0) * (t >= 3.65)
        s1 = amplitude * np.sin(2 * np.pi * 0.5 * (t - 5.3)) * ((t >= 5.3) & (t < 9.3))
        s2 = amplitude * np.sin(2 * np.pi * 1.0 * (t - 9.3)) * ((t >= 9.3) & (t < 11.3))
        return step + s1 + s2
    return Maneuver("identification", speed, 12.5, steer=steer)


def small_steer_runs(set_id: int, speeds_kmh=FIT_SPEEDS_KMH) -> list[dict]:
    """The multi-body car's small-steer responses: per speed ``t``, road-wheel ``steer``, ``yaw_rate``,
    ``beta``, ``ay``, ``vx`` (the truth, no sensors)."""
    from ..kernels.compiled import compiled_plant
    from evstab.plants import COMMANDS, TRUTH, default_disturbance
    from ..loop.simulator import steer_rate
    model = get_plant(f"commonroad-mb:{set_id}")
    truth = geometry(set_id, 5e4, 5e4)  # the plant's dynamics are the set's; this gives the geometry
    cp = compiled_plant(model, truth, DT)
    runs = []
    q = commonroad_mb.mb_set(set_id).namespace()
    for kmh in speeds_kmh:
        v = kmh / 3.6
        amp = FIT_AY * (q.a + q.b) / v ** 2  # kinematic steer for FIT_AY; the car's gain is close
        man = _fit_maneuver(v, amp)
        n = int(round(man.duration / DT))
        t = np.arange(n) * DT
        steer = man.steer(t)
        cmd = COMMANDS.pack(steer=steer, yaw_moment=np.zeros(n), speed_ref=np.full(n, v), drive_on=np.ones(n),
                            steer_rate=steer_rate(steer, DT))
        X, Y = cp.rollout(model.initial_state(truth, v), cmd, default_disturbance())
        y = TRUTH.as_dict(Y)
        runs.append({"speed": v, "t": t, "steer": X[model.state_index("steer"), :n],
                     "yaw_rate": y["yaw_rate"], "beta": y["beta"], "ay": y["ay"], "vx": y["vx"]})
    return runs


def _bicycle_response(p: VehicleParams, run: dict) -> np.ndarray:
    """Linear bicycle driven by the run's road-wheel angle, exact ZOH at its mean speed: columns
    sideslip, yaw rate and lateral acceleration ``v (beta' + r)``."""
    v = float(np.mean(run["vx"]))
    A, B = lateral_matrices(p, v)
    blk = scipy.linalg.expm(np.block([[A, B[:, :1]], [np.zeros((1, 3))]]) * DT)
    Ad, Bd = blk[:2, :2], blk[:2, 2]
    steer = run["steer"]
    x = np.zeros(2)
    out = np.empty((len(steer), 3))
    for k, d in enumerate(steer):
        xd = A @ x + B[:, 0] * d
        out[k] = (x[0], x[1], v * (xd[0] + x[1]))
        x = Ad @ x + Bd * d
    return out


def identify_cornering_stiffness(set_id: int, runs: list[dict] | None = None) -> StiffnessFit:
    """Output-error least squares (scipy ``least_squares`` on log stiffness) of the bicycle's yaw
    rate and lateral acceleration against the multi-body car's, each normalised by its RMS per run."""
    runs = runs or small_steer_runs(set_id)
    q = commonroad_mb.mb_set(set_id).namespace()
    fz_f = q.m * G * q.b / (q.a + q.b) / 2.0
    fz_r = q.m * G * q.a / (q.a + q.b) / 2.0
    slope_f, slope_r = abs(q.tire.p_ky1) * fz_f, abs(q.tire.p_ky1) * fz_r
    base = geometry(set_id, slope_f, slope_r)

    def model(logc):
        return dataclasses.replace(base, cornering_stiffness_front=float(np.exp(logc[0])),
                                   cornering_stiffness_rear=float(np.exp(logc[1])))

    def residual(logc):
        p = model(logc)
        res = []
        for run in runs:
            o = _bicycle_response(p, run)
            res.append((o[:, 1] - run["yaw_rate"]) / np.sqrt(np.mean(run["yaw_rate"] ** 2)))
            res.append((o[:, 2] - run["ay"]) / np.sqrt(np.mean(run["ay"] ** 2)))
        return np.concatenate(res)

    sol = scipy.optimize.least_squares(residual, np.log([slope_f, slope_r]), xtol=1e-10, ftol=1e-12)
    cf, cr = np.exp(sol.x)
    res = residual(sol.x).reshape(len(runs) * 2, -1)
    p = model(sol.x)
    beta = np.concatenate([_bicycle_response(p, run)[:, 0] - run["beta"] for run in runs])
    beta_rms = float(np.sqrt(np.mean(beta ** 2)) / np.sqrt(np.mean(np.concatenate([r["beta"] for r in runs]) ** 2)))
    return StiffnessFit(float(cf), float(cr), float(np.sqrt(np.mean(res[0::2] ** 2))),
                        float(np.sqrt(np.mean(res[1::2] ** 2))), beta_rms, float(slope_f), float(slope_r))


def derive_nominal(spec: str) -> tuple[VehicleParams, str]:
    """The nominal :class:`VehicleParams` for ``commonroad-mb:N`` and the TOML text of its file."""
    set_id, _ = commonroad_mb.parse_spec(spec)
    fit = identify_cornering_stiffness(set_id)
    speeds = ", ".join(f"{v:g}" for v in FIT_SPEEDS_KMH)
    source = (f"CommonRoad vehicle models (PyPI commonroad-vehicle-models), multi-body parameter set {set_id} "
              f"({commonroad_mb.SETS[set_id]}), made by `evstab derive-nominal commonroad-mb:{set_id}`. Exactly "
              "from the set: mass m, yaw_inertia I_z, lf = a, lr = b, sprung_mass m_s, cg_height h_cg, "
              "track_front T_f, track_rear T_r, width w, wheel_radius R_w, wheel_inertia I_y_w. "
              "roll_inertia = I_Phi_s + m_s h^2 (parallel axis; roll_arm h = h_s minus the roll-axis height at "
              "the CG). roll_stiffness = per axle (K_s T^2/2 - K_ts) in series with the tyres' K_zt T^2/2; "
              "roll_damping = K_sd T^2/2 summed over the axles; longitudinal_stiffness = p_kx1 m g / 4. "
              f"cornering_stiffness_front/rear: output-error fit of the linear bicycle (seed 003 eq. 1-2) to the "
              f"multi-body car's yaw rate and lateral acceleration in small-steer runs ({FIT_AY:g} m/s^2: step and "
              f"0.5/1 Hz sines) at {speeds} km/h; residual RMS {100 * fit.yaw_rate_rms_rel:.1f} % of the yaw "
              f"rate, {100 * fit.ay_rms_rel:.1f} % of the lateral acceleration (sideslip not fitted: "
              f"{100 * fit.beta_rms_rel:.0f} %); the tyre's slope times static load would be "
              f"{fit.tire_slope_front:.0f} / {fit.tire_slope_rear:.0f} N/rad. Assumptions (not in the set): "
              f"steering_ratio {STEERING_RATIO:g}; max_motor_torque = {MOTOR_ACCEL:g} m g R_w / 2 per rear motor.")
    p = geometry(set_id, fit.front, fit.rear, source=source)
    notes = ("mu = 1 is the package's tyre (peak lateral friction p_dy1 = "
             f"{commonroad_mb.mb_set(set_id).namespace().tire.p_dy1:g}); evstab's road friction scales it.")
    return p, to_toml(p, header=f"Nominal model of commonroad-mb:{set_id} ({commonroad_mb.SETS[set_id]}).",
                      notes=notes)


def to_toml(p: VehicleParams, header: str = "", notes: str = "") -> str:
    """A vehicle file (the format of docs/formats.md) for ``p``; numbers written with repr (round trip exact)."""
    lines = [f"# {header}"] if header else []
    lines += ["[meta]", f"name = {json.dumps(p.name)}", f"source = {json.dumps(p.source)}"]
    if notes:
        lines.append(f"notes = {json.dumps(notes)}")
    lines += ["", "[vehicle]"]
    for k, v in p.to_dict().items():
        if k in ("name", "source"):
            continue
        lines.append(f"{k} = {float(v)!r}")
    return "\n".join(lines) + "\n"


def write_nominal(spec: str, out: str | Path) -> VehicleParams:
    """:func:`derive_nominal` written atomically to ``out`` (re-read and checked before the rename)."""
    p, text = derive_nominal(spec)
    out = Path(out)
    back = parse_vehicle_toml(text, str(out))
    if back != p:
        raise ParameterError(f"{out}: the written vehicle file does not read back as the derived parameters")
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=out.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return p
