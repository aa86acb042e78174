"""The stability loop, closed in one place: :func:`loop_step`.

One sample of the loop, written once for numpy and casadi:

1. the sensors sample the plant at the start of the period (truth ``h(x_k)`` with the commands
   applied over the last period; gyro errors, noise, GPS course of the latched truth when a fix
   arrives ``gps_latency`` late);
2. the ECU step runs on those readings: the firmware's :func:`toolkit.ecu.step.ecu_step`
   (filter, then the 2-DOF law, speed-scheduled from tables, calibration as run-time inputs),
   or one of its variants (:class:`LoopEcu`);
3. the actuators (steer servo lag and limits, motor torque limits and rate) turn the ECU's
   commands into what is applied over the period (zero-order hold);
4. the plant is integrated over the period (RK4, ``n_sub`` sub-steps).

Everything that runs a loop runs this function: the simulator evaluates it sample by sample
(numpy, or the compiled step when a path driver closes an outer loop around it), the compiled
rollouts trace it once into a casadi function and compile that to a lane kernel
(:mod:`toolkit.kernels.lanes`: many cases per call, the time loop in C) for sweeps, FMVSS 126 and the
soak run, the tuning rolls it out by ``mapaccum`` and differentiates it, and the stability
analysis differentiates the same
trace (:meth:`toolkit.loop.loop_program.LoopProgram.jacobian`, :func:`toolkit.design.stability.estimator_loop`). The compiled
program (:class:`toolkit.loop.loop_program.LoopProgram`, :func:`toolkit.loop.loop_program.program`) builds on this module.

The driver stays outside the step: its road-wheel angle command is an input (``steer_driver``),
read from an open-loop profile or computed between steps by the path follower.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import casadi as ca
import numpy as np

import evstab.controllers.supervisor as sup_mod
import evstab.controllers.two_dof as ctl_mod
from evstab.controllers.actuators import (OUTPUTS as ACT_OUTPUTS, SIGNALS as ACT_SIGNALS, STATE as ACT_STATE,
                                          ActuatorLimits, actuator_law)
from evstab.controllers import brakes as brakes_mod
from evstab.controllers.baselines import STATE as YAW_PI_STATE
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import COMMANDS, DISTURBANCES, TRUTH, PlantModel, VehicleParams, get_plant, truth_params
from evstab.plants.errors import ParameterError
from evstab.plants.model import brake_yaw_moment
from evstab.plants.backend import CASADI, NUMPY, call_nodes
from evstab.plants.disturbances import Disturbances, disturbance_profile
from evstab.plants.maneuvers import Maneuver
from evstab.plants.sensors import SensorConfig, gps_fix_mask, noise_rows, readings
from evstab.plants.signals import Layout, Signal

from ..kernels.compiled import numeric_fields, param_vector, rk4_step, rk4_substeps, symbolic_view, with_fields
from .ecu_faults import FAULT_PARAMS, fault_parameters
from ..kernels import lanes as lanes_mod
from ..estimation import kalman as kal_mod
from ..estimation.spec import FilterDesign
from ..ecu import guard as guard_mod
from ..ecu.step import INPUTS as ECU_INPUTS, OUTPUTS as ECU_OUTPUTS, EcuDesign
from .loop_ecu import CONTROLLERS, LoopEcu, LoopError, loop_ecu  # noqa: F401  (the loop's public names)

NOISE = Layout("loop noise", [Signal(k, "-", f"standard-normal draw of the {k} sensor's noise") for k in (
    "steer", "gyro", "roll_gyro", "accel_x", "accel_y", "wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr", "speed",
    "gps_e", "gps_n", "heading")])
NOISE_STREAMS = ("steer", "gyro", "roll_gyro", "accel", "wheel", "speed", "gps", "heading")
"""The sensor noise streams whose rows make :data:`NOISE`, in its order (:func:`noise_matrix`)."""
EXTRA = Layout("loop signals", [
    Signal("steer", "rad", "road-wheel angle applied over the period"),
    Signal("yaw_moment", "N m", "yaw moment the motors achieved"),
    Signal("steer_driver", "rad", "the driver's road-wheel angle"),
    Signal("yaw_moment_cmd", "N m", "the ECU's yaw moment command"),
    Signal("beta_ref", "rad", "sideslip reference"),
    Signal("yaw_rate_ref", "rad/s", "yaw-rate reference"),
    Signal("beta_est", "rad", "estimated sideslip"),
    Signal("yaw_rate_est", "rad/s", "estimated yaw rate"),
    Signal("yaw_moment_limited", "-", "1 while the motors were at a limit"),
    Signal("steer_cmd", "rad", "the ECU's road-wheel angle command"),
    Signal("steer_limited", "-", "1 while the steer was at a limit"),
    Signal("steer_limited_last", "-", "the steer limit flag the ECU was given"),
    Signal("yaw_moment_limited_last", "-", "the motors' limit flag the ECU was given"),
    Signal("steer_rate", "rad/s", "rate of the applied road-wheel angle"),
    Signal("active", "-", "authority of the stability law"),
    Signal("mu_est", "-", "the ECU's friction estimate"),
    Signal("fault_word", "-", "the ECU's fault word (toolkit.ecu.guard.FAULT_BITS)"),
    Signal("drive_share", "-", "share of the driver's drive torque the ECU let through"),
    *(Signal(f"brake_{c}", "N m", f"the {c} wheel brake's torque over the period (0 without an allocation to the "
             "brakes)") for c in brakes_mod.WHEELS),
    Signal("yaw_moment_brakes_cmd", "N m", "the yaw moment the ECU's brake pressures make before the slip limiter"),
])
"""Per-sample loop signals besides the truth: applied commands, driver, ECU outputs, limit flags."""
MEAS = Layout("loop readings", [
    Signal("steer", "rad", "measured road-wheel angle"), Signal("yaw_moment", "N m", "yaw moment applied"),
    Signal("yaw_rate", "rad/s", "gyro"), Signal("roll_rate", "rad/s", "roll gyro"),
    Signal("ax", "m/s^2", "longitudinal accelerometer"), Signal("ay", "m/s^2", "lateral accelerometer"),
    *(Signal(f"wheel_speed_{c}", "rad/s", f"{c} wheel speed") for c in ("fl", "fr", "rl", "rr")),
    Signal("speed", "m/s", "speed from the non-driven wheels"), Signal("gps_valid", "-", "1 on a usable fix"),
    Signal("gps_fix", "-", "1 on a sample with a fix"), Signal("gps_course", "rad", "GPS course over ground"),
    Signal("gps_speed", "m/s", "GPS ground speed"), Signal("gps_heading", "rad", "dual-antenna heading"),
])
"""The sensor readings the ECU was given (drive-log columns; GPS entries meaningful where ``gps_fix``)."""
CASE = Layout("case parameters", [
    Signal("gyro_bias", "rad/s", "the gyro's bias"),
    Signal("gyro_scale_error", "-", "the gyro's scale-factor error"),
    Signal("mu_assumed", "-", "the friction the ECU's mu input gives"),
])
"""Run-time parameters of a case after the ECU's calibration: the gyro's errors and the friction
the ECU's reference assumes (an ECU input)."""
SLOTS = 4
"""GPS fixes in flight at once (latched truth waiting for its latency to pass)."""
SLOT = Layout("GPS slot", [Signal("yaw", "rad"), Signal("vx", "m/s"), Signal("vy", "m/s"), Signal("yaw_rate", "rad/s")])
"""The truth a GPS fix in flight describes (latched when it is measured)."""
GPS_SLOTS = Layout("GPS slots", [Signal(f"slot{j}", "-", "a fix in flight (SLOT)", SLOT.size) for j in range(SLOTS)])
INPUTS = Layout("loop inputs", [
    Signal("steer_driver", "rad", "the driver's road-wheel angle"),
    Signal("speed_ref", "m/s", "speed reference"),
    Signal("drive_on", "-", "1 = hold speed, 0 = coast"),
    Signal("disturbances", "-", "disturbances (plants.DISTURBANCES)", DISTURBANCES.size),
    Signal("noise", "-", "standard-normal sensor noise (NOISE)", NOISE.size),
    Signal("fix", "-", "1 on a sample with a GPS fix"),
    Signal("capture", "-", "one-hot: latch this sample's truth into slot j", SLOTS),
    Signal("emit", "-", "one-hot: the fix arriving now is slot j's", SLOTS),
])
"""The loop's per-sample inputs."""
APPLIED = Layout("applied commands", [
    Signal("steer", "rad", "road-wheel angle applied over the last period"),
    Signal("yaw_moment", "N m", "yaw moment achieved over the last period"),
    Signal("steer_rate", "rad/s", "rate of the applied road-wheel angle"),
    Signal("drive_cut", "-", "share of the driver's drive torque the ECU took away over the last period"),
])
FLAGS = Layout("actuator flags", [Signal("steer_limited", "-", "last period's steer limit flag"),
                                  Signal("yaw_moment_limited", "-", "last period's motor limit flag")])
CHUNK = 1000


# ------------------------------------------------------------------------------ the loop step
@dataclass(frozen=True)
class LoopSpec:
    """What is traced into a loop: plant structure, ECU, sensor set-up, actuators.

    Everything that varies across a sweep (plant parameters, speed, friction, GPS rate and
    latency, gyro errors, the ECU's calibration: gains and noise intensities) is a run-time
    input, so one compiled library serves a whole sweep.
    """

    plant: str
    fields: tuple[str, ...]
    """The plant parameters' set fields (:func:`toolkit.kernels.compiled.numeric_fields`): their values are run-time."""
    dt: float
    ecu: LoopEcu
    sensors: SensorConfig
    """Sensor set-up with the run-time parts (latency, gyro bias and scale) zeroed."""
    n_sub: int
    limits: ActuatorLimits = ActuatorLimits()
    ecu_faults: bool = False
    """Trace the fault injector between the sensors and the ECU (:data:`FAULT_PARAMS`: run-time parameters;
    a sample clock and each input's held value in the loop state)."""

    def __post_init__(self):
        if self.brakes:
            lacks = [f for f in brakes_mod.FIELDS + ("track_front", "track_rear", "wheel_radius") if f not in self.fields]
            if lacks:
                raise ParameterError(f"{self.plant}: an ECU that shares its yaw moment with the friction brakes needs "
                                     f"the car's vehicle parameter(s) {', '.join(lacks)}; add them to the [vehicle] "
                                     "table")

    @functools.cached_property
    def state_layout(self) -> Layout:
        """Loop state: plant, ECU, actuators, applied commands (:data:`APPLIED`), limit flags
        (:data:`FLAGS`), GPS slots (:data:`GPS_SLOTS`); with ``ecu_faults`` the fault injector's."""
        faults = [Signal("faults", "-", "the fault injector's sample clock and each ECU input's held value",
                         1 + ECU_INPUTS.size)] if self.ecu_faults else []
        return Layout("loop state", [
            Signal("plant", "-", "the plant's state", len(get_plant(self.plant).states)),
            Signal("ecu", "-", "the ECU's state", self.ecu.n_state),
            Signal("actuator", "-", "the actuators' state (controllers.actuators.STATE)", ACT_STATE.size),
            Signal("applied", "-", "APPLIED", APPLIED.size),
            Signal("flags", "-", "FLAGS", FLAGS.size),
            Signal("slots", "-", "GPS_SLOTS", GPS_SLOTS.size),
            *faults,
            *([Signal("brakes", "-", "the wheel brakes' pressures (controllers.brakes.STATE)", brakes_mod.STATE.size)]
              if self.brakes else []),
        ])

    @property
    def brakes(self) -> bool:
        """Whether the ECU shares its yaw moment with the friction brakes (an allocation not ``motors``): the loop
        then runs the hydraulic unit (:func:`controllers.brakes.brake_law`) and the plant's brakes."""
        return self.ecu.ecu is not None and self.ecu.ecu.brakes

    @property
    def sizes(self) -> list[int]:
        """The sizes of the parts of :attr:`state_layout`."""
        return [s.size for s in self.state_layout.signals]

    @functools.cached_property
    def theta_layout(self) -> Layout:
        """The run-time parameters: the ECU's calibration, then :data:`CASE`; with ``ecu_faults`` the fault's
        window (``fault_start``, ``fault_end`` [s]), ``fault_reset`` (1: the ECU resets, booting through the
        window) and :data:`FAULT_PARAMS` per ECU input."""
        faults = [Signal("fault_start", "s"), Signal("fault_end", "s"), Signal("fault_reset")] + [
            Signal(f"fault_{k}_{n}") for n in ECU_INPUTS for k in FAULT_PARAMS] if self.ecu_faults else []
        return Layout("loop parameters", [Signal(n) for n in self.ecu.calibration_names()] + list(CASE.signals)
                      + faults)

    @property
    def theta_names(self) -> tuple[str, ...]:
        return tuple(self.theta_layout)

    def state_names(self) -> tuple[str, ...]:
        """Names of the loop-state entries (``plant.*``, ``filter.*``, ``controller.*``, ``actuator.*``,
        ``applied.*``, ``flag.*``, ``slotJ.*``)."""
        model = get_plant(self.plant)
        names = [f"plant.{s}" for s in model.states]
        ne, nc = self.ecu.sizes
        if ne:
            f = self.ecu.design.filter
            for s in kal_mod.layout(f).signals:
                if s.name == "x":
                    names += [f"filter.{k}" for k in f.states]
                elif s.size == 1:
                    names.append(f"filter.{s.name}")
                else:
                    names += [f"filter.{s.name}{i}" for i in range(s.size)]
        if nc:
            names += [f"controller.{s}" for s in (YAW_PI_STATE if self.ecu.kind == "yaw-pi" else ctl_mod.STATE)]
            if self.ecu.kind != "yaw-pi":
                names += [f"supervisor.{s}" for s in sup_mod.STATE]
            names += [f"guard.{s}" for s in guard_mod.STATE]
        names += [f"actuator.{k}" for k in ACT_STATE] + [f"applied.{k}" for k in APPLIED]
        names += [f"flag.{k}" for k in FLAGS]
        names += [f"{j}.{k}" for j in GPS_SLOTS for k in SLOT]
        if self.ecu_faults:
            names += ["faults.clock"] + [f"faults.held_{n}" for n in ECU_INPUTS]
        if self.brakes:
            names += [f"brakes.{k}" for k in brakes_mod.STATE]
        if len(names) != sum(self.sizes):
            raise LoopError(f"loop state names ({len(names)}) do not match the loop state ({sum(self.sizes)})")
        return tuple(names)


def n_inputs() -> int:
    return INPUTS.size


def loop_step(spec: LoopSpec, model: PlantModel, sp, z, u, theta, o=NUMPY):
    """One sample of the loop: ``(z, u, p, theta) -> (z_next, truth, extra, meas)``.

    ``z`` per :attr:`LoopSpec.state_layout`; ``u`` per :data:`INPUTS`; ``sp`` the plant's
    parameters (a :class:`VehicleParams` or its symbolic view); ``theta`` per
    :attr:`LoopSpec.theta_names`. Returns the truth at the sample (:data:`plants.TRUTH`, with the
    commands of the last period), :data:`EXTRA` and :data:`MEAS`.
    """
    zs = spec.state_layout.unpack(z)
    x, z_ecu, z_act = zs.plant, zs.ecu, zs.actuator
    applied, flags, slots = APPLIED.unpack(zs.applied), FLAGS.unpack(zs.flags), GPS_SLOTS.unpack(zs.slots)
    ui = INPUTS.unpack(u)
    steer_drv, speed_ref, drive_on, w = ui.steer_driver, ui.speed_ref, ui.drive_on, ui.disturbances
    nzd = NOISE.as_dict(ui.noise)
    fix = ui.fix
    capture = [ui.capture[j] for j in range(SLOTS)]
    emit = [ui.emit[j] for j in range(SLOTS)]
    th = spec.theta_layout.as_dict(theta)
    cal = [th[k] for k in spec.ecu.calibration_names()]
    case = {k: th[k] for k in CASE}
    dt = spec.dt

    # 1. sensors sample the plant at the start of the period
    brakes_prev = {}
    if spec.brakes:  # the brakes' torques over the last period: the hydraulic unit's pressures times their gains
        z_brk = zs.brakes
        brake_torques = [k * z_brk[i] for i, k in enumerate(brakes_mod.gains(sp))]
        nz_brakes_applied = brake_yaw_moment(brake_torques, sp.wheel_radius, sp.track_front, sp.track_rear)
        brakes_prev = {f"brake_{c}": t for c, t in zip(brakes_mod.WHEELS, brake_torques)}
    cmd_prev = COMMANDS.pack(o=o, steer=applied.steer, yaw_moment=applied.yaw_moment, speed_ref=speed_ref,
                             drive_on=drive_on * (1.0 - applied.drive_cut), steer_rate=applied.steer_rate,
                             **brakes_prev)
    y = model.h(x, model.command_map(cmd_prev, x, sp), w, sp)
    tr = TRUTH.as_dict(y)
    # GPS latency: the truth a fix describes is latched into a slot when it is measured and read
    # out when the fix arrives (one-hot inputs computed from the fix times): exact for latencies of
    # whole samples, and a run-time input
    gps = {k: 0.0 * tr["yaw"] for k in SLOT}
    nxt = {}
    for j, name in enumerate(GPS_SLOTS):
        before = SLOT.as_dict(getattr(slots, name))
        held = {k: capture[j] * tr[k] + (1.0 - capture[j]) * before[k] for k in SLOT}
        nxt[name] = SLOT.pack(held, o)
        gps = {k: gps[k] + emit[j] * held[k] for k in SLOT}
    noise = {"steer": nzd["steer"], "gyro": nzd["gyro"], "roll_gyro": nzd["roll_gyro"], "accel_x": nzd["accel_x"],
             "accel_y": nzd["accel_y"], "wheel": [nzd[f"wheel_{c}"] for c in ("fl", "fr", "rl", "rr")],
             "speed": nzd["speed"], "gps_e": nzd["gps_e"], "gps_n": nzd["gps_n"], "heading": nzd["heading"]}
    sensors = with_fields(spec.sensors, gyro_bias=case["gyro_bias"], gyro_scale_error=case["gyro_scale_error"])
    radius = sp.wheel_radius if "wheel_radius" in spec.fields else None
    inp = {"steer": applied.steer, "yaw_moment": applied.yaw_moment, "bank": DISTURBANCES.unpack(w).bank}
    m = readings(tr, inp, noise, tuple(gps[k] for k in SLOT), fix, sensors, radius, o)
    meas = MEAS.pack({k: m[k] for k in MEAS}, o)

    # 2. the ECU step
    ecu = spec.ecu
    if ecu.kind == "driver":
        z_ecu_n = z_ecu
        steer_cmd, nz_cmd, drive_share = steer_drv, 0.0 * steer_drv, 1.0 + 0.0 * steer_drv
        beta_ref = yaw_rate_ref = beta_est = yaw_rate_est = active = mu_est = fault_word = 0.0 * steer_drv
    else:
        valid = m["gps_valid"]
        g = {"dt": dt + 0.0 * steer_drv, "speed": m["speed"], "steer": m["steer"], "yaw_rate": m["yaw_rate"],
             "ay": m["ay"], "gps_valid": valid, "gps_course": valid * m["gps_course"],
             "gps_speed": fix * m["gps_speed"], "gps_hdop": o.if_else(fix > 0.5, spec.sensors.gps_hdop, 1.0),
             "gps_sats": o.if_else(fix > 0.5, float(spec.sensors.gps_sats), 99.0), "steer_cmd_driver": steer_drv,
             "yaw_moment_applied": m["yaw_moment"] + (nz_brakes_applied if spec.brakes else 0.0),
             "steer_limited": flags.steer_limited, "yaw_moment_limited": flags.yaw_moment_limited,
             "mu": case["mu_assumed"], "brake_pressure_driver": 0.0 * steer_drv}
        wheels = brakes_mod.WHEELS
        if radius is None:  # a plant without wheels: no wheel speeds, so no slip
            g.update({f"wheel_speed_{c}": m["speed"] / ecu.design.wheel_radius for c in wheels})
        else:
            g.update({f"wheel_speed_{c}": m[f"wheel_speed_{c}"] for c in wheels})
        if spec.ecu_faults:
            g, faults_n = _inject(spec, zs.faults, g, th, o)
            # an ECU reset: booting through the window (no step: the state is evstab_init's, the driver's
            # steer passed on, no yaw moment); the first step after it starts from that state
            booting = _window(spec, zs.faults, th) * (th["fault_reset"] > 0.5)
            z_start = ecu.start_state(cal, o)
            z_ecu = o.if_else(booting, z_start, z_ecu)
        z_ecu_n, e = ecu.step(z_ecu, ECU_INPUTS.pack(g, o), tr, cal, o)
        out = ECU_OUTPUTS.as_dict(e)
        if spec.ecu_faults:
            z_ecu_n = o.if_else(booting, z_start, z_ecu_n)
            out = {k: o.if_else(booting, 0.0 * v, v) for k, v in out.items()}
            out["steer_cmd"] = o.if_else(booting, steer_drv, out["steer_cmd"])
            out["drive_share"] = o.if_else(booting, 1.0, out["drive_share"])
        steer_cmd, nz_cmd, drive_share = out["steer_cmd"], out["yaw_moment_cmd"], out["drive_share"]
        steer_corr = out["steer_correction"]
        beta_ref, yaw_rate_ref, beta_est, yaw_rate_est = out["beta_ref"], out["yaw_rate_ref"], out["beta"], \
            out["yaw_rate"]
        active, mu_est, fault_word = out["active"], out["mu_est"], out["fault_word"]

    # 3. actuators
    zero = 0.0 * steer_drv
    if ecu.kind == "driver":
        z_act_n = z_act
        a = {"steer": steer_drv, "yaw_moment": zero, "steer_limited": zero, "yaw_moment_limited": zero}
    else:
        lim = spec.limits
        tmax = lim.torque_max if lim.torque_max is not None else (
            sp.max_motor_torque if "max_motor_torque" in spec.fields else 1e9)
        z_act_n, av = actuator_law(sp, lim, tmax, z_act, ACT_SIGNALS.pack(o=o, steer_cmd=steer_cmd, steer_driver=steer_drv,
                                                                          steer_correction=steer_corr,
                                                                          yaw_moment_cmd=nz_cmd, t_mean=0.0 * steer_cmd,
                                                                          dt=dt), o)
        a = ACT_OUTPUTS.as_dict(av)
    rate = (a["steer"] - applied.steer) / dt

    # the hydraulic unit: each wheel's pressure towards the ECU's command (controllers.brakes)
    brake_cmd = {}
    if spec.brakes:
        z_brk_n, bo = brakes_mod.brake_law(sp, zs.brakes, [out[f"brake_pressure_{c}"] for c in brakes_mod.WHEELS],
                                           dt, o)
        torques = brakes_mod.OUTPUTS.as_dict(bo)
        brake_cmd = {f"brake_{c}": torques[f"brake_{c}"] for c in brakes_mod.WHEELS}

    # 4. the plant over the period
    cmd = COMMANDS.pack(o=o, steer=a["steer"], yaw_moment=a["yaw_moment"], speed_ref=speed_ref,
                        drive_on=drive_on * drive_share, steer_rate=rate, **brake_cmd)
    x_n = rk4_step(model, sp, x, cmd, w, dt, spec.n_sub)
    parts = {"plant": x_n, "actuator": z_act_n,
             "applied": APPLIED.pack(o=o, steer=a["steer"], yaw_moment=a["yaw_moment"], steer_rate=rate,
                                            drive_cut=1.0 - drive_share),
             "flags": FLAGS.pack(o=o, steer_limited=a["steer_limited"], yaw_moment_limited=a["yaw_moment_limited"]),
             "slots": GPS_SLOTS.pack(nxt, o)}
    if spec.ecu.n_state:
        parts["ecu"] = z_ecu_n
    if spec.ecu_faults:
        parts["faults"] = faults_n if ecu.kind != "driver" else zs.faults
    if spec.brakes:
        parts["brakes"] = z_brk_n
    z_n = spec.state_layout.pack(parts, o)
    extra = EXTRA.pack(o=o, steer=a["steer"], yaw_moment=a["yaw_moment"], steer_driver=steer_drv, yaw_moment_cmd=nz_cmd,
                       beta_ref=beta_ref, yaw_rate_ref=yaw_rate_ref, beta_est=beta_est, yaw_rate_est=yaw_rate_est,
                       yaw_moment_limited=a["yaw_moment_limited"], steer_cmd=steer_cmd, steer_limited=a["steer_limited"],
                       steer_limited_last=flags.steer_limited, yaw_moment_limited_last=flags.yaw_moment_limited,
                       steer_rate=rate, active=active, mu_est=mu_est, fault_word=fault_word,
                       drive_share=drive_share, **(brake_cmd or {f"brake_{c}": zero for c in brakes_mod.WHEELS}),
                       yaw_moment_brakes_cmd=out["yaw_moment_brakes"] if spec.brakes else zero)
    return z_n, y, extra, meas


def _window(spec: LoopSpec, z_f, th: dict):
    """1 while the injector's clock (``z_f[0]``, samples) is inside the fault's window."""
    t = z_f[0] * spec.dt
    return (t >= th["fault_start"]) * (t < th["fault_end"])


def _inject(spec: LoopSpec, z_f, g: dict, th: dict, o):
    """The ECU inputs ``g`` with the run's fault (:data:`FAULT_PARAMS`) inside its window; returns them and the
    injector's next state (the clock one sample on; each input's held value, the reading until the window
    opens)."""
    clock = z_f[0]
    on = _window(spec, z_f, th)
    out, held_n = dict(g), []
    for i, name in enumerate(ECU_INPUTS):
        x, held = g[name], z_f[1 + i]
        f = {k: th[f"fault_{k}_{name}"] for k in FAULT_PARAMS}
        bad = o.if_else(f["set"] > 0.5, f["value"], o.if_else(f["hold"] > 0.5, held, x * f["gain"] + f["add"]))
        out[name] = o.if_else(on, bad, x)
        held_n.append(o.if_else(on, held, x))
    return out, o.stack([clock + 1.0] + held_n)


def _lane_step(spec: LoopSpec):
    """The step traced for a lane kernel: schedule reads and the tyres' shape function as call nodes
    (:func:`plants.backend.call_nodes`), which the kernel runs as table lookups."""
    with call_nodes():
        return _build(spec, chunk=False)[0]


def _build(spec: LoopSpec, chunk: bool = True):
    model = get_plant(spec.plant)
    sizes = spec.sizes
    Z = ca.SX.sym("z", sum(sizes))
    U = ca.SX.sym("u", n_inputs())
    pv = ca.SX.sym("p", len(spec.fields))
    th = ca.SX.sym("theta", len(spec.theta_names))
    sp = symbolic_view(_TEMPLATE, spec.fields, pv)
    Zn, y, extra, meas = loop_step(spec, model, sp, Z, U, th, CASADI)
    step = ca.Function("loop_step", [Z, U, pv, th], [Zn, y, extra, meas], ["z", "u", "p", "theta"],
                       ["z_next", "truth", "extra", "meas"])
    if not chunk:
        return step, None, (Z, U, pv, th, Zn)
    acc = step.mapaccum("loop_acc", CHUNK)
    z0, Uc = ca.MX.sym("z0", Z.shape[0]), ca.MX.sym("U", U.shape[0], CHUNK)
    pm, tm = ca.MX.sym("p", pv.shape[0]), ca.MX.sym("theta", th.shape[0])
    Zs, Ys, Es, Ms = acc(z0, Uc, ca.repmat(pm, 1, CHUNK), ca.repmat(tm, 1, CHUNK))
    chunk_fn = ca.Function("loop_chunk", [z0, Uc, pm, tm], [Zs[:, -1], Ys, Es, Ms])
    return step, chunk_fn, (Z, U, pv, th, Zn)


LANE_ROLES = lanes_mod.Roles(stepped=(1,))
"""The loop step's inputs for a lane kernel: ``u`` changes every sample; ``p`` and ``theta`` per case."""

_TEMPLATE = VehicleParams.__new__(VehicleParams)
object.__setattr__(_TEMPLATE, "name", "loop")
object.__setattr__(_TEMPLATE, "source", "")
"""Stand-in for :func:`toolkit.kernels.compiled.symbolic_view`, which reads only the field names and ``name``."""


def run_stepped(spec: LoopSpec, params: VehicleParams, U: np.ndarray, z0: np.ndarray, theta: np.ndarray, *,
                driver=None, program=None):
    """The loop one sample at a time, with an outer path-following ``driver`` (a
    :class:`plants.paths.PathDriver`) setting ``steer_driver`` from the plant state before each
    step. With ``program`` (a :class:`toolkit.loop.loop_program.LoopProgram`) the compiled step runs; without, :func:`loop_step` in numpy (the
    reference evaluation). Returns (Y, E, M); a run that stops being finite is cut with NaN."""
    model = get_plant(spec.plant)
    n = U.shape[0]
    Y = np.full((n, len(TRUTH)), np.nan)
    E = np.full((n, len(EXTRA)), np.nan)
    M = np.full((n, len(MEAS)), np.nan)
    plant_part = spec.state_layout.slot("plant")
    i_steer, i_speed = INPUTS.index("steer_driver"), INPUTS.index("speed_ref")
    ix, iy, iyaw = (model.state_index(s) for s in ("x", "y", "yaw"))
    ivx = model.states.index("vx") if "vx" in model.states else None
    drv = driver.initial_state() if driver is not None else None
    pv = np.ascontiguousarray(param_vector(params, spec.fields), float)
    theta = np.ascontiguousarray(theta, float)
    z = np.array(z0, float)
    U = np.array(U, float)
    for k in range(n):
        if driver is not None:
            x = z[plant_part]
            vx = x[ivx] if ivx is not None else U[k, i_speed]
            drv, U[k, i_steer] = driver.steer(drv, x[ix], x[iy], x[iyaw], vx)
        if program is not None:
            z, Y[k], E[k], M[k] = program.step_once(z, U[k], pv, theta)
        else:
            z_n, y, e, m = loop_step(spec, model, params, z, U[k], theta, NUMPY)
            z, Y[k], E[k], M[k] = np.asarray(z_n, float).ravel(), np.ravel(y), np.ravel(e), np.ravel(m)
        if not np.all(np.isfinite(z)):
            break
    return Y, E, M


def loop_theta(spec: LoopSpec, *, gyro_bias: float = 0.0, gyro_scale_error: float = 0.0, mu_assumed: float = 1.0,
               fault=None, **calibration) -> np.ndarray:
    """The run-time parameter vector: the ECU's calibration (:meth:`EcuDesign.calibration`; entries
    given by name replace the design's), the case's gyro errors and assumed friction, and with ``ecu_faults``
    the injected fault's (``fault``: a :class:`toolkit.loop.ecu_faults.EcuFault`, None: none)."""
    names = spec.ecu.calibration_names()
    vals = dict(zip(names, spec.ecu.calibration_values()))
    over = dict(calibration)
    unknown = sorted(set(over) - set(names))
    if unknown:
        raise LoopError(f"calibration {', '.join(unknown)} not in this ECU's ({', '.join(names)})")
    vals.update(over)
    case = {"gyro_bias": gyro_bias, "gyro_scale_error": gyro_scale_error, "mu_assumed": mu_assumed}
    theta = [float(vals[k]) for k in names] + [float(case[k]) for k in CASE]
    if spec.ecu_faults:
        theta += fault_parameters(fault)
    elif fault is not None:
        raise LoopError("a fault needs a loop traced with ecu_faults=True")
    return np.array(theta)


def samples(spec: LoopSpec, maneuver: Maneuver) -> int:
    """The number of loop samples of a run of ``maneuver``."""
    return int(round(maneuver.duration / spec.dt))


def loop_inputs(spec: LoopSpec, params: VehicleParams, maneuver: Maneuver, disturbances: Disturbances,
                sensors: SensorConfig, seed: int, *, out: np.ndarray | None = None, noise: np.ndarray | None = None):
    """(U, z0, p) for a run: the input matrix (samples x inputs), initial loop state, plant parameters.

    ``out``: a (samples x inputs) float array to fill and return as ``U`` (a batch's slice: no copy);
    ``noise``: the run's :func:`noise_matrix` when the caller already drew it (runs of one seed and
    length draw the same)."""
    dt = spec.dt
    model = get_plant(spec.plant)
    n = samples(spec, maneuver)
    t = np.arange(n) * dt
    W = disturbance_profile(disturbances, t)
    if out is None:
        U = INPUTS.zeros(n)
    else:
        if out.shape != (n, INPUTS.size) or out.dtype != float:
            raise LoopError(f"loop_inputs: out must be a float ({n}, {INPUTS.size}) array, got {out.dtype} {out.shape}")
        U = out
    col = INPUTS.columns(U)  # views: writing them fills U
    col["steer_driver"][:] = maneuver.steer(t) if maneuver.open_loop else 0.0
    col["speed_ref"][:] = maneuver.speed_ref(t)
    col["drive_on"][:] = maneuver.drive_on(t)
    col["disturbances"][:] = W.T
    if noise is None:
        noise = noise_matrix(sensors, seed, n)
    elif noise.shape != (NOISE.size, n):
        raise LoopError(f"loop_inputs: noise must be ({NOISE.size}, {n}), got {noise.shape}")
    col["noise"][:] = noise.T
    fix = gps_fix_mask(t, sensors)
    col["fix"][:] = fix
    latch_schedule_parts(fix, sensors.gps_latency, dt, out=(col["capture"], col["emit"]))
    need = rk4_substeps(model, params, dt)
    if need > spec.n_sub:
        raise LoopError(f"'{params.name}': these plant parameters need {need} RK4 sub-steps per sample, the "
                        f"loop has {spec.n_sub}")
    names = numeric_fields(params)
    if names != spec.fields:
        raise LoopError(f"'{params.name}': the plant parameters set differ from the loop's "
                        f"({sorted(set(names) ^ set(spec.fields))})")
    x0 = model.initial_state(params, maneuver.speed)
    if maneuver.path is not None:  # start on the path, aligned with it
        path = maneuver.path
        x0[model.state_index("x")], x0[model.state_index("y")] = path.x[0], path.y[0]
        x0[model.state_index("yaw")] = np.arctan2(path.y[1] - path.y[0], path.x[1] - path.x[0])
    return U, _initial_state_of_run(spec, x0, params, maneuver.speed, W[:, 0]), param_vector(params, names)


_ECU_START: dict = {}
_RUN_START: dict = {}


def _initial_state_of_run(spec: LoopSpec, x0, params: VehicleParams, speed: float, w0) -> np.ndarray:
    """:func:`loop_initial_state`, remembered for the last runs: a sweep's case starts each of its
    manoeuvres from the same state (same parameters, speed and first disturbance sample), and the
    plant's output equation in numpy costs a sixth of a manoeuvre's inputs."""
    x0, w0 = np.asarray(x0, float), np.asarray(w0, float)
    key = (id(spec), id(params), float(speed), x0.tobytes(), w0.tobytes())
    hit = _RUN_START.get(key)
    if hit is None or hit[0] is not spec or hit[1] is not params:  # identity: ids are reused after collection
        if len(_RUN_START) > 64:
            _RUN_START.clear()
        hit = _RUN_START[key] = (spec, params, loop_initial_state(spec, x0, params, speed, w0))
    return hit[2].copy()


def loop_initial_state(spec: LoopSpec, x0, params: VehicleParams, speed: float, w0) -> np.ndarray:
    """The loop state at the start: plant ``x0``, the ECU's initial state, nothing applied, the
    GPS slots holding the first sample's truth."""
    model = get_plant(spec.plant)
    lay = spec.state_layout
    z0 = lay.zeros()
    z0[lay.slot("plant")] = x0
    # the same for every run of an ECU, and a sweep starts thousands (keyed by identity: hashing the
    # design's tables costs more than the lookup saves)
    hit = _ECU_START.get(id(spec.ecu))
    if hit is None or hit[0] is not spec.ecu:
        if len(_ECU_START) > 256:
            _ECU_START.clear()
        hit = _ECU_START[id(spec.ecu)] = (spec.ecu, spec.ecu.initial_state())
    z0[lay.slot("ecu")] = hit[1]
    cmd0 = COMMANDS.pack(steer=0.0, yaw_moment=0.0, speed_ref=speed, drive_on=1.0, steer_rate=0.0)
    y0 = TRUTH.as_dict(np.asarray(model.h(x0, model.command_map(cmd0, x0, params), w0, params), float).ravel())
    first = SLOT.pack({k: y0[k] for k in SLOT})
    z0[lay.slot("slots")] = np.tile(first, SLOTS)
    return z0


def noise_matrix(cfg: SensorConfig, seed: int, n: int) -> np.ndarray:
    """The standard-normal draws of a run, one row per :data:`NOISE` entry (the simulator's streams,
    :func:`plants.sensors.draw_noise`)."""
    return noise_rows(seed, n, NOISE_STREAMS)


def latch_schedule_parts(fix: np.ndarray, latency: float, dt: float,
                         out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The (samples x SLOTS) capture and emit one-hots of :func:`latch_schedule` (the :data:`INPUTS`
    entries ``capture`` and ``emit``); ``out``: two (samples x SLOTS) arrays (views of an input
    matrix) to fill and return instead (zeroed, then the ones written: no dense temporary)."""
    if out is None:
        both = latch_schedule(fix, latency, dt)
        return both[:SLOTS].T, both[SLOTS:].T
    slot, cap, emit = _latch_indices(fix, latency, dt)
    capture, emitted = out
    capture[...] = 0.0
    emitted[...] = 0.0
    capture[cap, slot] = 1.0
    emitted[emit, slot] = 1.0
    return capture, emitted


def latch_schedule(fix: np.ndarray, latency: float, dt: float) -> np.ndarray:
    """One-hot capture and emit signals (2 SLOTS x samples) for fixes arriving ``latency`` late.

    The fix at sample k describes the truth the sensors saw at sample k - lag (clamped to the
    first sample). Fix i uses slot i mod SLOTS; a slot must not be captured again before its
    fix has been emitted.
    """
    slot, cap, emit = _latch_indices(fix, latency, dt)
    out = np.zeros((2 * SLOTS, len(fix)))
    out[slot, cap] = 1.0
    out[SLOTS + slot, emit] = 1.0
    return out


def _latch_indices(fix: np.ndarray, latency: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(slot, capture sample, emit sample) of each fix of :func:`latch_schedule`."""
    lag = latency / dt
    if abs(lag - round(lag)) > 1e-9 or lag < 0:
        raise LoopError(f"the loop needs a GPS latency of whole samples >= 0, got {latency} s at dt {dt} s")
    lag = int(round(lag))
    ks = np.nonzero(np.asarray(fix) > 0.5)[0]
    caps = np.maximum(ks - lag, 0)
    # fix i reuses fix i - SLOTS's slot: that fix must have been emitted before this one is captured
    if len(ks) > SLOTS and np.any(caps[SLOTS:] <= ks[:-SLOTS]):
        raise LoopError(f"GPS latency {latency} s spans more than {SLOTS - 1} fix periods; "
                        f"the loop holds at most {SLOTS} fixes in flight")
    return np.arange(len(ks)) % SLOTS, caps, ks


def loop_spec(nominal: VehicleParams, *, plant: str = "two-track", controller: str = "two-dof",
              estimator: str | FilterDesign = "dakf", sensors: SensorConfig | None = None, dt: float = 1e-3,
              design: TwoDofDesign | EcuDesign | None = None, estimator_latency: float = 0.0,
              n_sub: int | None = None, truth: VehicleParams | None = None,
              limits: ActuatorLimits = ActuatorLimits(), ecu_faults: bool = False) -> LoopSpec:
    """The trace-time part of a loop (see :class:`LoopSpec`). ``nominal`` is what the ECU believes;
    ``truth`` a parameter set of the plant (default: the multi-body set for ``commonroad-mb``
    plants, else ``nominal``), whose set fields the loop's plant-parameter vector holds."""
    model = get_plant(plant)
    sensors = sensors or SensorConfig()
    ecu = loop_ecu(controller, nominal, dt=dt, estimator=estimator, latency=estimator_latency, design=design)
    template = truth if truth is not None else truth_params(model.name, nominal)
    # the fix times, outages and latency enter through the inputs, the gyro's errors through theta
    base = dataclasses.replace(sensors, gps_latency=0.0, gyro_bias=0.0, gyro_scale_error=0.0, gps_rate=5.0,
                               gps_start=0.0, gps_outages=())
    n_sub = n_sub if n_sub is not None else rk4_substeps(model, template, dt)
    return LoopSpec(model.name, numeric_fields(template), float(dt), ecu, base, int(n_sub), limits, ecu_faults)


def traced(spec: LoopSpec) -> LoopSpec:
    """``spec`` with the ECU's calibration replaced by placeholders: the calibration is a run-time
    input, so specs that differ only there share one trace and one compiled library."""
    if spec.ecu.ecu is None:
        return spec
    ecu = spec.ecu.ecu.bind([1.0] * len(spec.ecu.calibration_names()))
    return dataclasses.replace(spec, ecu=LoopEcu(spec.ecu.kind, ecu))
