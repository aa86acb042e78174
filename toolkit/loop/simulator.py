"""The simulator: one manoeuvre on one plant, named signals out.

A driver supplies the steer (open-loop profile or path following) and the speed
demand. With a controller the stability loop runs: :func:`toolkit.loop.closed_loop.loop_step`
(sensors -> the ECU step -> actuators -> plant), rolled out in one compiled call for an
open-loop steer profile, stepped sample by sample (compiled step) when the path follower
closes an outer loop around it. Without a controller the plant runs alone (one compiled
rollout, or the same loop step with the driver straight to the plant when following a
path) and the sensors are read from the finished run. Time is fixed step (1 ms default).
A run is deterministic for a seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evstab.plants import COMMANDS, DISTURBANCES, TRUTH, PlantModel, VehicleParams, get_plant, is_multibody, truth_params
from evstab.plants.disturbances import Disturbances, disturbance_profile
from evstab.plants.errors import EvstabError
from evstab.plants.maneuvers import Maneuver
from evstab.plants.sensors import SensorConfig, measure

from ..kernels.compiled import compiled_plant
from ..logs.drivelog import write_log_csv


class SimulationError(EvstabError, RuntimeError):
    """A run diverged (non-finite state) or was set up inconsistently."""


class RolloverError(SimulationError):
    """The car rolled over (a multi-body car's body roll passed :data:`ROLLOVER`); ``t`` says when."""

    def __init__(self, message: str, t: float):
        super().__init__(message)
        self.t = t

    def __reduce__(self):  # pickled with its time (a worker process's run that rolled over reaches its caller)
        return type(self), (str(self), self.t)


ROLLOVER = np.deg2rad(45.0)
"""Body roll [rad] past which a multi-body car has rolled over: on two wheels and beyond its
tipping angle (atan(t / 2h) is 49-51 deg for the CommonRoad sets), where the model's suspension
geometry no longer means anything."""


@dataclass(frozen=True)
class SimResult:
    """A finished run: time, truth, commands, disturbances and sensor readings, all named."""

    t: np.ndarray
    truth: dict
    commands: dict
    disturbances: dict
    measurements: dict
    meta: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        for group in (self.truth, self.measurements, self.commands, self.disturbances):
            if name in group:
                return group[name]
        raise KeyError(f"no signal '{name}' in this result")

    def log_columns(self) -> dict:
        """Drive-log columns (the drive-log schema, docs/formats.md): sensor readings plus ``*_true`` truth."""
        cols = {"t": self.t}
        cols.update(self.measurements)
        truth = self.truth
        cols.update({
            "beta_true": truth["beta"], "yaw_rate_true": truth["yaw_rate"], "yaw_true": truth["yaw"],
            "vx_true": truth["vx"], "vy_true": truth["vy"], "roll_true": truth["roll"],
            "ay_true": truth["ay"], "x_true": truth["x"], "y_true": truth["y"],
            "steer_true": self.commands["steer"],
        })
        if "steer_driver" in self.commands:
            cols["steer_driver"] = self.commands["steer_driver"]
            cols["yaw_moment_cmd"] = self.commands["yaw_moment_cmd"]
        for name in ("steer_limited_last", "yaw_moment_limited_last"):  # the controller's limit-flag inputs
            if name in self.commands:
                cols[name] = self.commands[name]
        return cols

    def write_csv(self, path) -> None:
        """Write the drive log atomically."""
        write_log_csv(path, self.log_columns())


def simulate(params: VehicleParams, plant: str | PlantModel, maneuver: Maneuver, *,
             disturbances: Disturbances | None = None, sensors: SensorConfig | None = None,
             seed: int = 0, dt: float = 1e-3, compile: bool = True, controller: str | None = None,
             estimator="dakf", mu_assumed: float | None = None,
             nominal: VehicleParams | None = None, design=None, ecu_fault=None) -> SimResult:
    """Run one manoeuvre on one plant and return the named signals.

    Parameters
    ----------
    params : VehicleParams
        The vehicle (the truth the plant simulates). For a ``commonroad-mb:N`` plant the truth
        is the package's set N (its geometry: :func:`plants.truth_params`), and ``params`` is
        what the controller and estimator believe unless ``nominal`` is given.
    plant : str or PlantModel
        ``bicycle``, ``bicycle-roll``, ``two-track`` or ``commonroad-mb:N[:STEER_RATE]``.
    maneuver : Maneuver
        See :mod:`plants.maneuvers`.
    disturbances, sensors : optional
        Wind, friction, bank; sensor noise, GPS rate/outages/latency (whole samples when a
        controller is in the loop).
    seed : int
        Seeds every noise source; equal seeds give identical runs.
    dt : float
        Fixed step [s] (the ECU's period when a controller is in the loop).
    compile : bool
        Run compiled code (C, cached; casadi's virtual machine without a compiler); False
        evaluates the same equations in numpy (the reference path, slow).
    controller : None, "none", "yaw-pi", "two-dof" or "two-dof-true"
        Closes the stability loop (:func:`toolkit.loop.closed_loop.loop_step`: sensors -> ECU step ->
        actuators -> plant). ``None`` runs the driver alone (sensors read after the run).
    estimator : str or FilterDesign
        The ECU's filter (``dakf`` default; designed for ``nominal`` with the sensors' GPS
        latency), or a designed filter; not used by ``two-dof-true``.
    mu_assumed : float
        The ECU's ``mu`` input, a road-friction sensor (an upper bound on the ECU's own friction
        estimate); default none: the design's ``mu_max``. The ECU is not told the road.
    nominal : VehicleParams
        What the ECU believes (default ``params``); a different set is a model error.
    design : TwoDofDesign or EcuDesign
        The controller design (default seed 003's gains for ``nominal``); an
        :class:`~toolkit.ecu.step.EcuDesign` (a design folder's ECU) replaces filter and
        controller as a whole.
    ecu_fault : EcuFault
        A fault injected into one of the ECU's inputs (:mod:`toolkit.loop.ecu_faults`); with a controller only.

    Returns
    -------
    SimResult
        Time ``t`` [s] and named signals: ``truth`` (plant states and outputs, SI, ISO 8855),
        ``measurements`` (sensor readings), ``commands`` (driver and, in the loop, the ECU's
        commands, estimates and references), ``disturbances``; ``meta`` (vehicle, plant, seed,
        step, events). :meth:`SimResult.write_csv` writes the drive log.

    Raises
    ------
    SimulationError
        The plant left what it can represent (``RolloverError``: the car rolled over).

    Examples
    --------
    A 2 deg step steer at 60 km/h on the linear single-track plant settles at its steady state
    (:func:`plants.bicycle.steady_state_gains`: 10.217 deg/s):

    >>> import numpy as np
    >>> import evstab
    >>> p = evstab.load_vehicle("compact-ev")
    >>> run = evstab.simulate(p, "bicycle", evstab.make_maneuver("step-steer", p, 60 / 3.6))
    >>> len(run.t), round(float(np.degrees(run.truth["yaw_rate"][-1])), 3)
    (6000, 10.217)
    """
    model, params, nominal, disturbances, sensors = _setup(plant, params, nominal, disturbances, sensors, dt)
    n = int(round(maneuver.duration / dt))
    t = np.arange(n) * dt
    W = disturbance_profile(disturbances, t)
    if controller is None and maneuver.open_loop:  # nothing feeds back: the plant alone, one call
        steer = np.asarray(maneuver.steer(t), float) * np.ones(n)
        cmd = COMMANDS.pack(steer=steer, yaw_moment=np.zeros(n), speed_ref=maneuver.speed_ref(t),
                            drive_on=np.asarray(maneuver.drive_on(t), float) * np.ones(n), steer_rate=steer_rate(steer, dt))
        cp = compiled_plant(model, params, dt, compile=compile)
        x0 = model.initial_state(params, maneuver.speed)
        X, Y = cp.rollout(x0, cmd, W)
        if not np.all(np.isfinite(X)):
            Y = Y.copy()
            Y[:, int(np.argmax(~np.all(np.isfinite(X), axis=0))):] = np.nan
        return _finish(model, params, maneuver, t, W, Y, COMMANDS.as_dict(cmd), None, None, sensors, seed, dt,
                       cp.backend, cp.n_sub)
    from . import closed_loop as cl
    spec, prog, theta = _loop(model, params, nominal, sensors, dt, controller, estimator, design, mu_assumed, compile,
                              ecu_fault)
    U, z0, pv = cl.loop_inputs(spec, params, maneuver, disturbances, sensors, seed)
    if maneuver.open_loop and prog is not None:
        Yt, E, M = prog.run(U, z0, pv, theta, meas=True)
    else:
        driver = None if maneuver.open_loop else maneuver.path_driver(params, dt)
        Yt, E, M = cl.run_stepped(spec, params, U, z0, theta, driver=driver, program=prog)
    return _loop_result(spec, prog, model, params, maneuver, t, W, U, Yt, E, M, sensors, seed, dt)


def simulate_many(params: VehicleParams, plant: str | PlantModel, maneuvers: list[Maneuver], *,
                  disturbances: Disturbances | None = None, sensors: SensorConfig | None = None,
                  seed: int = 0, dt: float = 1e-3, controller: str = "none", estimator="dakf",
                  mu_assumed: float | None = None, nominal: VehicleParams | None = None,
                  design=None) -> list:
    """:func:`simulate` of several open-loop manoeuvres through the same compiled stability loop,
    the runs of one length stepped together (:meth:`toolkit.loop.loop_program.LoopProgram.run_batch`): an
    FMVSS 126 series is one call. Each run equals :func:`simulate` of it alone.

    Parameters are :func:`simulate`'s, with ``maneuvers`` (open loop) for ``maneuver``; the loop is
    always closed (``controller`` ``none`` runs the ECU and passes the driver through).

    Returns
    -------
    list
        Per manoeuvre, its :class:`SimResult`, or the :class:`SimulationError` (a
        ``RolloverError`` for one) :func:`simulate` would have raised.
    """
    model, params, nominal, disturbances, sensors = _setup(plant, params, nominal, disturbances, sensors, dt)
    if any(not m.open_loop for m in maneuvers):
        raise SimulationError("simulate_many runs open-loop manoeuvres (a path follower steers sample by sample)")
    from . import closed_loop as cl
    spec, prog, theta = _loop(model, params, nominal, sensors, dt, controller, estimator, design, mu_assumed, True)
    runs = []
    for man in maneuvers:
        t = np.arange(int(round(man.duration / dt))) * dt
        runs.append((man, t, disturbance_profile(disturbances, t),
                     *cl.loop_inputs(spec, params, man, disturbances, sensors, seed)))
    out: list = [None] * len(runs)
    groups: dict[int, list[int]] = {}
    for i, r in enumerate(runs):
        groups.setdefault(len(r[1]), []).append(i)
    for idx in groups.values():
        Yb, Eb, Mb = prog.run_batch(np.stack([runs[i][3] for i in idx]), np.stack([runs[i][4] for i in idx]),
                                    np.stack([runs[i][5] for i in idx]), np.tile(theta, (len(idx), 1)), meas=True)
        for q, i in enumerate(idx):
            man, t, W, U, _, _ = runs[i]
            try:
                out[i] = _loop_result(spec, prog, model, params, man, t, W, U, Yb[q], Eb[q], Mb[q], sensors, seed, dt)
            except SimulationError as exc:
                out[i] = exc
    return out


def _setup(plant, params, nominal, disturbances, sensors, dt):
    model = get_plant(plant) if isinstance(plant, str) else plant
    if is_multibody(model.name):
        nominal = nominal or params
        params = truth_params(model.name, params)
    model.check_params(params)
    disturbances = disturbances or Disturbances(friction=_uniform(params.mu))
    sensors = sensors or SensorConfig()
    if not (dt > 0 and np.isfinite(dt)):
        raise SimulationError(f"time step must be > 0 s, got {dt!r}")
    return model, params, nominal, disturbances, sensors


def _loop(model, params, nominal, sensors, dt, controller, estimator, design, mu_assumed, compile, ecu_fault=None):
    """(spec, compiled program or None, theta) of the stability loop a simulation closes."""
    from . import closed_loop as cl
    from ..estimation.spec import FilterDesign
    kind = "driver" if controller is None else controller
    if kind != "driver" and kind not in cl.CONTROLLERS:
        raise SimulationError(f"unknown controller '{controller}'; known: {', '.join(cl.CONTROLLERS)}")
    lat = sensors.gps_latency if not isinstance(estimator, FilterDesign) else 0.0
    if ecu_fault is not None and kind == "driver":
        raise SimulationError("an ECU fault needs a controller in the loop")
    spec = cl.loop_spec(nominal or params, plant=model.name, controller=kind, estimator=estimator,
                        sensors=sensors, dt=dt, design=design, estimator_latency=lat, truth=params,
                        ecu_faults=ecu_fault is not None)
    from .loop_program import program
    prog = program(spec) if compile else None
    no_sensor = spec.ecu.ecu.controller.mu_max if spec.ecu.ecu is not None else 1.0
    theta = cl.loop_theta(spec, gyro_bias=sensors.gyro_bias, gyro_scale_error=sensors.gyro_scale_error,
                          mu_assumed=no_sensor if mu_assumed is None else mu_assumed, fault=ecu_fault)
    return spec, prog, theta


def _loop_result(spec, prog, model, params, maneuver, t, W, U, Yt, E, M, sensors, seed, dt) -> SimResult:
    from . import closed_loop as cl
    Y = Yt.T
    ec, uc = cl.EXTRA.columns(E), cl.INPUTS.columns(U)
    commands = {"steer": ec["steer"], "yaw_moment": ec["yaw_moment"], "speed_ref": uc["speed_ref"].copy(),
                "drive_on": uc["drive_on"].copy(), "steer_rate": ec["steer_rate"]}
    extra = meas = None
    if spec.ecu.kind != "driver":
        extra = {k: ec[k] for k in cl.EXTRA if k not in commands}
        meas = _log_readings(M, Y, W, sensors, seed)
    return _finish(model, params, maneuver, t, W, Y, commands, extra, meas, sensors, seed, dt,
                   prog.backend if prog is not None else "numpy", spec.n_sub)


def _finish(model, params, maneuver, t, W, Y, commands, extra, meas, sensors, seed, dt, backend, n_sub) -> SimResult:
    truth = TRUTH.as_dict(Y)
    if is_multibody(model.name):
        check_rollover(model.name, truth["roll"], dt, maneuver)
    motion = [TRUTH.index(k) for k in ("vx", "vy", "yaw_rate", "yaw", "x", "y")]  # wheel speeds may be NaN
    if not np.all(np.isfinite(Y[motion])):
        k = int(np.argmax(~np.all(np.isfinite(Y[motion]), axis=0)))
        raise SimulationError(f"{model.name} diverged at t = {k * dt:.3f} s ({maneuver.name}, "
                              f"{maneuver.speed * 3.6:.0f} km/h)")
    if is_multibody(model.name):
        _check_mb_speed(model, truth["vx"], dt, maneuver)
    dist = DISTURBANCES.as_dict(W)
    if meas is None:
        meas = measure(t, truth, {"steer": commands["steer"], "yaw_moment": commands["yaw_moment"],
                                  "bank": dist["bank"]}, sensors, seed, params.wheel_radius)
    else:
        commands.update(extra)
    meta = {"vehicle": params.name, "params_digest": params.digest(), "plant": model.name,
            "maneuver": maneuver.name, "speed_mps": maneuver.speed, "seed": seed, "dt": dt,
            "backend": backend, "rk4_substeps": n_sub, "events": dict(maneuver.events)}
    return SimResult(t=t, truth=truth, commands=commands, disturbances=dist, measurements=meas, meta=meta)


def _log_readings(M: np.ndarray, Y: np.ndarray, W: np.ndarray, sensors: SensorConfig, seed: int) -> dict:
    """Drive-log columns from the readings the ECU was given, and the dual-antenna roll, which the ECU
    does not read, from the truth as :func:`measure` makes it."""
    from .closed_loop import MEAS
    from evstab.plants.sensors import draw_noise, log_columns
    m = MEAS.columns(M)
    roll = TRUTH.as_dict(Y)["roll"] + DISTURBANCES.as_dict(W)["bank"]
    return log_columns(m, sensors, roll, draw_noise(sensors, seed, M.shape[0])["gps_roll"])


def check_rollover(plant: str, roll: np.ndarray, dt: float, maneuver) -> None:
    """Raise :class:`RolloverError` if the body roll passed :data:`ROLLOVER` (or stopped being a number
    after passing 30 deg: the model tumbling)."""
    roll = np.asarray(roll, float)
    over = ~(np.abs(roll) < ROLLOVER)
    if np.any(over):
        k = int(np.argmax(over))
        if np.isfinite(roll[k]) or np.any(np.abs(roll[:k]) > np.deg2rad(30.0)):
            raise RolloverError(f"{plant} rolled over at t = {k * dt:.3f} s ({maneuver.name}, "
                                f"{maneuver.speed * 3.6:.0f} km/h): body roll passed {np.degrees(ROLLOVER):.0f} deg",
                                k * dt)


def _check_mb_speed(model, vx, dt, maneuver) -> None:
    from evstab.plants.commonroad_mb import MIN_SPEED
    if np.any(vx < MIN_SPEED):
        k = int(np.argmax(vx < MIN_SPEED))
        raise SimulationError(f"{model.name}: speed fell to {vx[k]:.2f} m/s at t = {k * dt:.3f} s ({maneuver.name}); "
                              f"the multi-body car runs above {MIN_SPEED:g} m/s (the port has no kinematic "
                              f"low-speed branch)")


def steer_rate(steer: np.ndarray, dt: float) -> np.ndarray:
    """The steer command's rate as a servo sees it: the backward difference over the last sample
    (causal, as in a loop where the next command is not known yet); 0 on the first sample."""
    steer = np.asarray(steer, float)
    return np.diff(steer, prepend=steer[:1]) / dt


def _uniform(mu: float):
    from evstab.plants.disturbances import Friction
    return Friction(mu=mu)
