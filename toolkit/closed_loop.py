"""The stability loop compiled: plant, sensors, estimator, controller and actuators in one C call.

:func:`compiled_loop_run` integrates exactly the loop that :func:`toolkit.simulator.simulate`
steps in Python for an open-loop steer manoeuvre (same one-sample sensor delay,
same noise draws, same component equations: each is written once for numpy and
casadi), but as one casadi step function rolled out by ``mapaccum`` and compiled
to C, so a 10 s run at 1 kHz costs milliseconds. Supported: the ``two-dof`` and
``two-dof-true`` controllers, Kalman-filter estimators, GPS latencies of whole
samples; the plant may differ from what controller and estimator believe
(``nominal``), which is what model-error sweeps need.
"""

from __future__ import annotations

import ctypes
import hashlib
import sys
from dataclasses import dataclass

import casadi as ca
import numpy as np

import controllers.actuators as act_mod
import controllers.two_dof as ctl_mod
import plants.sensors as sens_mod
from controllers.actuators import ActuatorLimits, actuator_law
from controllers.two_dof import TwoDofDesign, control_law
from plants import DISTURBANCES, TRUTH, VehicleParams, get_plant
from plants.backend import CASADI
from plants.disturbances import Disturbances, Friction, disturbance_profile
from plants.maneuvers import Maneuver
from plants.sensors import SensorConfig, draw_noise, gps_fix_mask, readings

from .compiled import CFunction, build_step, compile_library, compiled_plant, param_vector, source_digest
from .estimation import design_filter
from .estimation import kalman as kal_mod

NOISE = ("steer", "gyro", "roll_gyro", "accel_x", "accel_y", "wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr",
         "speed", "gps_e", "gps_n", "heading")
EXTRA = ("steer", "yaw_moment", "steer_driver", "yaw_moment_cmd", "beta_ref", "yaw_rate_ref", "beta_est",
         "yaw_rate_est", "yaw_moment_limited")
CHUNK = 1000


@dataclass(frozen=True)
class LoopSpec:
    plant: str
    params: VehicleParams
    dt: float
    controller: str
    estimator: str | None
    sensors: SensorConfig
    mu: float
    design: TwoDofDesign | None = None
    nominal: VehicleParams | None = None
    """What the controller and estimator believe (default: ``params`` itself, as nominal)."""


def _noise_matrix(cfg: SensorConfig, seed: int, n: int) -> np.ndarray:
    nz = draw_noise(cfg, seed, n)
    rows = [nz["steer"], nz["gyro"], nz["roll_gyro"], nz["accel"][0], nz["accel"][1], *nz["wheel"], nz["speed"],
            nz["gps"][0], nz["gps"][1], nz["heading"]]
    return np.vstack(rows)


def _build(spec: LoopSpec):
    model = get_plant(spec.plant)
    p = spec.params
    n_sub = compiled_plant(model, p, spec.dt).n_sub
    plant_step, names = build_step(model, p, spec.dt, n_sub)
    nom = spec.nominal if spec.nominal is not None else p
    lat = spec.sensors.gps_latency
    est = (None if spec.controller == "two-dof-true"
           else design_filter(spec.estimator, nom, dt=spec.dt, latency=lat))
    ctl = spec.design if spec.design is not None else TwoDofDesign(nom.as_nominal(), dt=spec.dt)
    n_lag = int(round(lat / spec.dt))
    lim = ActuatorLimits()
    tmax = lim.torque_max if lim.torque_max is not None else (p.max_motor_torque or 1e9)
    nx, nt = len(model.states), len(TRUTH)
    ne = kal_mod.layout(est)["size"] if est is not None else 0
    sizes = [nx, ne, len(ctl_mod.STATE), len(act_mod.STATE), nt, 2, 2, 4 * n_lag]
    Z = ca.SX.sym("z", sum(sizes))
    parts, o = [], 0
    for s in sizes:
        parts.append(Z[o:o + s])
        o += s
    x, z_est, z_ctl, z_act, y_prev, applied, flags, lag_buf = parts
    nin = 3 + len(DISTURBANCES) + len(NOISE) + 1
    U = ca.SX.sym("u", nin)
    steer_drv, speed_ref, drive_on = U[0], U[1], U[2]
    w = U[3:3 + len(DISTURBANCES)]
    nzv = U[3 + len(DISTURBANCES):3 + len(DISTURBANCES) + len(NOISE)]
    fix = U[nin - 1]
    pv = ca.SX.sym("p", len(names))
    tr = {name: y_prev[i] for i, name in enumerate(TRUTH)}
    nzd = {k: nzv[i] for i, k in enumerate(NOISE)}
    noise = {"steer": nzd["steer"], "gyro": nzd["gyro"], "roll_gyro": nzd["roll_gyro"], "accel_x": nzd["accel_x"],
             "accel_y": nzd["accel_y"], "wheel": [nzd[f"wheel_{c}"] for c in ("fl", "fr", "rl", "rr")],
             "speed": nzd["speed"], "gps_e": nzd["gps_e"], "gps_n": nzd["gps_n"], "heading": nzd["heading"]}
    inp = {"steer": applied[0], "yaw_moment": applied[1], "bank": w[DISTURBANCES.index("bank")]}
    radius = p.wheel_radius if model.name == "two-track" or p.wheel_radius is not None else None
    now = ca.vertcat(tr["yaw"], tr["vx"], tr["vy"], tr["yaw_rate"])
    if n_lag > 0:  # the fix describes the truth n_lag samples ago (a shift register of it)
        gps = tuple(lag_buf[4 * (n_lag - 1) + i] for i in range(4))
        lag_next = ca.vertcat(now, lag_buf[:4 * (n_lag - 1)])
    else:
        gps = tuple(now[i] for i in range(4))
        lag_next = lag_buf
    m = readings(tr, inp, noise, gps, fix, spec.sensors, radius, CASADI)
    dt = spec.dt
    if est is not None:
        valid = m["gps_valid"]
        u_est = ca.vertcat(dt, m["speed"], m["steer"], m["yaw_moment"], m["yaw_rate"], valid,
                           valid * m["gps_course"], ca.if_else(fix > 0.5, spec.sensors.gps_hdop, 1.0),
                           ca.if_else(fix > 0.5, float(spec.sensors.gps_sats), 99.0), m["ay"])
        z_est_n, y_est = kal_mod.step(est, z_est, u_est, CASADI)
        beta, r = y_est[0], y_est[1]
        d1 = y_est[4] if "d1" in est.states else 0.0
        d2 = y_est[5] if "d2" in est.states else 0.0
    else:
        z_est_n = z_est
        beta, r, d1, d2 = tr["beta"], tr["yaw_rate"], 0.0, 0.0
    sig = ca.vertcat(m["speed"], steer_drv, beta, r, d1, d2, spec.mu, flags[0], flags[1])
    z_ctl_n, u = control_law(ctl, z_ctl, sig, CASADI)
    z_act_n, a = actuator_law(p, lim, tmax, z_act, ca.vertcat(u[0], u[1], 0.0, dt), CASADI)
    cmd = ca.vertcat(a[0], a[1], speed_ref, drive_on)
    x_n, y_k = plant_step(x, cmd, w, pv)
    Zn = ca.vertcat(x_n, z_est_n, z_ctl_n, z_act_n, y_k, a[0], a[1], a[2], a[3], lag_next)
    extra = ca.vertcat(a[0], a[1], steer_drv, u[1], u[2], u[3], beta, r, a[3])
    step = ca.Function("loop_step", [Z, U, pv], [Zn, y_k, extra])
    acc = step.mapaccum("loop_acc", CHUNK)
    z0, Uc, pm = ca.MX.sym("z0", Z.shape[0]), ca.MX.sym("U", nin, CHUNK), ca.MX.sym("p", len(names))
    Zs, Ys, Es = acc(z0, Uc, ca.repmat(pm, 1, CHUNK))
    chunk = ca.Function("loop_chunk", [z0, Uc, pm], [Zs[:, -1], Ys, Es])
    return step, chunk, names, sizes, est, nin


_CACHE: dict = {}


def _compiled(spec: LoopSpec):
    if spec not in _CACHE:
        step, chunk, names, sizes, est, nin = _build(spec)
        src = source_digest(sys.modules[__name__], ctl_mod, act_mod, sens_mod, kal_mod)
        key = "loop_" + hashlib.sha256(repr((spec, ca.__version__, src, CHUNK)).encode()).hexdigest()[:20]
        lib = compile_library([chunk], key)
        cf = CFunction(ctypes.CDLL(str(lib)), "loop_chunk") if lib is not None else None
        _CACHE[spec] = (step, chunk, names, sizes, est, nin, cf)
    return _CACHE[spec]


def compiled_loop_run(params: VehicleParams, maneuver: Maneuver, *, plant: str = "two-track",
                      controller: str = "two-dof", estimator: str = "dakf", sensors: SensorConfig | None = None,
                      disturbances: Disturbances | None = None, seed: int = 0, dt: float = 1e-3,
                      design: TwoDofDesign | None = None, nominal: VehicleParams | None = None) -> dict:
    """Run the stability loop compiled; returns ``t``, ``truth`` and ``commands`` (as the simulator names them)."""
    if not maneuver.open_loop:
        raise ValueError("the compiled loop takes open-loop steer manoeuvres (no path driver)")
    sensors = sensors or SensorConfig()
    if abs(sensors.gps_latency / dt - round(sensors.gps_latency / dt)) > 1e-9:
        raise ValueError("the compiled loop needs a GPS latency that is a whole number of samples")
    disturbances = disturbances or Disturbances(friction=Friction(mu=params.mu))
    spec = LoopSpec(plant, params, float(dt), controller, None if controller == "two-dof-true" else estimator,
                    sensors, disturbances.friction.mu, design, nominal)
    step, chunk, names, sizes, est, nin, cf = _compiled(spec)
    model = get_plant(plant)
    n = int(round(maneuver.duration / dt))
    t = np.arange(n) * dt
    W = disturbance_profile(disturbances, t)
    U = np.zeros((n, nin))
    U[:, 0] = maneuver.steer(t)
    U[:, 1] = maneuver.speed
    U[:, 2] = maneuver.drive_on(t)
    U[:, 3:3 + len(DISTURBANCES)] = W.T
    U[:, 3 + len(DISTURBANCES):nin - 1] = _noise_matrix(sensors, seed, n).T
    U[:, nin - 1] = gps_fix_mask(t, sensors)
    x0 = model.initial_state(params, maneuver.speed)
    cp = compiled_plant(model, params, dt)
    _, y0 = cp.step(x0, np.array([0.0, 0.0, maneuver.speed, 1.0]), W[:, 0])
    z0 = np.zeros(sum(sizes))
    z0[:sizes[0]] = x0
    if est is not None:
        z0[sizes[0]:sizes[0] + sizes[1]] = kal_mod.initial_state(est, 0.0, 0.0)
    off = sum(sizes[:4])
    z0[off:off + len(TRUTH)] = y0
    if sizes[7]:
        first = np.array([y0[TRUTH.index(k)] for k in ("yaw", "vx", "vy", "yaw_rate")])
        z0[sum(sizes[:7]):] = np.tile(first, sizes[7] // 4)
    pv = param_vector(params, names)
    n_pad = -(-n // CHUNK) * CHUNK
    Up = np.empty((n_pad, nin))
    Up[:n] = U
    Up[n:] = U[-1]
    Y = np.empty((n_pad, len(TRUTH)))
    E = np.empty((n_pad, len(EXTRA)))
    z = z0.copy()
    if cf is not None:
        zn = np.empty_like(z)
        for s in range(0, n_pad, CHUNK):
            cf([z, Up.ctypes.data + s * Up.strides[0], pv],
               [zn, Y.ctypes.data + s * Y.strides[0], E.ctypes.data + s * E.strides[0]])
            z, zn = zn, z
    else:
        for s in range(0, n_pad, CHUNK):
            zs, ys, es = chunk(z, Up[s:s + CHUNK].T, pv)
            z = np.array(zs).ravel()
            Y[s:s + CHUNK], E[s:s + CHUNK] = np.array(ys).T, np.array(es).T
    truth = {name: Y[:n, i] for i, name in enumerate(TRUTH)}
    commands = {name: E[:n, i] for i, name in enumerate(EXTRA)}
    return {"t": t, "truth": truth, "commands": commands}
