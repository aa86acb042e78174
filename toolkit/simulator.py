"""The one closed-loop simulator.

Every loop in evstab is closed here: plant -> sensors -> (estimator ->
controller, later issues) -> actuators -> plant, with a driver that supplies the
steer (open-loop profile or path following) and the speed demand. Time is fixed
step (1 ms default). A run is deterministic for a seed.

Components follow one step protocol (:class:`Component`): an explicit state from
``initial_state()``, advanced by a pure ``step(state, t, signals) -> (state,
outputs)``. When nothing in the loop feeds back (an open-loop steer manoeuvre and
no controller) the whole run is integrated in one compiled call
(:meth:`toolkit.compiled.CompiledPlant.rollout`); otherwise the loop steps sample
by sample through the same compiled plant step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np

from plants import COMMANDS, DISTURBANCES, TRUTH, PlantModel, VehicleParams, get_plant, is_multibody, truth_params
from plants.disturbances import Disturbances, disturbance_profile
from plants.errors import EvstabError
from plants.maneuvers import Maneuver
from plants.paths import PathDriver
from plants.sensors import SensorConfig, measure

from .compiled import compiled_plant
from .logio import write_log_csv


class SimulationError(EvstabError, RuntimeError):
    """A run diverged (non-finite state) or was set up inconsistently."""


class RolloverError(SimulationError):
    """The car rolled over (a multi-body car's body roll passed :data:`ROLLOVER`); ``t`` says when."""

    def __init__(self, message: str, t: float):
        super().__init__(message)
        self.t = t


ROLLOVER = np.deg2rad(45.0)
"""Body roll [rad] past which a multi-body car has rolled over: on two wheels and beyond its
tipping angle (atan(t / 2h) is 49-51 deg for the CommonRoad sets), where the model's suspension
geometry no longer means anything."""


class Component(Protocol):
    """The step protocol shared by drivers, estimators, controllers and the plant."""

    def initial_state(self) -> Any: ...

    def step(self, state: Any, t: float, signals: Mapping[str, float]) -> tuple[Any, Mapping[str, float]]: ...


@dataclass(frozen=True)
class DriverComponent:
    """Wraps :class:`plants.paths.PathDriver` in the step protocol (signals: x, y, yaw, vx)."""

    driver: PathDriver

    def initial_state(self):
        return self.driver.initial_state()

    def step(self, state, t, signals):
        idx, steer = self.driver.steer(state, signals["x"], signals["y"], signals["yaw"], signals["vx"])
        return idx, {"steer": steer}


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
        """Drive-log columns (DESIGN.md schema): sensor readings plus ``*_true`` truth."""
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
             seed: int = 0, dt: float = 1e-3, compile: bool = True, controller=None,
             estimator="dakf", mu_assumed: float | None = None,
             nominal: VehicleParams | None = None) -> SimResult:
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
        Wind, friction, bank; sensor noise, GPS rate/outages/latency.
    seed : int
        Seeds every noise source; equal seeds give identical runs.
    dt : float
        Fixed step [s].
    controller : None, "none", "yaw-pi", "two-dof", "two-dof-true" or a controller object
        Closes the stability-control loop: plant -> sensors -> estimator ->
        controller -> actuators -> plant (see :func:`_stability_loop`). ``None``
        runs the driver alone (no sensors in the loop).
    estimator : str or FilterDesign
        Estimation method in the loop (``dakf`` default; designed for ``nominal`` with the
        sensors' true GPS latency), or a designed filter (its noise settings and assumed
        latency as designed); ignored by ``two-dof-true``.
    mu_assumed : float
        Friction the reference model assumes (default the run's friction).
    nominal : VehicleParams
        What the controller and the estimator believe (default ``params``, as nominal);
        a different set is a model error.
    """
    model = get_plant(plant) if isinstance(plant, str) else plant
    if is_multibody(model.name):
        nominal = nominal or params
        params = truth_params(model.name, params)
    model.check_params(params)
    disturbances = disturbances or Disturbances(friction=_uniform(params.mu))
    sensors = sensors or SensorConfig()
    if not (dt > 0 and np.isfinite(dt)):
        raise SimulationError(f"time step must be > 0 s, got {dt!r}")
    n = int(round(maneuver.duration / dt))
    t = np.arange(n) * dt
    W = disturbance_profile(disturbances, t)
    cmd = np.zeros((len(COMMANDS), n))
    cmd[COMMANDS.index("speed_ref")] = maneuver.speed
    cmd[COMMANDS.index("drive_on")] = maneuver.drive_on(t)
    cp = compiled_plant(model, params, dt, compile=compile)
    x0 = model.initial_state(params, maneuver.speed)
    if maneuver.path is not None:  # start on the path, aligned with it
        path = maneuver.path
        x0[model.state_index("x")], x0[model.state_index("y")] = path.x[0], path.y[0]
        x0[model.state_index("yaw")] = np.arctan2(path.y[1] - path.y[0], path.x[1] - path.x[0])
    meas = None
    if controller is not None:
        mu = disturbances.friction.mu if mu_assumed is None else mu_assumed
        X, Y, meas, extra = _stability_loop(cp, model, params, maneuver, x0, cmd, W, t, sensors, seed, controller,
                                            estimator, mu, nominal or params)
    elif maneuver.open_loop:
        cmd[COMMANDS.index("steer")] = maneuver.steer(t)
        cmd[COMMANDS.index("steer_rate")] = steer_rate(cmd[COMMANDS.index("steer")], dt)
        X, Y = cp.rollout(x0, cmd, W)
    else:
        X, Y = _closed_loop(cp, model, params, maneuver, x0, cmd, W, t)
    if is_multibody(model.name):
        check_rollover(model.name, X[model.state_index("roll")], dt, maneuver)
    if not np.all(np.isfinite(X)):
        k = int(np.argmax(~np.all(np.isfinite(X), axis=0)))
        raise SimulationError(f"{model.name} diverged at t = {k * dt:.3f} s ({maneuver.name}, "
                              f"{maneuver.speed * 3.6:.0f} km/h)")
    if is_multibody(model.name):
        _check_mb_speed(model, X, dt, maneuver)
    truth = {name: Y[i] for i, name in enumerate(TRUTH)}
    commands = {name: cmd[i] for i, name in enumerate(COMMANDS)}
    dist = {name: W[i] for i, name in enumerate(DISTURBANCES)}
    if meas is None:
        meas = measure(t, truth, {"steer": commands["steer"], "yaw_moment": commands["yaw_moment"],
                                  "bank": dist["bank"]}, sensors, seed, params.wheel_radius)
    else:
        commands.update(extra)
    meta = {"vehicle": params.name, "params_digest": params.digest(), "plant": model.name,
            "maneuver": maneuver.name, "speed_mps": maneuver.speed, "seed": seed, "dt": dt,
            "backend": cp.backend, "rk4_substeps": cp.n_sub, "events": dict(maneuver.events)}
    return SimResult(t=t, truth=truth, commands=commands, disturbances=dist, measurements=meas, meta=meta)


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


def _check_mb_speed(model, X, dt, maneuver) -> None:
    from plants.commonroad_mb import MIN_SPEED
    vx = X[model.state_index("vx")]
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
    from plants.disturbances import Friction
    return Friction(mu=mu)


def make_controller(kind, params: VehicleParams, dt: float):
    """A controller object from a name (``none``, ``yaw-pi``, ``two-dof``, ``two-dof-true``)."""
    from controllers.baselines import NoControl, YawRatePI
    from controllers.two_dof import TwoDofController, TwoDofDesign
    if not isinstance(kind, str):
        return kind
    if kind == "none":
        return NoControl(params.as_nominal())
    if kind == "yaw-pi":
        return YawRatePI(params.as_nominal())
    if kind in ("two-dof", "two-dof-true"):
        return TwoDofController(TwoDofDesign(params.as_nominal(), dt=dt))
    raise SimulationError(f"unknown controller '{kind}'; known: none, yaw-pi, two-dof, two-dof-true")


def _stability_loop(cp, model, params, maneuver, x0, cmd, W, t, sensors, seed, controller, estimator, mu, nominal):
    """Plant -> sensors -> estimator -> controller -> actuators -> plant, one sample at a time.

    Sensors read the truth of the previous sample (a one-sample sensor and
    computation delay, as on an ECU that samples, computes and then actuates); the
    logged sensor columns are exactly what the estimator was given.
    """
    from controllers.actuators import Actuators
    from plants.sensors import draw_noise
    from .estimation import design_filter
    from .estimation.component import EstimatorComponent

    n, dt = len(t), cp.dt
    true_states = controller == "two-dof-true"
    ctl = make_controller(controller, nominal, dt)
    from .estimation.spec import FilterDesign
    if true_states or estimator is None:
        est = None
    elif isinstance(estimator, FilterDesign):  # a designed filter (its own noise and assumed latency)
        est = EstimatorComponent(estimator)
    else:
        est = EstimatorComponent(design_filter(estimator, nominal, dt=dt, latency=sensors.gps_latency))
    act = Actuators(params)
    driver = None if maneuver.open_loop else PathDriver(maneuver.path, params)
    steer_drv = maneuver.steer(t) if maneuver.open_loop else np.zeros(n)
    noise = draw_noise(sensors, seed, n)
    X = np.empty((len(model.states), n + 1))
    Y = np.empty((len(TRUTH), n))
    X[:, 0] = x0
    _, y_prev = cp.step(x0, np.array([0.0, 0.0, maneuver.speed, 1.0, 0.0]), W[:, 0])
    hist = np.empty((len(TRUTH), n))
    inputs = {"steer": np.zeros(n), "yaw_moment": np.zeros(n), "bank": W[DISTURBANCES.index("bank")]}
    log_names = None
    meas_log = {}
    extra = {name: np.zeros(n) for name in ("steer_driver", "yaw_moment_cmd", "beta_ref", "yaw_rate_ref",
                                             "beta_est", "yaw_rate_est", "yaw_moment_limited", "steer_limited_last",
                                             "yaw_moment_limited_last", "steer_cmd")}
    ix, iy_, iyaw = (model.state_index(s) for s in ("x", "y", "yaw"))
    ivx = model.states.index("vx") if "vx" in model.states else None
    truth_idx = {name: i for i, name in enumerate(TRUTH)}
    est_state = est.initial_state(0.0) if est is not None else None
    ctl_state, act_state = ctl.initial_state(), act.initial_state()
    drv_state = driver.initial_state() if driver is not None else None
    flags = {"steer_limited": 0.0, "yaw_moment_limited": 0.0}
    x = x0
    applied = (0.0, 0.0)
    for k in range(n):
        hist[:, k] = y_prev  # the sensors sample the truth of the previous step ...
        inputs["steer"][k], inputs["yaw_moment"][k] = applied  # ... and the inputs applied over it
        truth_view = {name: hist[i, :k + 1] for name, i in truth_idx.items()}
        m = measure(t[:k + 1], truth_view, {key: v[:k + 1] for key, v in inputs.items()}, sensors, seed,
                    params.wheel_radius, noise=noise, index=k)
        m = {key: float(v[0]) for key, v in m.items()}
        if log_names is None:
            log_names = list(m)
            meas_log = {key: np.empty(n) for key in log_names}
        for key in log_names:
            meas_log[key][k] = m[key]
        if driver is not None:
            vx = x[ivx] if ivx is not None else maneuver.speed
            drv_state, steer_drv[k] = driver.steer(drv_state, x[ix], x[iy_], x[iyaw], vx)
        sig = dict(m)
        sig["dt"] = dt if k == 0 else t[k] - t[k - 1]
        if est is not None:
            est_state, e = est.step(est_state, t[k], sig)
            b, r = e["beta"], e["yaw_rate"]
            d1 = e["d1"] if np.isfinite(e["d1"]) else 0.0
            d2 = e["d2"] if np.isfinite(e["d2"]) else 0.0
        else:
            b, r, d1, d2 = y_prev[truth_idx["beta"]], y_prev[truth_idx["yaw_rate"]], 0.0, 0.0
        cs = {"speed": m["speed"], "steer_driver": steer_drv[k], "beta": b, "yaw_rate": r, "d1": d1, "d2": d2,
              "mu": mu, "dt": sig["dt"], **flags}
        extra["steer_limited_last"][k], extra["yaw_moment_limited_last"][k] = flags["steer_limited"], \
            flags["yaw_moment_limited"]
        ctl_state, u = ctl.step(ctl_state, t[k], cs)
        act_state, a = act.step(act_state, t[k], {"steer": u["steer"], "yaw_moment": u["yaw_moment"], "dt": sig["dt"]})
        flags = {"steer_limited": a["steer_limited"], "yaw_moment_limited": a["yaw_moment_limited"]}
        cmd[0, k], cmd[1, k] = a["steer"], a["yaw_moment"]
        cmd[4, k] = (a["steer"] - applied[0]) / sig["dt"]
        applied = (a["steer"], a["yaw_moment"])
        for key, val in (("steer_driver", steer_drv[k]), ("yaw_moment_cmd", u["yaw_moment"]),
                         ("beta_ref", u["beta_ref"]), ("yaw_rate_ref", u["yaw_rate_ref"]), ("beta_est", b),
                         ("yaw_rate_est", r), ("yaw_moment_limited", a["yaw_moment_limited"]),
                         ("steer_cmd", u["steer"])):
            extra[key][k] = val
        x, Y[:, k] = cp.step(x, cmd[:, k], W[:, k])
        y_prev = Y[:, k]
        if not np.all(np.isfinite(x)):
            X[:, k + 1:] = np.nan
            break
        X[:, k + 1] = x
    return X, Y, meas_log, extra


def _closed_loop(cp, model: PlantModel, params, maneuver, x0, cmd, W, t):
    driver = DriverComponent(PathDriver(maneuver.path, params))
    n = len(t)
    X = np.empty((len(model.states), n + 1))
    Y = np.empty((len(TRUTH), n))
    X[:, 0] = x0
    ix, iy, iyaw = (model.state_index(s) for s in ("x", "y", "yaw"))
    ivx = model.states.index("vx") if "vx" in model.states else None
    i_steer, i_rate = COMMANDS.index("steer"), COMMANDS.index("steer_rate")
    state = driver.initial_state()
    x = x0
    for k in range(n):
        vx = x[ivx] if ivx is not None else cmd[COMMANDS.index("speed_ref"), k]
        state, out = driver.step(state, t[k], {"x": x[ix], "y": x[iy], "yaw": x[iyaw], "vx": vx})
        cmd[i_steer, k] = out["steer"]
        cmd[i_rate, k] = (out["steer"] - (cmd[i_steer, k - 1] if k else 0.0)) / cp.dt
        x, Y[:, k] = cp.step(x, cmd[:, k], W[:, k])
        if not np.all(np.isfinite(x)):
            X[:, k + 1:] = np.nan
            break
        X[:, k + 1] = x
    return X, Y
