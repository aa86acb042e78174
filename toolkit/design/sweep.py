"""Model-error sweeps of the closed loop with the estimator in it.

A :class:`Case` is one model error: the plant's cornering stiffnesses, mass and yaw
inertia scaled against what the designer believes, the road friction, the speed,
the GPS rate and latency, the gyro's bias and scale error. For each case and each
design (:class:`DesignPoint`: gains and noise intensities) the sweep gives

* a stability verdict: the sampled multi-rate loop with the estimator in it
  (:func:`toolkit.design.stability.estimator_loop`, linear bicycle with the case's mass,
  inertia and stiffness at the case's speed and GPS rate; spectral radius of the
  monodromy) **and** boundedness of the nonlinear rollouts (finite, |beta| below
  ``SPIN_BETA``); latency, friction and gyro errors act through the rollouts;
* estimation and tracking errors and actuator usage on the standard manoeuvre set
  (:func:`standard_maneuvers`), run as compiled loops on the two-track plant;
* a cost (:func:`cost_terms`), the quantity the tuning minimises in the worst case.

All of it is data: one row per case and design (:func:`evaluate_cases`). The
local executor is a process pool; :func:`run_sweep` with ``executor="dask"`` sends
the same batches to a Dask cluster. Cases carry their own seed, so results do not
depend on the executor or the batching.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import TRUTH, VehicleParams, is_multibody, truth_params
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import Maneuver, sine_lane_change, step_steer, steer_for_lateral_acceleration
from evstab.plants.sensors import SensorConfig

from ..loop.closed_loop import EXTRA, loop_spec, noise_matrix, samples
from ..loop.loop_program import program
from ..estimation import design_filter
from ..estimation.spec import FilterDesign, NoiseSettings
from .stability import estimator_loop
from evstab.plants.errors import SettingsError

SPIN_BETA = np.deg2rad(20.0)
"""A rollout whose true sideslip exceeds this [rad] has lost the car (not bounded)."""
R_SCALE = np.deg2rad(1.0)
"""Yaw-rate tracking error that costs 1 [rad/s]."""
B_SCALE = np.deg2rad(0.5)
"""Sideslip tracking error that costs 1 [rad]."""
E_SCALE = np.deg2rad(0.5)
"""Sideslip estimation error that costs 1 [rad]."""
U_WEIGHT = 0.1
"""Weight of the mean-square yaw moment, relative to the largest the motors make."""
MANEUVER_DURATION = 5.0
"""Every standard manoeuvre lasts this long [s] (the tuning's rollouts have one length)."""


@dataclass(frozen=True)
class Case:
    """One model-error case (scales are plant / nominal)."""

    case_id: int
    cf_scale: float = 1.0
    cr_scale: float = 1.0
    mu: float = 1.0
    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    speed_kmh: float = 80.0
    gps_rate: float = 5.0
    gps_latency: float = 0.0
    gyro_bias: float = 0.0
    """[rad/s]"""
    gyro_scale_error: float = 0.0
    group: str = "nominal"
    """Which family of the sweep the case belongs to (grid, axis, random)."""

    @property
    def seed(self) -> int:
        return 1000 + self.case_id

    def plant_params(self, nominal: VehicleParams) -> VehicleParams:
        p = nominal
        kw = {"cornering_stiffness_front": p.cornering_stiffness_front * self.cf_scale,
              "cornering_stiffness_rear": p.cornering_stiffness_rear * self.cr_scale,
              "mass": p.mass * self.mass_scale, "yaw_inertia": p.yaw_inertia * self.inertia_scale,
              "mu": self.mu}
        if p.sprung_mass is not None:  # the body is what gets heavier or lighter
            kw["sprung_mass"] = p.sprung_mass * self.mass_scale
        return dataclasses.replace(p, **kw)

    def sensors(self, base: SensorConfig) -> SensorConfig:
        return dataclasses.replace(base, gps_rate=self.gps_rate, gps_latency=self.gps_latency,
                                   gyro_bias=self.gyro_bias, gyro_scale_error=self.gyro_scale_error)


CASE_FIELDS = tuple(f.name for f in dataclasses.fields(Case))


@dataclass(frozen=True)
class DesignPoint:
    """What the tuning chooses: the model-following poles and the process-noise intensities."""

    name: str
    k_beta: float = 5.0
    k_gamma: float = 5.0
    q_beta: float = NoiseSettings.q_beta
    q_yaw_rate: float = NoiseSettings.q_yaw_rate
    q_d1: float = NoiseSettings.q_d1
    q_d2: float = NoiseSettings.q_d2

    TUNED = ("k_beta", "k_gamma", "q_beta", "q_yaw_rate", "q_d1", "q_d2")

    def vector(self) -> np.ndarray:
        return np.array([getattr(self, k) for k in self.TUNED])

    def calibration(self) -> dict:
        """The ECU calibration entries this point sets (:meth:`toolkit.ecu.step.EcuDesign.calibration` names)."""
        return {k: float(getattr(self, k)) for k in self.TUNED}

    def noise(self, base: NoiseSettings | None = None) -> NoiseSettings:
        return dataclasses.replace(base or NoiseSettings(), q_beta=self.q_beta, q_yaw_rate=self.q_yaw_rate,
                                   q_d1=self.q_d1, q_d2=self.q_d2)

    def controller(self, base: TwoDofDesign) -> TwoDofDesign:
        return dataclasses.replace(base, k_beta=self.k_beta, k_gamma=self.k_gamma)


PAPER = DesignPoint("paper")
"""Seed 003's K_beta = K_gamma = 5 rad/s with the hand-tuned noise intensities of ``dakf``."""


@dataclass(frozen=True)
class SweepConfig:
    """Everything a worker needs (picklable): the nominal vehicle and the design structure."""

    nominal: VehicleParams
    plant: str = "two-track"
    estimator: str = "dakf"
    dt: float = 1e-3
    sensors: SensorConfig = SensorConfig()
    ay_lane_change: float = 4.0
    """Peak lateral acceleration [m/s^2] the lane change asks for (linear, nominal car)."""
    ay_step: float = 3.0
    noise: NoiseSettings | None = None
    """The filter's noise settings (a noise file's, :func:`toolkit.estimation.noise_fit.load_noise`);
    None: the method's defaults. The paper point starts from their process-noise intensities."""
    kinematic: bool = True
    """The ECU's filter with the kinematic sideslip path (:func:`toolkit.estimation.spec.design_filter`;
    ``evstab design --no-kinematic-path``: without)."""

    @property
    def paper(self) -> "DesignPoint":
        """Seed 003's gains with this configuration's process noise: the design the tuning starts from
        and is judged against (:data:`PAPER` without a noise file)."""
        if self.noise is None:
            return PAPER
        n = self.noise
        return DesignPoint("paper", q_beta=n.q_beta, q_yaw_rate=n.q_yaw_rate, q_d1=n.q_d1, q_d2=n.q_d2)

    def base_design(self) -> TwoDofDesign:
        return TwoDofDesign(self.nominal.as_nominal(), dt=self.dt)

    def filter_design(self, point: DesignPoint) -> FilterDesign:
        base = design_filter(self.estimator, self.nominal, self.noise, dt=self.dt, latency=self.sensors.gps_latency,
                             control=True, kinematic=None if self.kinematic else False)
        return dataclasses.replace(base, noise=point.noise(base.noise))

    def spec(self):
        return loop_spec(self.nominal, plant=self.plant, estimator=self.filter_design(self.paper), sensors=self.sensors,
                         dt=self.dt, design=self.base_design())


def standard_maneuvers(cfg: SweepConfig, speed: float) -> list[Maneuver]:
    """The manoeuvre set every case drives: a sine lane change and a step steer, amplitudes
    for ``ay_lane_change`` / ``ay_step`` on the nominal car at ``speed`` (so the low-friction
    cases run into the limit, where stability control matters)."""
    p = cfg.nominal
    a1 = steer_for_lateral_acceleration(p, speed, cfg.ay_lane_change)
    a2 = steer_for_lateral_acceleration(p, speed, cfg.ay_step)
    return [sine_lane_change(speed, a1, start=1.0, period=2.5, duration=MANEUVER_DURATION),
            step_steer(speed, a2, start=0.5, duration=MANEUVER_DURATION)]


def cost_terms(Y: np.ndarray, E: np.ndarray) -> dict:
    """Mean squares over one rollout (samples x signals arrays as the compiled loop returns)."""
    y, e = TRUTH.columns(Y), EXTRA.columns(E)
    e_est = e["beta_est"] - y["beta"]
    e_r = y["yaw_rate"] - e["yaw_rate_ref"]
    e_b = y["beta"] - e["beta_ref"]
    return {"ms_est": float(np.mean(e_est**2)), "ms_r": float(np.mean(e_r**2)), "ms_b": float(np.mean(e_b**2)),
            "ms_nz": float(np.mean(e["yaw_moment"] ** 2))}


def cost_of(ms_r, ms_b, ms_est, ms_nz, nz_max):
    """The cost of one rollout from its mean squares: yaw-rate tracking, sideslip tracking, sideslip
    estimation, yaw moment. Plain arithmetic, so numbers and casadi expressions alike (the sweep's
    rows and the tuning's differentiable objective are this one formula)."""
    return ms_r / R_SCALE**2 + ms_b / B_SCALE**2 + ms_est / E_SCALE**2 + U_WEIGHT * ms_nz / nz_max**2


def cost_value(terms: dict, nz_max: float) -> float:
    """The cost of one rollout from its mean squares (:func:`cost_terms`)."""
    return float(cost_of(terms["ms_r"], terms["ms_b"], terms["ms_est"], terms["ms_nz"], nz_max))


def linear_verdict(cfg: SweepConfig, case: Case, point: DesignPoint) -> tuple[bool, float]:
    """(stable, spectral radius) of the multi-rate loop with the estimator, linearised for the case
    (:func:`toolkit.design.stability.estimator_loop`: the loop step with the linear bicycle of the case's
    parameters as the plant; on a ``commonroad-mb`` plant that bicycle is the nominal one, the
    multi-body car itself is judged by the bounded rollouts)."""
    true = case.plant_params(cfg.nominal)
    v = max(case.speed_kmh / 3.6, 3.0)
    try:
        _, st = estimator_loop(point.controller(cfg.base_design()), cfg.filter_design(point), v, true_params=true,
                               gps_rate=case.gps_rate, dt=cfg.dt)
    except np.linalg.LinAlgError:
        return False, float("nan")
    return st.stable, 1.0 - st.margin


def case_setup(cfg: SweepConfig, case: Case):
    """What a case's runs are made of: (the plant's parameters, sensors, disturbances, manoeuvres)."""
    return (truth_params(cfg.plant, case.plant_params(cfg.nominal)), case.sensors(cfg.sensors),
            Disturbances(friction=Friction(mu=case.mu)), standard_maneuvers(cfg, case.speed_kmh / 3.6))


def case_inputs(cfg: SweepConfig, case: Case, prog=None):
    """Per manoeuvre: (U, z0, p) for the compiled loop, and the theta entries of the case."""
    prog = prog if prog is not None else program(cfg.spec())
    true, sens, dist, mans = case_setup(cfg, case)
    return prog, [prog.inputs(true, man, dist, sens, case.seed) for man in mans]


def _summary(Y: np.ndarray, E: np.ndarray, nz_max: float) -> dict:
    """What a row needs of one rollout (the signals themselves are dropped)."""
    it, ie = TRUTH.index("beta"), EXTRA.index
    finite = bool(np.all(np.isfinite(Y)) and np.all(np.isfinite(E)))
    if not finite:
        terms = {k: float("inf") for k in ("ms_est", "ms_r", "ms_b", "ms_nz")}
        return {"finite": False, "beta_max": float("inf"), "terms": terms, "cost": float("inf"), "nz_peak": 0.0,
                "steer_corr": 0.0}
    terms = cost_terms(Y, E)
    return {"finite": True, "beta_max": float(np.max(np.abs(Y[:, it]))), "terms": terms,
            "cost": cost_value(terms, nz_max), "nz_peak": float(np.max(np.abs(E[:, ie("yaw_moment")]))),
            "steer_corr": float(np.max(np.abs(E[:, ie("steer")] - E[:, ie("steer_driver")])))}


def _row(cfg: SweepConfig, case: Case, point: DesignPoint, runs: list[dict], linear: bool) -> dict:
    """The sweep's row of one case and design point from its rollouts' summaries (:func:`_summary`)."""
    nz_max = cfg.base_design().nz_max
    bounded = all(r["finite"] and r["beta_max"] < SPIN_BETA for r in runs)
    lin_stable, rho = linear_verdict(cfg, case, point) if linear else (True, float("nan"))
    mean = {k: float(np.mean([r["terms"][k] for r in runs])) for k in runs[0]["terms"]}
    row = {f: getattr(case, f) for f in CASE_FIELDS}
    row.update({
        "design": point.name, "stable": bool(lin_stable and bounded), "linear_stable": bool(lin_stable),
        "spectral_radius": rho, "bounded": bool(bounded),
        "beta_rms_deg": float(np.degrees(np.sqrt(mean["ms_est"]))),
        "yaw_rate_rms_err": float(np.sqrt(mean["ms_r"])),
        "beta_track_rms_deg": float(np.degrees(np.sqrt(mean["ms_b"]))),
        "yaw_moment_rms": float(np.sqrt(mean["ms_nz"])),
        "yaw_moment_peak_share": max(r["nz_peak"] for r in runs) / nz_max,
        "steer_correction_max_deg": float(np.degrees(max(r["steer_corr"] for r in runs))),
        "beta_max_deg": float(np.degrees(max(r["beta_max"] for r in runs))),
        "cost": float(np.mean([r["cost"] for r in runs])),
    })
    return row


def evaluate_case(cfg: SweepConfig, case: Case, points: list[DesignPoint], *, linear: bool = True) -> list[dict]:
    """One row per design point: the case, the rollouts' metrics and (``linear``) the linear verdict."""
    return evaluate_cases(cfg, [case], points, linear=linear)


BLOCK = 32
"""Cases rolled out together by :func:`evaluate_cases`; bounds the memory a batch holds at once
(one manoeuvre's inputs and signals: 32 cases x 5 s at 1 kHz x 64 numbers, about 80 MB)."""

_WORKSPACE = threading.local()
"""The rollouts' input and signal arrays of a thread (``arrays``: name -> flat array), kept from one
block (and one task) to the next: fresh arrays of this size come from the operating system as
untouched pages, and faulting them in (zero-filled) cost about a tenth of a sweep worker's time
(docs/internals.md). Per thread, because Dask's
in-process cluster runs its workers as threads of one process."""


def _workspace(name: str, shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised C-ordered float array of ``shape``, in this thread's memory reused between calls
    with the same ``name`` (the previous array of that name is invalid afterwards)."""
    arrays = _WORKSPACE.__dict__.setdefault("arrays", {})
    size = int(np.prod(shape))
    buf = arrays.get(name)
    if buf is None or buf.size < size:
        buf = arrays[name] = np.empty(size)
    return buf[:size].reshape(shape)


def release_workspace() -> None:
    """Free this thread's rollout arrays (a sweep run in the calling process does, when it is done)."""
    _WORKSPACE.__dict__.pop("arrays", None)


def case_thetas(cfg: SweepConfig, prog, point: DesignPoint, cases: list[Case]) -> np.ndarray:
    """The run-time parameters of ``cases`` under design ``point`` (cases x theta): the point's
    calibration, each case's gyro errors, and the ECU not told the road (its mu input is the design's
    "no road sensor" value)."""
    mu_assumed = cfg.base_design().mu_max
    return np.array([prog.theta(**point.calibration(), gyro_bias=c.gyro_bias, gyro_scale_error=c.gyro_scale_error,
                                mu_assumed=mu_assumed) for c in cases])


def evaluate_cases(cfg: SweepConfig, cases: list[Case], points: list[DesignPoint], linear: bool = True) -> list[dict]:
    """Rows for a batch of cases (the unit of work an executor runs), case by case and point by point
    as :func:`evaluate_case` orders them. The cases' rollouts of one manoeuvre and design point are one
    call of the compiled loop (:meth:`LoopProgram.run_batch`), in blocks of :data:`BLOCK` cases."""
    prog = program(cfg.spec())
    nz_max = cfg.base_design().nz_max
    rows: dict[tuple[int, int], dict] = {}
    for s in range(0, len(cases), BLOCK):
        block = list(cases[s:s + BLOCK])
        thetas = [case_thetas(cfg, prog, point, block) for point in points]
        setup = [case_setup(cfg, c) for c in block]
        rollouts: list[list[list]] = [[[] for _ in block] for _ in points]
        # a case's runs of one length draw the same noise (its seed): drawn once, shared by its manoeuvres
        noise: dict[tuple[int, int], np.ndarray] = {}
        for m in range(len(setup[0][3])):
            by_len: dict[int, list[int]] = {}  # one call per manoeuvre length (the standard set has one)
            for i, (_, _, _, mans) in enumerate(setup):
                by_len.setdefault(samples(prog.spec, mans[m]), []).append(i)
            for n, idx in by_len.items():
                # filled in place, case by case and signal by signal: each input signal's samples lie side
                # by side (the lane kernel reads any strides), so that every write is contiguous
                U = _workspace("inputs", (len(idx), prog.nin, n)).transpose(0, 2, 1)
                z0_rows: list = []
                pv_rows: list = []
                for q, i in enumerate(idx):
                    true, sens, dist, mans = setup[i]
                    if (i, n) not in noise:
                        noise[(i, n)] = noise_matrix(sens, block[i].seed, n)
                    _, z, p = prog.inputs(true, mans[m], dist, sens, block[i].seed, out=U[q], noise=noise[(i, n)])
                    z0_rows.append(z)
                    pv_rows.append(p)
                z0, pv = np.array(z0_rows), np.array(pv_rows)
                for j in range(len(points)):
                    Y, E = prog.run_batch(U, z0, pv, thetas[j][idx],
                                          out=(_workspace("truth", (len(idx), n, len(TRUTH))),
                                               _workspace("extra", (len(idx), n, len(EXTRA)))))
                    for q, i in enumerate(idx):
                        rollouts[j][i].append(_summary(Y[q], E[q], nz_max))
        for j, point in enumerate(points):
            for i, c in enumerate(block):
                rows[(s + i, j)] = _row(cfg, c, point, rollouts[j][i], linear)
    return [rows[(i, j)] for i in range(len(cases)) for j in range(len(points))]


def single_threaded_blas() -> None:
    """Process-pool initializer: one BLAS thread per worker. The matrices here are at most
    13 x 13, and two workers with two BLAS threads each on two cores ran the linear verdicts
    2x slower than one worker (measured)."""
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)


def _batches(cases: list[Case], size: int) -> list[list[Case]]:
    return [cases[i:i + size] for i in range(0, len(cases), size)]


def run_sweep(cfg: SweepConfig, cases: list[Case], points: list[DesignPoint], *, executor: str = "local",
              scheduler: str | None = None, workers: int | None = None, progress: bool = True,
              batch: int = 4, linear: bool = True) -> list[dict]:
    """Evaluate every case for every design point; rows sorted by (case_id, design order).

    ``executor``: ``local`` (a process pool of ``workers``, default the CPU count; 1 runs
    in this process), ``dask`` (a Dask distributed cluster at ``scheduler``, or a local
    cluster when none is given). Results are identical either way. ``batch`` cases go to a task,
    rounded up to a multiple of the compiled loop's lane width (a task's cases are stepped
    together, :func:`evaluate_cases`).
    """
    from ..kernels.lanes import native_width
    width = native_width()
    batches = _batches(list(cases), -(-max(1, batch) // width) * width)
    results: list[list[dict]] = [None] * len(batches)  # type: ignore[list-item]
    bar = progress_bar(len(cases), progress)
    if executor == "local":
        workers = workers or os.cpu_count() or 1
        if workers == 1:
            try:
                for i, b in enumerate(batches):
                    results[i] = evaluate_cases(cfg, b, points, linear)
                    bar.update(len(b))
            finally:
                release_workspace()
        else:
            program(cfg.spec()).compile()  # once here; the forked workers inherit the loaded library
            import multiprocessing as mp
            # fork where there is one (no re-import of the caller's script); the pool is torn
            # down before anything else runs, and casadi starts no threads of its own
            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context(method),
                                     initializer=single_threaded_blas) as pool:
                futs = {pool.submit(evaluate_cases, cfg, b, points, linear): i for i, b in enumerate(batches)}
                from concurrent.futures import as_completed
                for f in as_completed(futs):
                    results[futs[f]] = f.result()
                    bar.update(len(batches[futs[f]]))
    elif executor == "dask":
        from distributed import Client, LocalCluster, as_completed as dask_completed
        cluster = None
        if scheduler is None:
            cluster = LocalCluster(n_workers=workers or 1, threads_per_worker=1, processes=False,
                                   dashboard_address=None)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        try:
            program(cfg.spec()).compile()  # once here; the workers load the cached library
            dask_futs = [client.submit(evaluate_cases, cfg, b, points, linear, pure=False) for b in batches]
            index = {f.key: i for i, f in enumerate(dask_futs)}
            for f in dask_completed(dask_futs):
                results[index[f.key]] = f.result()
                bar.update(len(batches[index[f.key]]))
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        raise SettingsError(f"unknown executor '{executor}'; known: local, dask")
    bar.close()
    return [row for rs in results for row in rs]


def progress_bar(total: int | None, enabled: bool, desc: str = "sweep", unit: str = "case"):
    """A progress bar on stderr (``total`` None: a count without an end), as every phase of the design job
    shows one."""
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, leave=False)


def sweep_cases(quick: bool = False, seed: int = 7, plant: str = "two-track") -> list[Case]:
    """The sweep's cases: a front x rear stiffness grid, one-at-a-time axes, random combinations.

    Ranges: stiffness -40..+40 %, mu 0.3..1, mass and yaw inertia +-20 %, speed, GPS 1..20 Hz,
    latency 0..150 ms, gyro bias +-5 mrad/s and scale error +-2 %. On a ``commonroad-mb`` plant
    the car is the package's set, whatever the nominal says: its model error is fixed (the
    nominal file against the multi-body car), so of the stiffness grid only its centre (the car
    itself) stays, the mass and inertia axes are left out and the random cases draw only
    friction, speed, GPS and gyro errors.
    """
    if is_multibody(plant):
        def fixed(c):
            return c.group not in ("stiffness", "mass_scale", "inertia_scale") or (
                c.group == "stiffness" and c.cf_scale == 1.0 and c.cr_scale == 1.0)
        kept = [c for c in sweep_cases(quick, seed) if fixed(c)]
        return [dataclasses.replace(c, case_id=i, cf_scale=1.0, cr_scale=1.0, mass_scale=1.0, inertia_scale=1.0)
                for i, c in enumerate(kept)]
    cases: list[Case] = []

    def add(group, **kw):
        cases.append(Case(len(cases), group=group, **kw))

    grid = (0.6, 1.0, 1.4) if quick else (0.6, 0.8, 1.0, 1.2, 1.4)
    for cf in grid:
        for cr in grid:
            add("stiffness", cf_scale=cf, cr_scale=cr)
    axes = [("mu", (0.3, 0.6) if quick else (0.3, 0.45, 0.6, 0.8)),
            ("gps_rate", (1.0, 20.0) if quick else (1.0, 2.0, 10.0, 20.0)),
            ("gps_latency", (0.15,) if quick else (0.05, 0.1, 0.15)),
            ("speed_kmh", (40.0, 120.0) if quick else (20.0, 40.0, 60.0, 100.0, 120.0, 140.0))]
    if not quick:
        axes += [("mass_scale", (0.8, 1.2)), ("inertia_scale", (0.8, 1.2)), ("gyro_bias", (-0.005, 0.005)),
                 ("gyro_scale_error", (-0.02, 0.02))]
    for name, values in axes:
        for v in values:
            add(name, **{name: v})
    rng = np.random.default_rng(seed)
    for _ in range(6 if quick else 120):
        add("random", cf_scale=rng.uniform(0.6, 1.4), cr_scale=rng.uniform(0.6, 1.4), mu=rng.uniform(0.3, 1.0),
            mass_scale=rng.uniform(0.8, 1.2), inertia_scale=rng.uniform(0.8, 1.2),
            speed_kmh=float(rng.choice([40.0, 60.0, 80.0, 100.0, 120.0])),
            gps_rate=float(rng.choice([1.0, 2.0, 5.0, 10.0, 20.0])),
            gps_latency=float(rng.choice([0.0, 0.05, 0.1, 0.15])), gyro_bias=rng.uniform(-0.005, 0.005),
            gyro_scale_error=rng.uniform(-0.02, 0.02))
    return cases
