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
import dataclasses
from dataclasses import dataclass

import casadi as ca
import numpy as np

import controllers.actuators as act_mod
import controllers.two_dof as ctl_mod
from controllers.actuators import ActuatorLimits, actuator_law
from controllers.two_dof import TwoDofDesign, control_law
from plants import DISTURBANCES, TRUTH, VehicleParams, get_plant, truth_params
from plants.backend import CASADI
from plants.disturbances import Disturbances, Friction, disturbance_profile
from plants.maneuvers import Maneuver
from plants.sensors import SensorConfig, draw_noise, gps_fix_mask, readings

from .compiled import (CFunction, build_step, cache_key, compile_library, numeric_fields, param_vector,
                       rk4_substeps, symbolic_view, with_fields)
from .estimation import design_filter
from .estimation.spec import FilterDesign, NoiseSettings
from .estimation import kalman as kal_mod

NOISE = ("steer", "gyro", "roll_gyro", "accel_x", "accel_y", "wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr",
         "speed", "gps_e", "gps_n", "heading")
EXTRA = ("steer", "yaw_moment", "steer_driver", "yaw_moment_cmd", "beta_ref", "yaw_rate_ref", "beta_est",
         "yaw_rate_est", "yaw_moment_limited")
THETA = ("k_beta", "k_gamma", "q_beta", "q_yaw_rate", "q_d1", "q_d2", "gyro_bias", "gyro_scale_error", "mu_assumed")
"""Run-time parameters of a compiled loop (no recompilation when they change): the design's
gains and process-noise intensities (what the tuning chooses) and the case's gyro errors and
the friction the reference assumes. The plant's parameters are run-time too (``p``)."""
SLOTS = 4
"""GPS fixes in flight at once (latched truth waiting for its latency to pass)."""
CHUNK = 1000


@dataclass(frozen=True)
class LoopSpec:
    """What is compiled into a loop: structure, the designer's beliefs, the sensor set-up.

    Everything that varies across a model-error sweep (plant parameters, speed,
    friction, GPS rate and latency, gyro errors, gains, noise intensities) is a
    run-time input, so one compiled library serves a whole sweep.
    """

    plant: str
    nominal: VehicleParams
    """What the controller and the estimator believe."""
    fields: tuple[str, ...]
    """Names of the plant parameter vector (the set numeric fields of the plant's parameters)."""
    dt: float
    controller: str
    estimator: FilterDesign | None
    design: TwoDofDesign
    sensors: SensorConfig
    """Sensor set-up with the run-time parts (latency, gyro bias and scale) zeroed."""
    n_sub: int


def _noise_matrix(cfg: SensorConfig, seed: int, n: int) -> np.ndarray:
    nz = draw_noise(cfg, seed, n)
    rows = [nz["steer"], nz["gyro"], nz["roll_gyro"], nz["accel"][0], nz["accel"][1], *nz["wheel"], nz["speed"],
            nz["gps"][0], nz["gps"][1], nz["heading"]]
    return np.vstack(rows)


def n_inputs() -> int:
    return 3 + len(DISTURBANCES) + len(NOISE) + 1 + 2 * SLOTS


def _build(spec: LoopSpec):
    model = get_plant(spec.plant)
    n_sub = spec.n_sub
    template = spec.nominal
    plant_step, names = build_step(model, template, spec.dt, n_sub)
    if names != spec.fields:
        raise ValueError(f"plant parameter fields differ from the nominal set: {names} vs {spec.fields}")
    th = ca.SX.sym("theta", len(THETA))
    thd = {k: th[i] for i, k in enumerate(THETA)}
    est = spec.estimator
    if est is not None:
        est = with_fields(est, noise=with_fields(est.noise, q_beta=thd["q_beta"], q_yaw_rate=thd["q_yaw_rate"],
                                     q_d1=thd["q_d1"], q_d2=thd["q_d2"]))
    ctl = with_fields(spec.design, k_beta=thd["k_beta"], k_gamma=thd["k_gamma"])
    sensors = with_fields(spec.sensors, gyro_bias=thd["gyro_bias"], gyro_scale_error=thd["gyro_scale_error"])
    lim = ActuatorLimits()
    nx, nt = len(model.states), len(TRUTH)
    ne = kal_mod.layout(est)["size"] if est is not None else 0
    sizes = [nx, ne, len(ctl_mod.STATE), len(act_mod.STATE), nt, 2, 2, 4 * SLOTS]
    Z = ca.SX.sym("z", sum(sizes))
    parts, o = [], 0
    for s in sizes:
        parts.append(Z[o:o + s])
        o += s
    x, z_est, z_ctl, z_act, y_prev, applied, flags, slots = parts
    nin = n_inputs()
    U = ca.SX.sym("u", nin)
    steer_drv, speed_ref, drive_on = U[0], U[1], U[2]
    w = U[3:3 + len(DISTURBANCES)]
    i0 = 3 + len(DISTURBANCES)
    nzv = U[i0:i0 + len(NOISE)]
    fix = U[i0 + len(NOISE)]
    capture = U[i0 + len(NOISE) + 1:i0 + len(NOISE) + 1 + SLOTS]
    emit = U[i0 + len(NOISE) + 1 + SLOTS:nin]
    pv = ca.SX.sym("p", len(names))
    sp = symbolic_view(template, names, pv)
    tr = {name: y_prev[i] for i, name in enumerate(TRUTH)}
    nzd = {k: nzv[i] for i, k in enumerate(NOISE)}
    noise = {"steer": nzd["steer"], "gyro": nzd["gyro"], "roll_gyro": nzd["roll_gyro"], "accel_x": nzd["accel_x"],
             "accel_y": nzd["accel_y"], "wheel": [nzd[f"wheel_{c}"] for c in ("fl", "fr", "rl", "rr")],
             "speed": nzd["speed"], "gps_e": nzd["gps_e"], "gps_n": nzd["gps_n"], "heading": nzd["heading"]}
    inp = {"steer": applied[0], "yaw_moment": applied[1], "bank": w[DISTURBANCES.index("bank")]}
    radius = sp.wheel_radius if model.name == "two-track" or template.wheel_radius is not None else None
    now = ca.vertcat(tr["yaw"], tr["vx"], tr["vy"], tr["yaw_rate"])
    # GPS latency: the truth a fix describes is latched into a slot when it is measured and read
    # out when the fix arrives (both one-hot inputs computed from the fix times), so the latency
    # is a run-time input; exact for whole-sample latencies
    gps = [0.0 * now[0]] * 4
    nxt = []
    for j in range(SLOTS):
        slot = slots[4 * j:4 * j + 4]
        held = capture[j] * now + (1.0 - capture[j]) * slot
        nxt.append(held)
        gps = [gps[i] + emit[j] * held[i] for i in range(4)]
    slots_next = ca.vertcat(*nxt)
    m = readings(tr, inp, noise, tuple(gps), fix, sensors, radius, CASADI)
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
    sig = ca.vertcat(m["speed"], steer_drv, beta, r, d1, d2, thd["mu_assumed"], flags[0], flags[1])
    z_ctl_n, u = control_law(ctl, z_ctl, sig, CASADI)
    tmax = lim.torque_max if lim.torque_max is not None else (sp.max_motor_torque
                                                              if template.max_motor_torque is not None else 1e9)
    z_act_n, a = actuator_law(sp, lim, tmax, z_act, ca.vertcat(u[0], u[1], 0.0, dt), CASADI)
    cmd = ca.vertcat(a[0], a[1], speed_ref, drive_on, (a[0] - applied[0]) / dt)
    x_n, y_k = plant_step(x, cmd, w, pv)
    Zn = ca.vertcat(x_n, z_est_n, z_ctl_n, z_act_n, y_k, a[0], a[1], a[2], a[3], slots_next)
    extra = ca.vertcat(a[0], a[1], steer_drv, u[1], u[2], u[3], beta, r, a[3])
    step = ca.Function("loop_step", [Z, U, pv, th], [Zn, y_k, extra])
    acc = step.mapaccum("loop_acc", CHUNK)
    z0, Uc = ca.MX.sym("z0", Z.shape[0]), ca.MX.sym("U", nin, CHUNK)
    pm, tm = ca.MX.sym("p", len(names)), ca.MX.sym("theta", len(THETA))
    Zs, Ys, Es = acc(z0, Uc, ca.repmat(pm, 1, CHUNK), ca.repmat(tm, 1, CHUNK))
    chunk = ca.Function("loop_chunk", [z0, Uc, pm, tm], [Zs[:, -1], Ys, Es])
    return step, chunk, names, sizes, est, nin


_CACHE: dict = {}


class LoopProgram:
    """A compiled loop for one :class:`LoopSpec`; :meth:`run` takes everything that varies by case."""

    def __init__(self, spec: LoopSpec):
        self.spec = spec
        self.step, self.chunk, self.names, self.sizes, self.est, self.nin = _build(spec)
        key = cache_key("loop", spec, CHUNK, SLOTS)
        lib = compile_library([self.chunk], key)
        self.cf = CFunction(ctypes.CDLL(str(lib)), "loop_chunk") if lib is not None else None
        self.model = get_plant(spec.plant)

    def theta(self, *, k_beta=None, k_gamma=None, noise: NoiseSettings | None = None, gyro_bias: float = 0.0,
              gyro_scale_error: float = 0.0, mu_assumed: float = 1.0) -> np.ndarray:
        d = self.spec.design
        nz = noise or (self.spec.estimator.noise if self.spec.estimator is not None else NoiseSettings())
        vals = {"k_beta": d.k_beta if k_beta is None else k_beta, "k_gamma": d.k_gamma if k_gamma is None else k_gamma,
                "q_beta": nz.q_beta, "q_yaw_rate": nz.q_yaw_rate, "q_d1": nz.q_d1, "q_d2": nz.q_d2,
                "gyro_bias": gyro_bias, "gyro_scale_error": gyro_scale_error, "mu_assumed": mu_assumed}
        return np.array([float(vals[k]) for k in THETA])

    def inputs(self, params: VehicleParams, maneuver: Maneuver, disturbances: Disturbances, sensors: SensorConfig,
               seed: int):
        """(U, z0, p) for a run: the input matrix (samples x inputs), initial loop state, plant parameters."""
        dt = self.spec.dt
        n = int(round(maneuver.duration / dt))
        t = np.arange(n) * dt
        W = disturbance_profile(disturbances, t)
        nin = self.nin
        U = np.zeros((n, nin))
        U[:, 0] = maneuver.steer(t)
        U[:, 1] = maneuver.speed
        U[:, 2] = maneuver.drive_on(t)
        i0 = 3 + len(DISTURBANCES)
        U[:, 3:i0] = W.T
        U[:, i0:i0 + len(NOISE)] = _noise_matrix(sensors, seed, n).T
        fix = gps_fix_mask(t, sensors)
        U[:, i0 + len(NOISE)] = fix
        U[:, i0 + len(NOISE) + 1:] = latch_schedule(fix, sensors.gps_latency, dt).T
        if rk4_substeps(self.model, params, dt) > self.spec.n_sub:
            raise ValueError(f"'{params.name}': these plant parameters need {rk4_substeps(self.model, params, dt)} "
                             f"RK4 sub-steps per sample, the compiled loop has {self.spec.n_sub}")
        x0 = self.model.initial_state(params, maneuver.speed)
        # the truth the sensors read on the first sample, by the numpy form of the same output
        # equation (building a compiled plant per parameter set would cost 80 ms per case)
        cmd0 = np.array([0.0, 0.0, maneuver.speed, 1.0, 0.0])
        y0 = np.asarray(self.model.h(x0, self.model.command_map(cmd0, x0, params), W[:, 0], params), float).ravel()
        sizes = self.sizes
        z0 = np.zeros(sum(sizes))
        z0[:sizes[0]] = x0
        if self.est is not None:
            z0[sizes[0]:sizes[0] + sizes[1]] = kal_mod.initial_state(self.est, 0.0, 0.0)
        off = sum(sizes[:4])
        z0[off:off + len(TRUTH)] = y0
        first = np.array([y0[TRUTH.index(k)] for k in ("yaw", "vx", "vy", "yaw_rate")])
        z0[sum(sizes[:7]):] = np.tile(first, SLOTS)
        names = numeric_fields(params)
        if names != self.names:
            raise ValueError(f"'{params.name}': the plant parameters set differ from the compiled loop's "
                             f"({sorted(set(names) ^ set(self.names))})")
        return U, z0, param_vector(params, names)

    def run(self, U: np.ndarray, z0: np.ndarray, pv: np.ndarray, theta: np.ndarray, final_state: bool = False):
        """Roll the loop out over ``U``; returns (truth Y, extra E) as samples x signals arrays, and with
        ``final_state`` the loop state after the last sample too (to continue a run block by block;
        ``U``'s length must then be a multiple of :data:`CHUNK`, so no padded sample advances it)."""
        if final_state and U.shape[0] % CHUNK:
            raise ValueError(f"final_state needs a multiple of {CHUNK} samples, got {U.shape[0]}")
        n, nin = U.shape
        n_pad = -(-n // CHUNK) * CHUNK
        Up = np.empty((n_pad, nin))
        Up[:n] = U
        Up[n:] = U[-1]
        Y = np.empty((n_pad, len(TRUTH)))
        E = np.empty((n_pad, len(EXTRA)))
        z = np.array(z0, float)
        theta = np.ascontiguousarray(theta, float)
        pv = np.ascontiguousarray(pv, float)
        if self.cf is not None:
            zn = np.empty_like(z)
            for s in range(0, n_pad, CHUNK):
                self.cf([z, Up.ctypes.data + s * Up.strides[0], pv, theta],
                        [zn, Y.ctypes.data + s * Y.strides[0], E.ctypes.data + s * E.strides[0]])
                z, zn = zn, z
        else:
            for s in range(0, n_pad, CHUNK):
                zs, ys, es = self.chunk(z, Up[s:s + CHUNK].T, pv, theta)
                z = np.array(zs).ravel()
                Y[s:s + CHUNK], E[s:s + CHUNK] = np.array(ys).T, np.array(es).T
        if final_state:
            return Y[:n], E[:n], z
        return Y[:n], E[:n]


def latch_schedule(fix: np.ndarray, latency: float, dt: float) -> np.ndarray:
    """One-hot capture and emit signals (2 SLOTS x samples) for fixes arriving ``latency`` late.

    The fix at sample k describes the truth the sensors saw at sample k - lag (clamped to the
    first sample). Fix i uses slot i mod SLOTS; a slot must not be captured again before its
    fix has been emitted.
    """
    lag = latency / dt
    if abs(lag - round(lag)) > 1e-9 or lag < 0:
        raise ValueError(f"the compiled loop needs a GPS latency of whole samples >= 0, got {latency} s at dt {dt} s")
    lag = int(round(lag))
    n = len(fix)
    out = np.zeros((2 * SLOTS, n))
    ks = np.nonzero(np.asarray(fix) > 0.5)[0]
    caps = np.maximum(ks - lag, 0)
    for i, (k, c) in enumerate(zip(ks, caps)):
        j = i % SLOTS
        if i >= SLOTS and caps[i] <= ks[i - SLOTS]:
            raise ValueError(f"GPS latency {latency} s spans more than {SLOTS - 1} fix periods; "
                             f"the compiled loop holds at most {SLOTS} fixes in flight")
        out[j, c] = 1.0
        out[SLOTS + j, k] = 1.0
    return out


def loop_spec(nominal: VehicleParams, *, plant: str = "two-track", controller: str = "two-dof",
              estimator: str | FilterDesign | None = "dakf", sensors: SensorConfig | None = None, dt: float = 1e-3,
              design: TwoDofDesign | None = None, estimator_latency: float = 0.0,
              n_sub: int | None = None) -> LoopSpec:
    """The compile-time part of a loop (see :class:`LoopSpec`)."""
    model = get_plant(plant)
    sensors = sensors or SensorConfig()
    if controller not in ("two-dof", "two-dof-true"):
        raise ValueError(f"the compiled loop runs the 'two-dof' or 'two-dof-true' controller, not '{controller}'")
    if controller == "two-dof-true" or estimator is None:
        est = None
    elif isinstance(estimator, FilterDesign):
        est = estimator
    else:
        est = design_filter(estimator, nominal, dt=dt, latency=estimator_latency)
    ctl = design if design is not None else TwoDofDesign(nominal.as_nominal(), dt=dt)
    base = dataclasses.replace(sensors, gps_latency=0.0, gyro_bias=0.0, gyro_scale_error=0.0)
    n_sub = n_sub if n_sub is not None else rk4_substeps(model, nominal, dt)
    return LoopSpec(model.name, nominal, numeric_fields(nominal), float(dt), controller, est, ctl, base, int(n_sub))


def program(spec: LoopSpec) -> LoopProgram:
    if spec not in _CACHE:
        _CACHE[spec] = LoopProgram(spec)
    return _CACHE[spec]


def compiled_loop_run(params: VehicleParams, maneuver: Maneuver, *, plant: str = "two-track",
                      controller: str = "two-dof", estimator: str | FilterDesign = "dakf",
                      sensors: SensorConfig | None = None, disturbances: Disturbances | None = None, seed: int = 0,
                      dt: float = 1e-3, design: TwoDofDesign | None = None, nominal: VehicleParams | None = None,
                      estimator_latency: float | None = None, mu_assumed: float | None = None) -> dict:
    """Run the stability loop compiled; returns ``t``, ``truth`` and ``commands`` (as the simulator names them).

    ``estimator_latency`` is the GPS latency the estimator compensates (default: the
    sensors' true latency, as the simulator assumes).
    """
    if not maneuver.open_loop:
        raise ValueError("the compiled loop takes open-loop steer manoeuvres (no path driver)")
    sensors = sensors or SensorConfig()
    disturbances = disturbances or Disturbances(friction=Friction(mu=params.mu))
    nom = nominal if nominal is not None else params
    params = truth_params(plant, params)
    lat = sensors.gps_latency if estimator_latency is None else estimator_latency
    model = get_plant(plant)
    spec = loop_spec(nom, plant=plant, controller=controller, estimator=estimator, sensors=sensors, dt=dt,
                     design=design, estimator_latency=lat, n_sub=rk4_substeps(model, params, dt))
    prog = program(spec)
    U, z0, pv = prog.inputs(params, maneuver, disturbances, sensors, seed)
    theta = prog.theta(gyro_bias=sensors.gyro_bias, gyro_scale_error=sensors.gyro_scale_error,
                       mu_assumed=disturbances.friction.mu if mu_assumed is None else mu_assumed)
    Y, E = prog.run(U, z0, pv, theta)
    t = np.arange(U.shape[0]) * dt
    return {"t": t, "truth": {name: Y[:, i] for i, name in enumerate(TRUTH)},
            "commands": {name: E[:, i] for i, name in enumerate(EXTRA)}}
