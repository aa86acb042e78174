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

from plants import COMMANDS, DISTURBANCES, TRUTH, PlantModel, VehicleParams, get_plant
from plants.disturbances import Disturbances, disturbance_profile
from plants.errors import EvstabError
from plants.maneuvers import Maneuver
from plants.paths import PathDriver
from plants.sensors import SensorConfig, measure

from .compiled import compiled_plant
from .logio import write_log_csv


class SimulationError(EvstabError, RuntimeError):
    """A run diverged (non-finite state) or was set up inconsistently."""


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
        return cols

    def write_csv(self, path) -> None:
        """Write the drive log atomically."""
        write_log_csv(path, self.log_columns())


def simulate(params: VehicleParams, plant: str | PlantModel, maneuver: Maneuver, *,
             disturbances: Disturbances | None = None, sensors: SensorConfig | None = None,
             seed: int = 0, dt: float = 1e-3, compile: bool = True) -> SimResult:
    """Run one manoeuvre on one plant and return the named signals.

    Parameters
    ----------
    params : VehicleParams
        The vehicle (the truth the plant simulates).
    plant : str or PlantModel
        ``bicycle``, ``bicycle-roll`` or ``two-track``.
    maneuver : Maneuver
        See :mod:`plants.maneuvers`.
    disturbances, sensors : optional
        Wind, friction, bank; sensor noise, GPS rate/outages/latency.
    seed : int
        Seeds every noise source; equal seeds give identical runs.
    dt : float
        Fixed step [s].
    """
    model = get_plant(plant) if isinstance(plant, str) else plant
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
    if maneuver.open_loop:
        cmd[COMMANDS.index("steer")] = maneuver.steer(t)
        X, Y = cp.rollout(x0, cmd, W)
    else:
        X, Y = _closed_loop(cp, model, params, maneuver, x0, cmd, W, t)
    if not np.all(np.isfinite(X)):
        k = int(np.argmax(~np.all(np.isfinite(X), axis=0)))
        raise SimulationError(f"{model.name} diverged at t = {k * dt:.3f} s ({maneuver.name}, "
                              f"{maneuver.speed * 3.6:.0f} km/h)")
    truth = {name: Y[i] for i, name in enumerate(TRUTH)}
    commands = {name: cmd[i] for i, name in enumerate(COMMANDS)}
    dist = {name: W[i] for i, name in enumerate(DISTURBANCES)}
    meas = measure(t, truth, {"steer": commands["steer"], "yaw_moment": commands["yaw_moment"],
                              "bank": dist["bank"]}, sensors, seed, params.wheel_radius)
    meta = {"vehicle": params.name, "params_digest": params.digest(), "plant": model.name,
            "maneuver": maneuver.name, "speed_mps": maneuver.speed, "seed": seed, "dt": dt,
            "backend": cp.backend, "rk4_substeps": cp.n_sub, "events": dict(maneuver.events)}
    return SimResult(t=t, truth=truth, commands=commands, disturbances=dist, measurements=meas, meta=meta)


def _uniform(mu: float):
    from plants.disturbances import Friction
    return Friction(mu=mu)


def _closed_loop(cp, model: PlantModel, params, maneuver, x0, cmd, W, t):
    driver = DriverComponent(PathDriver(maneuver.path, params))
    n = len(t)
    X = np.empty((len(model.states), n + 1))
    Y = np.empty((len(TRUTH), n))
    X[:, 0] = x0
    ix, iy, iyaw = (model.state_index(s) for s in ("x", "y", "yaw"))
    ivx = model.states.index("vx") if "vx" in model.states else None
    i_steer = COMMANDS.index("steer")
    state = driver.initial_state()
    x = x0
    for k in range(n):
        vx = x[ivx] if ivx is not None else cmd[COMMANDS.index("speed_ref"), k]
        state, out = driver.step(state, t[k], {"x": x[ix], "y": x[iy], "yaw": x[iyaw], "vx": vx})
        cmd[i_steer, k] = out["steer"]
        x, Y[:, k] = cp.step(x, cmd[:, k], W[:, k])
        if not np.all(np.isfinite(x)):
            X[:, k + 1:] = np.nan
            break
        X[:, k + 1] = x
    return X, Y
