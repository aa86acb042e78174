"""``evstab design``: design, analyse, sweep, tune, report — the main job.

Steps (each writes data; the report only draws what was written, so ``evstab
report DIR`` can redraw it without recomputing):

1. the paper design (seed 003: K_beta = K_gamma = 5 rad/s, the ``dakf`` filter with
   its hand-tuned noise) on the vehicle's nominal parameters;
2. the model-error sweep of the paper design (:mod:`toolkit.design.sweep`);
3. the tuning (:mod:`toolkit.design.tuning`) on the paper design's worst cases plus the
   nominal case; in the full run one cutting-plane round adds the tuned design's
   worst case when it lies outside the tuning set and tunes again;
4. the sweep of the tuned design; the comparison (worst case, stability);
5. the limit manoeuvres (:mod:`toolkit.design.limits`: FMVSS 126 on mu 1.0 and 0.6, ISO 3888-1,
   step steer into saturation) for no control, the paper design and the tuning's candidate; when
   a candidate is worse than no control anywhere, the tuning runs again in smaller boxes around
   the paper design (a constraint, not a cost term), and an unchanged design says so;
6. the speed-grid analysis of both designs (observability, estimator poles, loop
   poles in s and z, margins) and the pole maps' data;
7. time responses of the standard manoeuvres (no control, paper, tuned);
8. ``design.json`` (the tuned design, self-describing), ``sweep.csv`` and
   ``sweep.parquet``, ``limits.csv``, the tables, ``report.md`` and ``report.html``.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from evstab.controllers.schedule import SpeedSchedule
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import VehicleParams, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.errors import DesignError

from . import sweep as sw
from .selection import (BETTER_MARGIN, CUT_ROUNDS, TRUST_RADII, TUNING_STARTS, design_margins, limit_constrained,
                        tune_rounds)
from .analysis import SPEEDS_KMH, speed_grid
from ..estimation.spec import FilterDesign, NoiseSettings
from ..logs.drivelog import atomic_write, write_rows_csv
from .stability import DISK_MARGIN_MIN, SENSITIVITY_PEAK_MAX, estimator_loop, nominal_loop

from .record import FORMAT, READS, design_points


def evstab_version() -> str:
    try:
        from importlib.metadata import version
        return version("evstab")
    except Exception:  # running from a source tree that is not installed
        return "unknown"


def git_revision() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent, capture_output=True,
                             text=True, timeout=5)
        rev = out.stdout.strip()
        if out.returncode != 0 or not rev:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=Path(__file__).resolve().parent, capture_output=True, text=True, timeout=5)
        return rev + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


# ------------------------------------------------------------------ design.json
def _controller_dict(d: TwoDofDesign) -> dict:
    out = {f.name: getattr(d, f.name) for f in dataclasses.fields(d) if f.name not in ("params", "schedule")}
    out["yaw_moment_max"] = d.nz_max
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in out.items()}


def _estimator_dict(f: FilterDesign) -> dict:
    return {"method": f.method, "states": list(f.states), "latency_s": f.latency, "antenna_x_m": f.antenna_x,
            "dt_s": f.dt_nominal, "kinematic": bool(f.kinematic),
            "noise": {k.name: float(getattr(f.noise, k.name)) for k in dataclasses.fields(f.noise)}}


def design_document(cfg: sw.SweepConfig, tuned: sw.DesignPoint, paper: sw.DesignPoint, summary: dict,
                    tuning: dict, command: str) -> dict:
    gps = {"rate_hz": cfg.sensors.gps_rate, "latency_s": cfg.sensors.gps_latency, "hdop": cfg.sensors.gps_hdop,
           "satellites": cfg.sensors.gps_sats}
    doc = basic_design_document(cfg.nominal, cfg.filter_design(tuned), tuned.controller(cfg.base_design()), gps,
                                command)
    doc["plant_model"] = cfg.plant
    doc["paper_design"] = {k: float(getattr(paper, k)) for k in sw.DesignPoint.TUNED}
    doc["tuning"] = tuning
    doc["sweep"] = summary
    doc["provenance"] = doc.pop("provenance")  # last, as before
    return doc


def basic_design_document(params: VehicleParams, filt: FilterDesign, ctl: TwoDofDesign, gps: dict,
                          command: str | None) -> dict:
    """What :func:`load_design` needs (vehicle, estimator, controller, schedule, GPS set-up), for a design
    made outside ``evstab design`` (e.g. gains chosen by hand) that is to be exported."""
    return {
        "format": FORMAT,
        "description": "evstab stability-control design: DAKF estimator (gyro 1 kHz + GPS course) and 2-DOF "
                       "model-following controller (front steer + rear in-wheel-motor yaw moment).",
        "units": "SI; angles in rad, rates in rad/s, yaw moment in N m; ISO 8855 signs (x forward, y left, z up)",
        "vehicle": {"name": params.name, "params_digest": params.digest(),
                    "nominal_params": params.as_nominal().to_dict()},
        "control_period_s": filt.dt_nominal,
        "gps": dict(gps),
        "estimator": _estimator_dict(filt),
        "schedule": SpeedSchedule.build(params.as_nominal()).to_dict(),
        "controller": _controller_dict(ctl),
        "provenance": {"evstab_version": evstab_version(), "git_revision": git_revision(), "command": command,
                       "created_unix": time.time(), "python": sys.version.split()[0]},
    }


DEFAULT_GPS = {"rate_hz": 5.0, "latency_s": 0.0, "hdop": 0.9, "satellites": 10}
"""The GPS set-up of :func:`default_design_document`."""


def default_design_document(command: str | None, vehicle: str = "compact-ev") -> dict:
    """The bundled car's ECU as it stands without a design job: ``dakf`` with the ECU's noise and the 2-DOF law
    on the nominal model, as :func:`basic_design_document` writes it (what the firmware tools export by
    default)."""
    from evstab.plants import load_vehicle

    from ..estimation import design_filter
    p = load_vehicle(vehicle)
    return basic_design_document(p, design_filter("dakf", p, control=True), TwoDofDesign(p.as_nominal()),
                                 DEFAULT_GPS, command)


@dataclasses.dataclass(frozen=True)
class LoadedDesign:
    """A design read back from ``design.json``: ready-made filter and controller designs."""

    document: dict
    params: VehicleParams
    filter: FilterDesign
    controller: TwoDofDesign

    @property
    def point(self) -> sw.DesignPoint:
        return sw.DesignPoint("tuned", **design_points(self.document)["tuned"])



def load_design(path) -> LoadedDesign:
    """Read a design folder back.

    Parameters
    ----------
    path : str or pathlib.Path
        An ``evstab design`` folder or its ``design.json``.

    Returns
    -------
    LoadedDesign
        The document, the nominal vehicle, the filter design and the controller design.

    Raises
    ------
    DesignError
        The file is missing, not JSON, of another format, or lacks a field; the message names
        the file and the field.
    """
    from ..estimation import design_filter
    from evstab.plants.params import VehicleParams as VP
    path = Path(path)
    f = path / "design.json" if path.is_dir() else path
    if not f.is_file():
        raise DesignError(f"{f}: no such file; expected an 'evstab design' folder or its design.json")
    try:
        doc = json.loads(f.read_text())
    except OSError as e:
        raise DesignError(f"{f}: cannot read it ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise DesignError(f"{f}: not JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    if doc.get("format") not in READS:
        raise DesignError(f"{f}: field 'format' is {doc.get('format')!r}, expected {FORMAT!r}")
    try:
        params = VP(**doc["vehicle"]["nominal_params"])
        est = doc["estimator"]
        noise = NoiseSettings(**est["noise"])
        fd = design_filter(est["method"], params, noise, latency=est["latency_s"], antenna_x=est["antenna_x_m"],
                           dt=est["dt_s"], control=True, kinematic=bool(est.get("kinematic", False)))
        c = dict(doc["controller"])
        c.setdefault("reference_model", "static")  # a design from before the linear reference was designed with that
        ctl = TwoDofDesign(params, **{k: v for k, v in c.items() if k != "yaw_moment_max"},
                           yaw_moment_max=c["yaw_moment_max"])
    except KeyError as e:
        raise DesignError(f"{f}: missing field {e}") from None
    except (TypeError, ValueError) as e:
        raise DesignError(f"{f}: {e}") from None
    return LoadedDesign(doc, params, fd, ctl)


# ------------------------------------------------------------------ analysis data
def analysis_rows(cfg: sw.SweepConfig, points: list[sw.DesignPoint], speeds=SPEEDS_KMH,
                  tick=None) -> tuple[list, list]:
    """Speed-grid table (one row per design and speed) and pole-map data (one row per pole); ``tick`` (optional)
    is called after each design's grid and each design and speed's poles."""
    tick = tick or (lambda: None)
    rows, poles = [], []
    p = cfg.nominal
    for pt in points:
        est, ctl = cfg.filter_design(pt), pt.controller(cfg.base_design())
        for r in speed_grid(p, est, ctl, speeds_kmh=speeds, gps_rate=cfg.sensors.gps_rate, dt=cfg.dt):
            rows.append({"design": pt.name, **r})
        tick()
        for kmh in speeds:
            v = kmh / 3.6
            _, st = nominal_loop(ctl, v, p)
            for z in st.poles:
                poles.append({"design": pt.name, "speed_kmh": kmh, "plane": "s", "what": "loop (controller + plant)",
                              "re": float(z.real), "im": float(z.imag)})
            try:
                _, mr = estimator_loop(ctl, est, v, true_params=p, gps_rate=cfg.sensors.gps_rate, dt=cfg.dt)
                for z in mr.poles:
                    poles.append({"design": pt.name, "speed_kmh": kmh, "plane": "z",
                                  "what": "multi-rate loop with estimator (per GPS period)",
                                  "re": float(z.real), "im": float(z.imag)})
            except np.linalg.LinAlgError:
                pass
            tick()
    return rows, poles


LIMIT_RESPONSE_MU = 0.5
"""Friction of the response set's limit run: the limit set's step steer (:func:`toolkit.design.limits.case_maneuver`,
asking the nominal linear car for ``STEP_SATURATION`` x ``mu g``), where the car alone slides and the
controller acts."""


def response_maneuvers(cfg: sw.SweepConfig, mu: float, speed: float) -> list:
    """The manoeuvres of the time responses on ``mu``: on :data:`LIMIT_RESPONSE_MU` the limit set's step steer
    at ``speed``, as long as the standard manoeuvres; on any other friction the standard set."""
    if mu != LIMIT_RESPONSE_MU:
        return sw.standard_maneuvers(cfg, speed)
    from . import limits as lm
    step = lm.case_maneuver(cfg.nominal, lm.LimitCase("step", mu, speed * 3.6))
    return [dataclasses.replace(step, name="step-steer at the limit", duration=sw.MANEUVER_DURATION)]


RESPONSE_MUS = (1.0, 0.45, LIMIT_RESPONSE_MU)
"""The frictions of the time responses (:func:`response_rows`)."""


def response_rows(cfg: sw.SweepConfig, points: list[sw.DesignPoint], decimate: int = 10, tick=None) -> list[dict]:
    """Time responses at 80 km/h: the standard manoeuvres on mu 1 and mu 0.45, and on
    :data:`LIMIT_RESPONSE_MU` the limit set's step steer, where the controller acts; no control and each
    design (``tick``, optional: called after each friction's runs)."""
    tick = tick or (lambda: None)
    from ..loop.loop_program import program
    from ..loop.simulator import simulate
    rows = []
    prog = program(cfg.spec())
    for mu in RESPONSE_MUS:
        case = sw.Case(-1, mu=mu, group="response")
        true = case.plant_params(cfg.nominal)
        sens = case.sensors(cfg.sensors)
        for man in response_maneuvers(cfg, mu, case.speed_kmh / 3.6):
            r = simulate(true, cfg.plant, man, disturbances=Disturbances(friction=Friction(mu=mu)), seed=case.seed)
            nan = np.full(len(r.t), np.nan)
            runs = {"no control": (r.t, r.truth["yaw_rate"], r.truth["beta"], nan, nan, r.commands["steer"],
                                   np.zeros(len(r.t)))}
            U, z0, pv = prog.inputs(true, man, Disturbances(friction=Friction(mu=mu)), sens, case.seed)
            for pt in points:
                th = prog.theta(**pt.calibration(), mu_assumed=cfg.base_design().mu_max)  # not told the road
                Y, E = prog.run(U, z0, pv, th)
                from evstab.plants import TRUTH
                from ..loop.closed_loop import EXTRA
                t = np.arange(len(U)) * cfg.dt
                y, e = TRUTH.columns(Y), EXTRA.columns(E)
                runs[pt.name] = (t, y["yaw_rate"], y["beta"], e["yaw_rate_ref"], e["beta_ref"], e["steer"],
                                 e["yaw_moment"])
            for label, (t, yr, b, ref, bref, st, nz) in runs.items():
                for k in range(0, len(t), decimate):
                    rows.append({"mu": mu, "maneuver": man.name, "controller": label, "t": float(t[k]),
                                 "yaw_rate": float(yr[k]), "beta": float(b[k]), "yaw_rate_ref": float(ref[k]),
                                 "beta_ref": float(bref[k]), "steer": float(st[k]), "yaw_moment": float(nz[k])})
        tick()
    return rows


# ------------------------------------------------------------------ comparison


def compare(rows: list[dict]) -> dict:
    """Worst case and stability of each design over the sweep, and the case-by-case relation
    ("better": lower by at least :data:`BETTER_MARGIN` of the other's cost)."""
    by: dict = {}
    for r in rows:
        by.setdefault(r["design"], {})[r["case_id"]] = r
    out: dict = {"cases": len(next(iter(by.values())))}
    for name, rs in by.items():
        worst = max(rs.values(), key=lambda r: r["cost"])
        out[name] = {"worst_cost": worst["cost"], "worst_case_id": worst["case_id"],
                     "stable_cases": sum(r["stable"] for r in rs.values()),
                     "median_cost": float(np.median([r["cost"] for r in rs.values()]))}
    if "paper" in by and "tuned" in by:
        ids = sorted(by["paper"])
        out["tuned_stable_where_paper_stable"] = all(by["tuned"][i]["stable"] for i in ids if by["paper"][i]["stable"])
        out["paper_stable_tuned_unstable"] = [i for i in ids if by["paper"][i]["stable"] and not by["tuned"][i]["stable"]]
        out["tuned_better_cases"] = sum(by["tuned"][i]["cost"] < (1.0 - BETTER_MARGIN) * by["paper"][i]["cost"]
                                        for i in ids)
        out["better_margin"] = BETTER_MARGIN
        out["tuned_strictly_better_worst_case"] = (out["tuned"]["worst_cost"]
                                                   < (1.0 - BETTER_MARGIN) * out["paper"]["worst_cost"])
    return out


# ------------------------------------------------------------------ the job
def _limit_summary(limit_rows: list[dict]) -> dict:
    """Per design: FMVSS 126 pass per surface, limit runs held, whether no worse than no control."""
    from . import limits as lm
    by: dict = {}
    for r in limit_rows:
        by.setdefault(r["design"], []).append(r)
    none = by["no control"]
    out = {}
    for name, rs in by.items():
        j = lm.judge(rs, none)
        out[name] = {"fmvss126": {f"{r['plant']} mu {r['mu']:g}": f"{r['runs_passed']}/{r['runs']}" for r in rs
                                  if r["kind"] == "fmvss126"},
                     "fmvss126_pass": j["fmvss126_pass"], "limit_runs_held": j["limit_runs_passed"],
                     "limit_runs": j["limit_runs"], "no_worse_than_no_control": j["admissible"],
                     "worse_than_no_control": j["worse_than_none"]}
    return out


def run_design(vehicle: str, out, *, quick: bool = False, executor: str = "local", scheduler: str | None = None,
               workers: int | None = None, command: str | None = None, progress: bool = True, log=print,
               plant: str = "two-track", noise: NoiseSettings | None = None, kinematic: bool = True) -> dict:
    """``evstab design``: the whole job, written into ``out`` (see the module notes).

    Parameters
    ----------
    vehicle : str
        Bundled vehicle name or TOML path: what the design believes (the nominal model).
    out : str or pathlib.Path
        Design folder to write (created when the outputs are written; a job that fails leaves
        none).
    quick : bool
        22 model-error cases and 12 IPOPT iterations instead of 170 and 25.
    executor : str
        ``local`` (process pool) or ``dask``.
    scheduler : str, optional
        Dask scheduler address (``tcp://host:8786``); None with ``dask``: a local cluster.
    workers : int, optional
        Worker processes (default the CPU count).
    command : str, optional
        The command line recorded in ``design.json``.
    progress : bool
        Progress bars on stderr.
    log : callable
        Receives the phase lines (default :func:`print`).
    plant : str
        The plant the sweep, the tuning and the limit manoeuvres run on (``two-track``,
        ``bicycle``, ``bicycle-roll``, ``commonroad-mb:N``).
    noise : NoiseSettings, optional
        The filter's noise settings (``evstab design --noise FILE``, a file ``evstab estimate
        --tune`` wrote); the paper design starts from its process-noise intensities.
    kinematic : bool
        The ECU's filter with the kinematic sideslip path (default; ``evstab design --no-kinematic-path``:
        without).

    Returns
    -------
    dict
        The ``design.json`` document.
    """
    from .report import write_report
    from ..verdicts.fmvss126 import LATERAL_DISPLACEMENT_MIN as DISPLACEMENT_MIN
    from .tuning import BOUNDS, DISPLACEMENT_MARGIN, SIGMA_MIN
    t_start = time.perf_counter()
    clock = {"last": t_start}

    def phase(text: str) -> None:
        """Log a finished phase with its own duration and the time since the start."""
        now = time.perf_counter()
        log(f"  {text}: {now - clock['last']:.1f} s (total {now - t_start:.1f} s)")
        clock["last"] = now
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise DesignError(f"{out}: exists and is not a folder; --out names the design folder to write")
    params = load_vehicle(vehicle)
    cfg = sw.SweepConfig(params, plant=plant, noise=noise, kinematic=kinematic)
    cases = sw.sweep_cases(quick=quick, plant=plant)
    paper = cfg.paper
    log(f"evstab design: {params.name} on {plant}, {len(cases)} model-error cases, {'quick' if quick else 'full'} run")
    rows_paper = sw.run_sweep(cfg, cases, [paper], executor=executor, scheduler=scheduler, workers=workers,
                              progress=progress)
    phase("sweep of the paper design")
    from . import limits as lm
    a_cache: dict = {}
    none_lim = lm.run_limits(cfg, None, a_cache=a_cache, progress=progress)
    paper_lim = lm.run_limits(cfg, cfg.paper, a_cache=a_cache, progress=progress)
    # FMVSS 126's lateral displacement, where no control and the paper design meet it, is a constraint of
    # the tuning itself (the criterion a stiff yaw-rate pole breaks first): the runs with the least margin
    # from the start, any other the candidate misses after it
    eligible = lm.displacement_runs(cfg, none_lim, a_cache, also=paper_lim)
    displacement = lm.tightest(eligible, paper_lim)
    phase(f"limit manoeuvres of no control and the paper design ({len(displacement)} of {len(eligible)} FMVSS 126 "
          f"runs held to the lateral displacement in the tuning)")
    tuned, rows_tuned, rounds, ids = tune_rounds(cfg, cases, rows_paper, quick, executor, scheduler, workers,
                                                  progress, log, displacement=displacement)
    phase("tuning and sweep of the tuned design")

    def retune(radius, missed):
        """The tuning again in the box of half-width ``radius`` around the paper design, on the tuning
        set as the earlier rounds left it, with the displacement runs named in ``missed`` held too;
        None when none of them is a run it can hold that it does not hold already."""
        nonlocal ids, displacement
        new = [r for r in eligible if r.label in set(missed) and r not in displacement]
        if missed and not new:
            return None
        displacement = displacement + new
        point, rows, more, ids = tune_rounds(cfg, cases, rows_paper, quick, executor, scheduler, workers,
                                              progress, log, ids=ids, bounds=radius, displacement=displacement)
        for r in more:
            r["displacement_runs_held"] = len(displacement)
        rounds.extend(more)
        return point, rows
    tuned, rows_tuned, limit_rows, selection = limit_constrained(cfg, cases, rows_paper, tuned, rows_tuned, retune,
                                                                  (none_lim, paper_lim, a_cache), log, progress)
    phase("limit manoeuvres and selection")
    rows = sorted(rows_paper + rows_tuned, key=lambda r: (r["case_id"], r["design"] != "paper"))
    summary = compare(rows)
    summary["tuned_is_paper"] = all(getattr(tuned, k) == getattr(paper, k) for k in sw.DesignPoint.TUNED)
    summary["limits"] = _limit_summary(limit_rows)
    points = [paper, tuned]
    bar = sw.progress_bar(len(points) * (2 + len(SPEEDS_KMH)) + len(RESPONSE_MUS), progress,
                       "margins, analysis and responses", "step")

    def margins_of(pt):
        m = {k: m.as_dict() for k, m in design_margins(cfg, pt, cases).items()}
        bar.update(1)
        return m
    summary["margins"] = {pt.name: margins_of(pt) for pt in points}
    summary["margin_constraint"] = {"disk_margin_min": DISK_MARGIN_MIN, "sensitivity_peak_max": SENSITIVITY_PEAK_MAX,
                                    "speeds_kmh": list(SPEEDS_KMH)}
    grid, poles = analysis_rows(cfg, points, tick=lambda: bar.update(1))
    responses = response_rows(cfg, points, tick=lambda: bar.update(1))
    bar.close()
    phase("analysis and responses")
    tuning = {"method": "IPOPT (limited-memory Hessian) on the epigraph of the worst case; gradients by casadi "
                        "AD (forward mode) through compiled rollouts of the loop; stability constraint: decay rate "
                        "of the multi-rate loop with the estimator >= min(sigma_min, the paper design's) on every "
                        f"tuning case; FMVSS 126 lateral displacement >= {DISPLACEMENT_MIN} m + "
                        f"{DISPLACEMENT_MARGIN} m in the held runs (of those at 5 A and above that no control and "
                        f"the paper design meet it in, the {lm.DISPLACEMENT_HELD} per surface and steer direction "
                        "with the least margin under the paper design, and any a candidate missed); loop margins "
                        f"(the margin constraint): disk margin >= {DISK_MARGIN_MIN:g} and sensitivity peak <= "
                        f"{SENSITIVITY_PEAK_MAX:g} on the design's own model at every speed of the analysis grid; "
                        f"{TUNING_STARTS} IPOPT starts, the best feasible point of all",
              "fmvss126_displacement_runs": [r.label for r in displacement],
              "decision_variables": "log of " + ", ".join(sw.DesignPoint.TUNED), "sigma_min_1_s": SIGMA_MIN,
              "bounds_factor": float(np.exp(BOUNDS)), "rounds": rounds, "limit_selection": selection,
              "limit_constraint": "no worse than no control on every limit manoeuvre (FMVSS 126 criteria run by "
                                  "run; peak sideslip within max(1.5 x no control, 3 deg), under "
                                  f"{lm.HELD_DEG:g} deg where no control spins, the step steer held {lm.STEP_HOLD:g} s "
                                  f"on {len(lm.STEP_SEEDS)} noise seeds), as many limit runs held as the paper design, "
                                  f"no sweep case lost, worst cost {BETTER_MARGIN:.0%} below the paper design's, the "
                                  "margin constraint met; else the "
                                  "tuning again with the FMVSS 126 runs the candidate missed held (the same box, "
                                  f"up to {CUT_ROUNDS} times), then with each parameter within a factor "
                                  + ", ".join(f"{np.exp(r):.3g}" for r in TRUST_RADII)
                                  + " of the paper design's, the first candidate accepted; else the paper design "
                                  "unchanged",
              "cost": "mean over the standard manoeuvres of ms(r - r_ref)/(1 deg/s)^2 + ms(beta - beta_ref)/"
                      "(0.5 deg)^2 + ms(beta_hat - beta)/(0.5 deg)^2 + 0.1 ms(N_z)/N_z,max^2"}
    cmd = command or "evstab design --vehicle " + shlex.quote(vehicle) + (" --quick" if quick else "")
    doc = design_document(cfg, tuned, paper, summary, tuning, cmd)
    out.mkdir(parents=True, exist_ok=True)  # only now: a job that fails leaves no folder behind
    _write_json(out / "design.json", doc)
    write_rows_csv(out / "sweep.csv", rows)
    _write_parquet(out / "sweep.parquet", rows)
    write_rows_csv(out / "analysis.csv", grid)
    write_rows_csv(out / "poles.csv", poles)
    write_rows_csv(out / "responses.csv", responses)
    from .limits import public
    write_rows_csv(out / "limits.csv", public(limit_rows))
    write_report(out)
    phase("outputs and report")
    return doc


def _write_json(path: Path, doc: dict) -> None:
    atomic_write(path, lambda fh: fh.write(json.dumps(doc, indent=2, sort_keys=False, allow_nan=True) + "\n"))


def _write_parquet(path: Path, rows: list[dict]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq
    table = pa.Table.from_pylist(rows)
    atomic_write(path, lambda fh: pq.write_table(table, fh), mode="wb")
