"""Limit manoeuvres: what a stability controller is for, and the design job's constraint.

The sweep (:mod:`toolkit.design.sweep`) judges a design on the standard manoeuvres across model
errors, most of them in the tyres' linear range. A stability controller is worth what it does
at the limit, so every design the design job considers is also driven, closed loop with the
ECU as exported and not told the road, through

* **FMVSS 126**: the sine-with-dwell series at 80 km/h (every amplitude, both directions,
  ``A`` from the slowly increasing steer on the same surface) on mu 1.0 and 0.6;
* **ISO 3888-1**: the severe lane change with the path-following driver at 80 and 100 km/h
  on mu 1.0, 0.8 and 0.5 (peak sideslip);
* **step steer into saturation**: 80 km/h, a hand-wheel step for 1.5 x the friction's lateral
  acceleration on the nominal linear car, on mu 1.0 and 0.5, held for :data:`STEP_HOLD` s and driven
  with the sensor noise of each of :data:`STEP_SEEDS` (the largest peak sideslip of the runs).

Each case is run without control too, and a design must do **no worse than no control** on
every one of them (:func:`no_worse`): on FMVSS 126 every criterion the uncontrolled car meets in
a run, the design meets in that run; in the sideslip cases the peak stays within
``max(1.5 x the uncontrolled peak, 3 deg)`` where the uncontrolled car keeps its sideslip
under :data:`SPIN_DEG`, and where it does not, the design holds the car: its peak stays below
:data:`HELD_DEG` (the envelope's rule, :data:`toolkit.verdicts.envelope.HELD_DEG`). That is a constraint: a design that
breaks it is not chosen, however small its cost (the design job's selection:
:func:`toolkit.design.selection.limit_constrained`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants import G, is_multibody
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import make_maneuver, step_steer, steer_for_lateral_acceleration
from ..verdicts.envelope import HELD_DEG, SLIDE_DEG

SPIN_DEG = SLIDE_DEG
"""Peak sideslip [deg] beyond which a limit run has lost the car (the envelope's slide)."""
SIDESLIP_FACTOR = 1.5
SIDESLIP_FLOOR_DEG = 3.0
"""Where the uncontrolled car holds its sideslip, a design's peak may be up to
``max(SIDESLIP_FACTOR x uncontrolled, SIDESLIP_FLOOR_DEG)`` (the stability-control issue's bound:
a controller may trade a little sideslip for path, never a slide)."""
STEP_SATURATION = 1.5
"""The step steer asks the nominal linear car for this multiple of ``mu g``."""
STEP_HOLD = 7.5
"""[s] How long the step steer is held (from 0.5 s). A filter whose noise lets a held slide pass for a
bias of the gyro (the yaw-rate disturbance's intensity ``q_d2`` six times the paper's) loses the
sideslip 3 to 7 s into the step on mu 0.5: measured on compact-ev with the quick tuning's candidate
K_beta 3.03, K_gamma 3.15, the peak over five noise seeds is 3.8 deg in a 4 s run; over ten seeds in an
8 s run it is 12.6 deg (past 5 deg in 4 of the 10), against 2.9 deg for the same gains on the paper
design's noise."""
STEP_SEEDS = (0, 1, 2)
"""The step's sensor-noise seeds: the slide of such a filter starts in some noise draws and not in
others (see :data:`STEP_HOLD`)."""


@dataclass(frozen=True)
class LimitCase:
    kind: str
    """``fmvss126``, ``iso3888-1`` or ``step``."""
    mu: float
    speed_kmh: float = 80.0
    plant: str | None = None
    """Plant to run on (None: the design's)."""

    @property
    def label(self) -> str:
        where = f" on {self.plant}" if self.plant else ""
        return f"{self.kind} {self.speed_kmh:.0f} km/h mu {self.mu:g}{where}"


def limit_cases(plant: str = "two-track") -> list[LimitCase]:
    """The limit set for a design on ``plant``; on a multi-body plant FMVSS 126 runs on the
    two-track of the nominal file as well (the model the design was made from)."""
    cases = [LimitCase("fmvss126", mu) for mu in (1.0, 0.6)]
    if is_multibody(plant):
        cases += [LimitCase("fmvss126", mu, plant="two-track") for mu in (1.0, 0.6)]
    cases += [LimitCase("iso3888-1", mu, kmh) for kmh in (80.0, 100.0) for mu in (1.0, 0.8, 0.5)]
    cases += [LimitCase("step", mu) for mu in (1.0, 0.5)]
    return cases


def _fmvss(p, plant, mu, controller, estimator, design, a_cache: dict) -> dict:
    from ..verdicts.fmvss126 import find_a, run_series
    key = (plant, mu)
    if key not in a_cache:
        a_cache[key] = find_a(p, plant, mu)
    _, rows, verdict = run_series(p, controller, estimator, mu=mu, plant=plant, a_deg=a_cache[key], design=design)
    return {"A_deg": a_cache[key], "runs": len(rows), "runs_passed": sum(r["pass"] for r in rows),
            "pass": verdict["pass"], "failed_criteria": " ".join(verdict["failed_criteria"]) or "-",
            "_runs": [(r["amplitude_deg"], r["direction"], frozenset(r["failed"].split())) for r in rows],
            "_displacement": [r["lateral_displacement_m"] for r in rows]}


def sideslip_result(peak: float) -> dict:
    """A sideslip case's result from its peak |sideslip| [deg] (inf: the car was lost): the peak, and
    whether the car spun (a peak of :data:`SPIN_DEG` or more)."""
    return {"peak_beta_deg": peak, "spun": not peak < SPIN_DEG}


def case_maneuver(p, case: LimitCase):
    """The manoeuvre of a sideslip case: ISO 3888-1 with the path-following driver, or the step steer
    asking the nominal linear car for :data:`STEP_SATURATION` x ``mu g`` (from 0.5 s, held :data:`STEP_HOLD` s)."""
    v = case.speed_kmh / 3.6
    if case.kind == "iso3888-1":
        return make_maneuver("iso3888-1", p, v)
    return step_steer(v, steer_for_lateral_acceleration(p, v, STEP_SATURATION * case.mu * G), start=0.5,
                      duration=0.5 + STEP_HOLD)


def _sideslip_run(p, plant, case: LimitCase, controller, estimator, design) -> dict:
    """The peak sideslip of a case: ISO 3888-1 on seed 0; the step on each of :data:`STEP_SEEDS`, the
    largest (without control the car reads no sensor: one run)."""
    from ..loop.simulator import SimulationError, simulate
    man = case_maneuver(p, case)
    seeds = STEP_SEEDS if case.kind == "step" and controller is not None else (0,)
    peak = 0.0
    for seed in seeds:
        try:
            r = simulate(p, plant, man, disturbances=Disturbances(friction=Friction(mu=case.mu)), seed=seed,
                         controller=controller, estimator=estimator, design=design)
            beta = np.abs(r.truth["beta"])
            peak = max(peak, float(np.degrees(np.max(beta))) if np.all(np.isfinite(beta)) else float("inf"))
        except SimulationError:  # rolled over or diverged: the car is lost
            peak = float("inf")
        if not np.isfinite(peak):
            break
    return sideslip_result(peak)


def run_case(cfg, case: LimitCase, point=None, a_cache: dict | None = None, name: str | None = None) -> dict:
    """One limit case for one design, closed loop on the compiled plant, the ECU not told the road.

    ``point``: a :class:`toolkit.design.sweep.DesignPoint` (its gains and noise on ``cfg``'s design), an
    :class:`toolkit.ecu.step.EcuDesign` (a design folder's ECU as exported) or a
    :class:`controllers.two_dof.TwoDofDesign` (with the ``dakf`` filter); None: no control."""
    from evstab.controllers.two_dof import TwoDofDesign
    from ..ecu.step import EcuDesign
    plant = case.plant or cfg.plant
    p = cfg.nominal
    controller: str | None
    if isinstance(point, EcuDesign):
        controller, estimator, design = "two-dof", point.filter.method, point
    elif isinstance(point, TwoDofDesign):
        controller, estimator, design = "two-dof", "dakf", point
    elif point is None:
        controller, estimator, design = ("none" if case.kind == "fmvss126" else None), "dakf", None
    else:
        controller, estimator, design = "two-dof", cfg.filter_design(point), point.controller(cfg.base_design())
    row = {"case": case.label, "kind": case.kind, "plant": plant, "mu": case.mu, "speed_kmh": case.speed_kmh,
           "design": name or ("no control" if point is None else point.name)}
    if case.kind == "fmvss126":
        row.update(_fmvss(p, plant, case.mu, controller, estimator, design, {} if a_cache is None else a_cache))
    else:
        row.update(_sideslip_run(p, plant, case, controller, estimator, design))
    return row


def run_limits(cfg, point=None, cases: list[LimitCase] | None = None, a_cache: dict | None = None,
               name: str | None = None, progress: bool = False, label: str | None = None) -> list[dict]:
    """:func:`run_case` for every case (default :func:`limit_cases` of ``cfg.plant``); ``progress``: a bar on
    stderr, named ``label`` (default the design's name)."""
    from .sweep import progress_bar
    a_cache = {} if a_cache is None else a_cache
    cases = cases or limit_cases(cfg.plant)
    label = label or name or ("no control" if point is None else getattr(point, "name", "the design"))
    rows = []
    with progress_bar(len(cases), progress, f"limit manoeuvres, {label}", "case") as bar:
        for c in cases:
            rows.append(run_case(cfg, c, point, a_cache, name))
            bar.update(1)
    return rows


def no_worse(row: dict, none: dict) -> tuple[bool, str]:
    """Whether a design's result on a limit case is no worse than no control's, and why not."""
    if row["kind"] == "fmvss126":
        lost: dict = {}
        for (amp, _, f), (_, _, g) in zip(row["_runs"], none["_runs"]):
            for c in f - g:
                lost.setdefault(c, []).append(amp)
        why = "; ".join(f"{c} failed in {len(a)} of {row['runs']} runs ({min(a):.0f}-{max(a):.0f} deg hand-wheel) "
                        f"where no control meets it" for c, a in sorted(lost.items()))
        return not lost, why
    if none["spun"]:
        ok = row["peak_beta_deg"] < HELD_DEG
        return ok, "" if ok else f"peak sideslip {row['peak_beta_deg']:.1f} deg, not below {HELD_DEG:g} deg, where " \
                                 f"no control spins ({none['peak_beta_deg']:.1f} deg)"
    bound = max(SIDESLIP_FACTOR * none["peak_beta_deg"], SIDESLIP_FLOOR_DEG)
    ok = row["peak_beta_deg"] <= bound
    return ok, "" if ok else f"peak sideslip {row['peak_beta_deg']:.2f} deg > {bound:.2f} deg " \
                             f"(no control {none['peak_beta_deg']:.2f} deg)"


def judge(rows: list[dict], none_rows: list[dict]) -> dict:
    """Summary of a design's limit results against no control's (same case order); no control's own rows
    are no worse than themselves (where the car alone spins, :func:`no_worse` asks a design to hold it)."""
    worse, passed, total = [], 0, 0
    for r, n in zip(rows, none_rows):
        ok, why = (True, "") if r is n else no_worse(r, n)
        r["no_worse_than_none"], r["_worse_why"] = ok, why
        if not ok:
            worse.append(f"{r['case']}: {why}")
        if r["kind"] == "fmvss126":
            passed += r["runs_passed"]
            total += r["runs"]
        else:
            passed += int(not r["spun"])
            total += 1
    return {"admissible": not worse, "worse_than_none": worse, "limit_runs_passed": passed, "limit_runs": total,
            "fmvss126_pass": all(r["pass"] for r in rows if r["kind"] == "fmvss126")}


def newly_worse(rows: list[dict], paper_rows: list[dict]) -> list[str]:
    """The limit cases where a design is worse than no control and the paper design is not, each as
    ``case: why`` (the rows judged by :func:`judge` first; same case order). A candidate may be worse than no
    control only where the paper design is too: a case the paper design fails does not excuse another."""
    return [f"{r['case']}: {r['_worse_why']}" for r, q in zip(rows, paper_rows)
            if q["no_worse_than_none"] and not r["no_worse_than_none"]]


DISPLACEMENT_TAIL = 1.0
"""[s] A displacement run of the tuning is rolled out this long past BOS + 1.07 s (not to the series'
end: half the work), enough for the scorer's 6 Hz zero-phase filter to have let go of what follows."""


DISPLACEMENT_HELD = 4
"""Runs per FMVSS 126 series and steer direction the design job's tuning holds to the lateral
displacement from the start: those with the least margin under the paper design
(:func:`tightest`); a run the candidate then misses joins them (a cutting-plane round)."""


def run_label(row: dict, amp: float, direction: str) -> str:
    """The name of one run of an FMVSS 126 limit row (the tuning's :class:`toolkit.design.tuning.DisplacementRun`)."""
    return f"{row['case']}, {amp:.0f} deg {direction}"


def tightest(runs: list, rows: list[dict], k: int = DISPLACEMENT_HELD) -> list:
    """Of ``runs`` (:func:`displacement_runs`), per series and steer direction the ``k`` whose lateral
    displacement in ``rows`` (a design's :func:`run_limits`, e.g. the paper design's) is the smallest."""
    value = {run_label(r, amp, d): x for r in rows if r["kind"] == "fmvss126"
             for (amp, d, _), x in zip(r["_runs"], r["_displacement"])}
    groups: dict = {}
    for run in runs:
        series, rest = run.label.rsplit(", ", 1)
        groups.setdefault((series, rest.split()[-1]), []).append(run)
    keep = {id(r) for g in groups.values() for r in sorted(g, key=lambda r: value[r.label])[:k]}
    return [r for r in runs if id(r) in keep]


def missed_displacement(rows: list[dict], none_rows: list[dict]) -> list[str]:
    """Labels of the FMVSS 126 runs where a design (``rows``) fails the lateral displacement and no
    control (``none_rows``, same order) meets it."""
    out = []
    for r, n in zip(rows, none_rows):
        if r["kind"] != "fmvss126":
            continue
        for (amp, d, f), (_, _, g) in zip(r["_runs"], n["_runs"]):
            if "lateral_displacement" in f and "lateral_displacement" not in g:
                out.append(run_label(r, amp, d))
    return out


def displacement_runs(cfg, none_rows: list[dict], a_cache: dict | None = None, also: list[dict] | None = None) -> list:
    """The FMVSS 126 runs on ``cfg``'s plant whose lateral displacement criterion the uncontrolled
    car meets (``none_rows``: :func:`run_limits` of no control; and ``also``, another design's rows
    in the same order, meets too), as the tuning's constraints
    (:class:`toolkit.design.tuning.DisplacementRun`): each run's inputs in the stability loop exactly as
    :func:`toolkit.verdicts.fmvss126.run_series` builds them for the paper design, and the linear map from the
    lateral acceleration to the displacement at BOS + 1.07 s. Runs on another plant (the two-track
    of a multi-body design's nominal file) are left to the check."""
    from ..loop import closed_loop as cl
    from ..verdicts.fmvss126 import (DISPLACEMENT_FROM_A, LATERAL_DISPLACEMENT_MIN, T_DISPLACEMENT, _timing,
                                     displacement_map, find_a, series_maneuver)
    from ..loop.simulator import _loop, _setup
    from .tuning import DisplacementRun
    from evstab.plants.errors import DesignError
    a_cache = {} if a_cache is None else a_cache
    p = cfg.nominal
    out = []
    for n_row, row in enumerate(none_rows):
        if row["kind"] != "fmvss126" or row["plant"] != cfg.plant:
            continue
        other = also[n_row]["_runs"] if also is not None else [(None, None, frozenset())] * len(row["_runs"])
        key = (cfg.plant, row["mu"])
        if key not in a_cache:
            a_cache[key] = find_a(p, cfg.plant, row["mu"])
        a_deg = a_cache[key]
        dist = Disturbances(friction=Friction(mu=row["mu"]))
        model, params, nominal, dist, sensors = _setup(cfg.plant, p, None, dist, None, cfg.dt)
        spec, _, theta = _loop(model, params, nominal, sensors, cfg.dt, "two-dof", cfg.filter_design(cfg.paper),
                               cfg.paper.controller(cfg.base_design()), None, False)
        if cl.traced(spec) != cl.traced(cfg.spec()):
            raise DesignError(f"{row['case']}: the FMVSS 126 loop differs in structure from the tuning's (plant "
                              f"{cfg.plant}); its lateral displacement cannot be a constraint of the tuning")
        for (amp, direction, failed), (_, _, failed_also) in zip(row["_runs"], other):
            if amp < DISPLACEMENT_FROM_A * a_deg - 1e-9 or (failed | failed_also) & {"lateral_displacement", "rollover"}:
                continue
            sign = 1.0 if direction == "left" else -1.0
            man = series_maneuver(p, sign * amp)
            U, z0, pv = cl.loop_inputs(spec, params, man, dist, sensors, 0)
            t = np.arange(U.shape[0]) * cfg.dt
            hw = man.steer(t) * p.steering_ratio
            # the rollout up to DISPLACEMENT_TAIL after the displacement's instant: what comes later
            # reaches it only through the zero-phase filter's backward pass, which has decayed by then
            n = min(U.shape[0], int(np.ceil((_timing(t, hw)[-1] + T_DISPLACEMENT + DISPLACEMENT_TAIL) / cfg.dt)))
            out.append(DisplacementRun(run_label(row, amp, direction), (U[:n].copy(), z0, pv),
                                       theta[-cl.CASE.size:].copy(), displacement_map(t[:n], hw[:n]),
                                       LATERAL_DISPLACEMENT_MIN))
    return out


def public(rows: list[dict]) -> list[dict]:
    """The rows without the per-run detail (for CSV)."""
    return [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
