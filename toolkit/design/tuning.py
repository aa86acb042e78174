"""Worst-case tuning of the model-following poles and the estimator's noise intensities.

Decision variables: ``phi = log(K_beta, K_gamma, q_beta, q_yaw_rate, q_d1, q_d2)``
(logarithms: all six are positive scale parameters spanning decades). The
objective is the worst case over a set of tuning cases of the sweep's cost
(:func:`toolkit.design.sweep.cost_value`, averaged over the standard manoeuvres), in
epigraph form for IPOPT::

    min  t   over (phi, t)
    s.t. log J_i(phi) <= t                   every tuning case i (log: costs span 1e-2..1e5)
         sigma_j(phi) >= min(SIGMA_MIN, sigma_j(start))   stability with a margin, every tuning case j
                                             (no less than the start's where it has less)
         log J_i(phi) <= log cap_i           no regression where the caller caps a case
         D_k(phi) >= 1.83 m + margin         FMVSS 126 lateral displacement, every run k given
         phi within the bounds around the start (BOUNDS unless told)

``J_i`` and its gradient come from casadi's algorithmic differentiation of the same
``loop_step`` the sweep compiles (plant, sensors, estimator, controller, actuators built
from the same model definitions): in forward mode, the step carrying its tangents along
``phi`` and the cost's sums, rolled out as a lane kernel four runs at a time
(:func:`toolkit.design.rollout._forward_step`); without a lane kernel in reverse mode, ``jacobian(cost, phi)``
through a ``mapaccum`` rollout generated as C. Both are compiled once (cached).
``sigma_j`` is the decay rate of the sampled multi-rate loop with the estimator
(``-ln(rho) * f_gps`` from the monodromy's spectral radius), evaluated by
:func:`toolkit.design.stability.estimator_loop` with finite differences (a spectral radius
has no closed-form derivative). ``D_k`` is FMVSS 126's lateral displacement at BOS + 1.07 s
of a sine-with-dwell run (:class:`DisplacementRun`): linear in the run's lateral acceleration,
so the same forward-mode rollout that carries the acceleration's derivatives gives its
gradient. Reproducible: the cases carry their seeds and IPOPT is deterministic; the lane
kernel's arithmetic is IEEE without contraction and its own vector ``sin``/``atan``, so the
same on every x86-64 machine. One IPOPT run's path does move with rounding (a gradient
perturbed by 1e-12 relative ends elsewhere); several starts (:func:`tune`'s ``starts``) make the
result depend on it less (``studies/tuning_spread.py``).

The tuning cases are chosen by the caller (:func:`tune` takes them); the design job
uses the paper design's worst cases of the sweep plus the nominal case, and re-adds
the tuned design's worst case when it lies outside the set (a cutting-plane round).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import casadi as ca
import numpy as np

from . import sweep
from .rollout import RolloutCost
from .sweep import Case, DesignPoint, SweepConfig
from evstab.plants.errors import SettingsError

SIGMA_MIN = 0.01
"""Smallest decay rate [1/s] the multi-rate loop must keep on every tuning case (time constant <= 100 s)."""
REGRESS_FACTOR = 2.0
REGRESS_OFFSET = 1.0
"""Cap on a paper-stable tuning case's cost: ``REGRESS_FACTOR * J_paper + REGRESS_OFFSET`` (1 cost unit is
a 1 deg/s RMS yaw-rate tracking error)."""
BOUNDS = 2.0
"""Each tuned parameter stays within a factor e^2 (7.4) of its start (the paper design)."""


class _Function(ca.Callback):
    """A casadi function ``R^n_in -> R^n_out`` evaluated by Python (``value(x)``) with its Jacobian
    (``jacobian(x)``, ``n_out x n_in``) as a second callback, so IPOPT can take the gradient path."""

    def __init__(self, name: str, n_in: int, n_out: int, value, jacobian):
        ca.Callback.__init__(self)
        self._n, self._m, self._value, self._jacobian = n_in, n_out, value, jacobian
        self.construct(name, {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self._n, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self._m, 1)

    def eval(self, arg):
        return [self._value(np.array(arg[0]).ravel())]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        outer = self

        class Jac(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.construct(name, opts)

            def get_n_in(self):
                return 2

            def get_n_out(self):
                return 1

            def get_sparsity_in(self, i):
                return ca.Sparsity.dense(outer._n, 1) if i == 0 else ca.Sparsity.dense(outer._m, 1)

            def get_sparsity_out(self, i):
                return ca.Sparsity.dense(outer._m, outer._n)

            def eval(self, arg):
                return [outer._jacobian(np.array(arg[0]).ravel())]

        self._jac = Jac()
        return self._jac


def phi_of(point: DesignPoint) -> np.ndarray:
    return np.log(point.vector())


def point_of(phi: np.ndarray, name: str = "tuned") -> DesignPoint:
    vals = np.exp(np.asarray(phi, float))
    return DesignPoint(name, **{k: float(v) for k, v in zip(DesignPoint.TUNED, vals)})


def decay_rate(cfg: SweepConfig, case: Case, point: DesignPoint) -> float:
    """``-ln(rho) f_gps`` [1/s] of the multi-rate loop with the estimator (negative: unstable; -1 where
    the estimator's periodic gains have no stabilising Riccati solution to compute them from)."""
    try:
        _, rho = sweep.linear_verdict(cfg, case, point)
    except (ValueError, np.linalg.LinAlgError):  # scipy's DARE: the pencil too ill-conditioned to reorder
        return -1.0
    if not np.isfinite(rho):
        return -1.0
    return float(-np.log(rho) * case.gps_rate)


STARTS_SEED = 0
"""Seed of the tuning's further starting points (:func:`tune`)."""
DISPLACEMENT_MARGIN = 0.02
"""[m] The tuning holds an FMVSS 126 run's lateral displacement this much above the criterion (IPOPT
meets constraints to its tolerance; the check reads the criterion itself)."""


@dataclass(frozen=True)
class DisplacementRun:
    """An FMVSS 126 run whose lateral displacement at BOS + 1.07 s the tuning keeps at or above
    ``bound`` (+ :data:`DISPLACEMENT_MARGIN`): ``run`` is its ``(U, z0, pv)`` in the tuning's loop,
    ``rest`` its case entries of theta, ``displacement`` the linear map from the truth's lateral
    acceleration to the displacement (:func:`toolkit.verdicts.fmvss126.displacement_map`; linear, so it maps
    the acceleration's derivatives to the displacement's). Built by
    :func:`toolkit.design.limits.displacement_runs`."""
    label: str
    run: tuple
    rest: np.ndarray
    displacement: object
    bound: float


@dataclass
class TuningResult:
    point: DesignPoint
    start: DesignPoint
    cases: list[int]
    worst_start: float
    worst_tuned: float
    costs_start: list[float]
    costs_tuned: list[float]
    sigma_tuned: list[float]
    displacement_tuned: list[float]
    """[m] per :class:`DisplacementRun` given, at the tuned point"""
    iterations: int
    status: str
    evaluations: int


_WORKER: dict = {}
"""Rollout cost and case data of the current tuning, inherited by forked worker processes."""


def _eval_subset(phi: np.ndarray, idx: list[int]):
    rc, data = _WORKER["rc"], _WORKER["data"]
    owner = [i for i in idx for _ in data[i][0]]
    vals = rc.batch(phi, [run for i in idx for run in data[i][0]], [data[i][1] for i in owner])
    out = []
    for i in idx:
        mine = [v for o, v in zip(owner, vals) if o == i]
        out.append((i, float(np.mean([v[0] for v in mine])), np.mean([v[1] for v in mine], axis=0)))
    return out


def _displacement_subset(phi: np.ndarray, idx: list[int]):
    rc, runs = _WORKER["rc"], _WORKER["displacement"]
    acc = rc.lateral_acceleration(phi, [runs[i].run for i in idx], [runs[i].rest for i in idx])
    return [(i, runs[i].displacement(a), np.array([runs[i].displacement(da[:, j]) for j in range(da.shape[1])]))
            for i, (a, da) in zip(idx, acc)]


@dataclass(frozen=True)
class MarginConstraint:
    """The margin constraint (:func:`toolkit.design.stability.margins_admissible`) as the tuning holds it: the
    disk margin and sensitivity peak of the loop (:func:`toolkit.design.stability.loop_margins`) on the design's
    own model at every speed of ``speeds_kmh``."""

    speeds_kmh: tuple

    @classmethod
    def on_analysis_grid(cls) -> "MarginConstraint":
        """The constraint at every speed of the design job's analysis (:data:`toolkit.design.analysis.SPEEDS_KMH`)."""
        from .analysis import SPEEDS_KMH
        return cls(tuple(SPEEDS_KMH))


def margin_values(cfg: SweepConfig, phi: np.ndarray, mc: MarginConstraint) -> np.ndarray:
    """``[disk margin, -sensitivity peak]`` of the design point ``phi`` on the design's own model: the
    least margin and the largest peak over the speeds."""
    from .stability import loop_margins
    ctl = point_of(phi).controller(cfg.base_design())
    vals = [loop_margins(ctl, cfg.nominal, kmh / 3.6) for kmh in mc.speeds_kmh]
    return np.array([min(v[0] for v in vals), -max(v[1] for v in vals)])


MARGIN_PARAMETERS = ("k_beta", "k_gamma")
"""The tuned parameters the loop's margins depend on (the controller's; the noise intensities act on the
estimator only)."""


def margin_floors(start: np.ndarray) -> np.ndarray:
    """The lower bounds of :func:`margin_values`' rows for a tuning that starts from a point with the
    values ``start``: the constraint's bounds, or the start's own values where it misses them (a start
    that breaks a bound would make the problem infeasible from its first point)."""
    from .stability import DISK_MARGIN_MIN, SENSITIVITY_PEAK_MAX
    return np.minimum(np.array([DISK_MARGIN_MIN, -SENSITIVITY_PEAK_MAX]), np.asarray(start, float)) - 1e-9


def _sigma_subset(cfg: SweepConfig, cases: list[Case], phi: np.ndarray) -> list[float]:
    p = point_of(phi)
    return [decay_rate(cfg, c, p) for c in cases]


def tune(cfg: SweepConfig, cases: list[Case], start: DesignPoint | None = None, *, max_iter: int = 30,
         stability_cases: list[Case] | None = None, caps: list[float] | None = None, bounds: float = BOUNDS,
         displacement: list[DisplacementRun] | None = None, starts: int = 1, verbose: bool = False,
         workers: int | None = None, progress: bool = False, margins: MarginConstraint | None = None
         ) -> TuningResult:
    """IPOPT on the epigraph problem above; returns the tuned design point and the figures.

    ``progress``: a progress bar on stderr, one step per cost-and-gradient evaluation (IPOPT
    evaluates about once per iteration, more when its line search backtracks), showing the
    worst tuning case's cost of the last point.

    ``caps``: per tuning case an upper bound on its cost (``inf``: none). The design job
    caps the cases where the paper design is stable at ``REGRESS_FACTOR`` times their
    paper cost plus ``REGRESS_OFFSET``, so that pushing the worst (spinning) cases down
    cannot buy a loss of stability elsewhere: a worst-case objective alone is blind to
    every case below the worst.

    ``bounds``: each parameter stays within a factor ``e^bounds`` of ``start`` (log space, default
    :data:`BOUNDS`).

    ``starts``: IPOPT runs, the first from ``start``, the others from fixed points drawn (seeded,
    :data:`STARTS_SEED`) uniformly within half the bounds around it; the result is the best point of
    them all. The worst case has local optima (spins) far apart in quality, and which one a run
    ends in moves with rounding: several starts make the result's quality depend less on one path.

    ``displacement``: FMVSS 126 runs (:class:`DisplacementRun`) whose lateral displacement stays at or
    above their bound plus :data:`DISPLACEMENT_MARGIN` (constraints, with their gradients by the
    same forward-mode rollouts); the tuned point meets every bound itself.

    ``margins``: the loop's disk margin and sensitivity peak on the design's own model held to
    :func:`margin_floors` (at least :data:`toolkit.design.stability.DISK_MARGIN_MIN` and at most
    :data:`toolkit.design.stability.SENSITIVITY_PEAK_MAX`), with forward-difference gradients in K_beta and
    K_gamma.

    ``start`` defaults to :attr:`SweepConfig.paper`.
    """
    if not (isinstance(starts, int) and starts >= 1):
        raise SettingsError(f"tuning starts must be a whole number >= 1, got {starts!r}")
    if not (np.isfinite(bounds) and bounds > 0):
        raise SettingsError(f"tuning bounds must be a finite number > 0 (log space), got {bounds!r}")
    start = cfg.paper if start is None else start
    rc = RolloutCost(cfg)
    data = []
    for c in cases:
        prog, runs = sweep.case_inputs(cfg, c)
        data.append((runs, np.array([c.gyro_bias, c.gyro_scale_error, cfg.base_design().mu_max])))  # not told mu
    stab = list(stability_cases if stability_cases is not None else cases)
    m = len(data)
    cache: dict = {}
    counter = {"n": 0}
    history: list = []
    disp = list(displacement or [])
    _WORKER.update(rc=rc, data=data, displacement=disp)
    workers = workers or os.cpu_count() or 1
    pool = None
    if workers > 1 and "fork" in mp.get_all_start_methods():
        # the cases' rollouts (and the stability rates) in parallel; forked workers inherit
        # the compiled cost and the case data, so only phi travels
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"),
                                   initializer=sweep.single_threaded_blas)
    parts = [list(range(k, m, workers)) for k in range(workers)] if pool else [list(range(m))]
    n_d = len(disp)
    d_parts = [list(range(k, n_d, workers)) for k in range(workers)] if pool else [list(range(n_d))]

    # a count without an end: IPOPT's line searches evaluate an iteration more than once, and every start runs
    # up to max_iter iterations
    bar = sweep.progress_bar(None, progress, f"tuning ({starts} IPOPT starts of up to {max_iter} iterations)", "eval")

    def evaluate(phi):
        key = tuple(np.round(phi, 15))
        if key not in cache:
            J, dJ = np.empty(m), np.empty((m, len(phi)))
            D, dD = np.empty(n_d), np.empty((n_d, len(phi)))
            if pool is not None:
                futures = [pool.submit(_eval_subset, phi, idx) for idx in parts if idx]
                d_futures = [pool.submit(_displacement_subset, phi, idx) for idx in d_parts if idx]
                results = [r for f in futures for r in f.result()]
                d_results = [r for f in d_futures for r in f.result()]
            else:
                results = _eval_subset(phi, list(range(m)))
                d_results = _displacement_subset(phi, list(range(n_d))) if n_d else []
            for i, c, gr in results:
                J[i], dJ[i] = c, gr
            for i, c, gr in d_results:
                D[i], dD[i] = c, gr
            J = np.where(np.isfinite(J), J, 1e12)
            dJ = np.where(np.isfinite(dJ), dJ, 0.0)
            D = np.where(np.isfinite(D), D, -1e3)  # a run that diverged has no displacement to speak of
            dD = np.where(np.isfinite(dD), dD, 0.0)
            cache.clear()
            cache[key] = (J, dJ, D, dD)
            history.append((np.array(phi), J.copy(), D.copy()))
            counter["n"] += 1
            bar.set_postfix_str(f"worst cost {float(np.max(J)):.4g}", refresh=False)
            bar.update(1)
        return cache[key]

    n_phi = len(DesignPoint.TUNED)
    sig_cache: dict = {}

    def sigma_values(phi):
        key = tuple(np.round(phi, 15))
        if key not in sig_cache:
            sig_cache[key] = np.array(_sigma_subset(cfg, stab, phi))
        return sig_cache[key]

    def sigma_jacobian(phi):
        """Forward differences (step 1e-4 in log space), the perturbed points spread over the pool."""
        h = 1e-4
        base = sigma_values(phi)
        pts = [phi + h * np.eye(n_phi)[k] for k in range(n_phi)]
        if pool is not None:
            cols = [f.result() for f in [pool.submit(_sigma_subset, cfg, stab, q) for q in pts]]
        else:
            cols = [_sigma_subset(cfg, stab, q) for q in pts]
        return np.column_stack([(np.array(c) - base) / h for c in cols])

    # log J: the costs span 0.05 (a held nominal case) to 4e4 (a spin); on the log scale the
    # epigraph's rows and the caps are comparable for IPOPT (the max is unchanged: log is monotone)
    costs = _Function("costs", n_phi, m, lambda phi: np.log(evaluate(phi)[0]),
                      lambda phi: (lambda J, dJ, *_: dJ / J[:, None])(*evaluate(phi)))
    bound = np.array([r.bound for r in disp])
    sigmas = _Function("sigmas", n_phi, len(stab), sigma_values, sigma_jacobian)
    phi0 = phi_of(start)
    x = ca.MX.sym("x", len(phi0) + 1)
    phi, t = x[:-1], x[-1]
    caps_arr = np.full(m, np.inf) if caps is None else np.asarray(caps, float)
    Jv = costs(phi)
    g = ca.vertcat(Jv - t, sigmas(phi), Jv)
    if n_d:  # (the callback objects must outlive the solver: named)
        displacements = _Function("displacements", n_phi, n_d, lambda phi: evaluate(phi)[2],
                                  lambda phi: evaluate(phi)[3])
        g = ca.vertcat(g, displacements(phi))
    margin_cache: dict = {}

    def margin_of(ph):
        key = tuple(np.round(ph, 15))
        if key not in margin_cache:
            margin_cache[key] = margin_values(cfg, ph, margins)
        return margin_cache[key]

    def margin_jacobian(ph):
        h, base = 1e-4, margin_of(ph)
        jac = np.zeros((2, n_phi))
        for name in MARGIN_PARAMETERS:
            k = DesignPoint.TUNED.index(name)
            jac[:, k] = (margin_of(ph + h * np.eye(n_phi)[k]) - base) / h
        return jac
    if margins is not None:
        margin_fn = _Function("margins", n_phi, 2, margin_of, margin_jacobian)
        g = ca.vertcat(g, margin_fn(phi))
    solver = ca.nlpsol("tune", "ipopt", {"x": x, "f": t, "g": g},
                       {"ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": max_iter,
                        "ipopt.print_level": 5 if verbose else 0, "ipopt.sb": "no" if verbose else "yes",
                        "print_time": False,
                        "ipopt.tol": 1e-4, "ipopt.acceptable_tol": 1e-3, "ipopt.mu_strategy": "adaptive"})
    J0, _, D0, _ = evaluate(phi0)
    # the stability margin where the start has it; elsewhere no less than the start's decay rate (its
    # slow modes, the heading and the gyro bias, hardly move with these parameters: a margin the start
    # misses would make the problem infeasible from its first point)
    sigma_floor = np.minimum(SIGMA_MIN, sigma_values(phi0))
    m_floor = margin_floors(margin_of(phi0)) if margins is not None else np.zeros(0)

    def feasible(J, D, ph):
        return bool(np.all(J <= caps_arr * (1 + 1e-9)) and np.all(D >= bound)
                    and np.all(sigma_values(ph) >= sigma_floor)
                    and (margins is None or np.all(margin_of(ph) >= m_floor)))
    x0 = np.concatenate([phi0, [float(np.log(np.max(J0))) + 1e-3]])
    lbx = np.concatenate([phi0 - bounds, [-np.inf]])
    ubx = np.concatenate([phi0 + bounds, [np.inf]])
    lbg = np.concatenate([np.full(m, -np.inf), sigma_floor, np.full(m, -np.inf),
                          bound + DISPLACEMENT_MARGIN, m_floor])
    ubg = np.concatenate([np.zeros(m), np.full(len(stab), np.inf), np.log(caps_arr), np.full(n_d, np.inf),
                          np.full(len(m_floor), np.inf)])
    # the other starts: fixed points of the box (seeded), the same for every run of the same problem
    rng = np.random.default_rng(STARTS_SEED)
    others = [phi0 + rng.uniform(-0.5 * bounds, 0.5 * bounds, n_phi) for _ in range(starts - 1)]
    iterations, status = 0, []
    try:
        for x_start in [x0] + [np.concatenate([q, [float(np.log(np.max(evaluate(q)[0]))) + 1e-3]]) for q in others]:
            sol = solver(x0=x_start, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            stats = solver.stats()
            iterations += int(stats.get("iter_count", -1))
            status.append(str(stats.get("return_status", "?")))
            evaluate(np.array(sol["x"]).ravel()[:-1])
    finally:
        if pool is not None:
            pool.shutdown()
        pool = None
        bar.close()
    _WORKER.clear()
    # IPOPT's iterates need not be feasible nor monotone, and it may stop on its iteration
    # limit: the result is the best point the runs evaluated that meets every cap, the stability
    # margin and every displacement bound (the start meets the caps built from it), never worse
    # than the start, which it is when no point is better
    tuned, J1, D1 = start, J0, D0
    for ph, J, D in sorted(history, key=lambda h: float(np.max(h[1]))):
        if np.max(J) >= np.max(J0):
            break
        if feasible(J, D, ph):
            tuned, J1, D1 = point_of(ph), J, D
            break
    sig = [decay_rate(cfg, c, tuned) for c in stab]
    return TuningResult(tuned, start, [c.case_id for c in cases], float(np.max(J0)), float(np.max(J1)),
                        [float(v) for v in J0], [float(v) for v in J1], sig, [float(v) for v in D1],
                        iterations, "; ".join(status), counter["n"])
