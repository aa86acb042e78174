"""A random fault campaign: the ECU in the closed loop, one randomly drawn fault per run, on the two-track car
and on CommonRoad's multi-body cars with a wrong nominal model, each run judged against the same run with no
control at all.

Each run draws, from one seeded generator (:data:`SEED`): a car (compact-ev on the two-track plant; the
Escort and the BMW 320i, ``commonroad-mb:1``/``:2``, whose ECU is designed on the bundled nominal with every
cornering stiffness +40 %: :func:`studies.control_mb_fmvss126.wrong_nominal`), a manoeuvre (ISO 3888-1
lane change at 60-100 km/h on mu 0.5-1.0, or a sine with dwell at 80 km/h, 4-6.5 times the road-wheel
steer of 0.3 g in the ECU's linear model, on mu 0.5-1.0), a sensor-noise seed, and one fault (:class:`toolkit.loop.ecu_faults.EcuFault`): an input
among the eleven the guard checks, or an ECU reset; a kind among NaN, +Inf, a value anywhere in the
input's plausible span, an offset of up to twice :data:`toolkit.loop.ecu_faults.OFFSETS`, a scale of 0.5-1.5,
stuck; a start anywhere in the manoeuvre's first 4 s and a length of 1 ms to 2 s (log-uniform; a reset
boots 1-100 ms).

Judged: every steer and yaw-moment command finite (a multi-body car that rolls over ends its run: its peak
sideslip counts as infinite, no worse than a reference that rolled over too); the peak sideslip against the same car, manoeuvre and
noise seed with no control, by the envelope's no-harm rule (:func:`studies.firmware_faults.no_harm`: at
most 1.1 x the car alone's or 0.3 deg more); and by the same rule against the controlled run without the
fault (a fault that only adds nothing to what the law does without it).

Outputs: ``firmware_campaign.csv`` (every run), ``firmware_campaign_summary.md`` (per car: runs, commands
finite, no worse than no control, no worse than without the fault), ``firmware_campaign_worst.md`` (the runs
beyond the no-harm rule, worst first, at most :data:`WORST_ROWS`).

Run: ``python -m evstab.studies.firmware_campaign OUT_DIR [--quick] [--parallel]`` (quick: 4 runs on the
two-track car, for the test suite; parallel: two worker processes).
"""

from __future__ import annotations

import functools
import sys

import numpy as np

from evstab.plants.params import G

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import make_maneuver, steer_for_lateral_acceleration
from evstab.studies._common import out_dir, write_markdown, write_table
from evstab.studies.control_mb_fmvss126 import CAR_NAMES, wrong_nominal
from evstab.studies.firmware_faults import no_harm, peak_beta_deg
from evstab.toolkit.loop.ecu_faults import ECU, OFFSETS, EcuFault
from evstab.toolkit.loop.loop_ecu import loop_ecu
from evstab.toolkit.loop.simulator import RolloverError, simulate

SEED = 20261203
RUNS = {"two-track": 120, "commonroad-mb:1": 40, "commonroad-mb:2": 40}
QUICK_RUNS = {"two-track": 4}
WORST_ROWS = 15
KINDS = ("nan", "inf", "value", "offset", "scale", "stuck", "reset")
SPAN = {"speed": (0.0, 60.0), "steer": (-0.6, 0.6), "yaw_rate": (-2.0, 2.0), "ay": (-15.0, 15.0),
        "steer_cmd_driver": (-0.6, 0.6), "yaw_moment_applied": (-5e3, 5e3), "gps_course": (-np.pi, np.pi),
        "mu": (0.05, 1.2), "wheel_speed_rl": (0.0, 200.0), "wheel_speed_rr": (0.0, 200.0), "dt": (1e-4, 5e-3)}
"""A ``value`` fault's span per input: what the sensor could plausibly read (inside the guard's ranges)."""


def draw_fault(rng: np.random.Generator) -> EcuFault:
    """One random fault (see the module)."""
    kind = KINDS[rng.integers(len(KINDS))]
    start = float(np.round(rng.uniform(0.5, 4.0), 3))
    if kind == "reset":
        return EcuFault(ECU, "reset", start, start + float(np.round(10 ** rng.uniform(-3, -1), 3)) + 1e-3)
    signal = list(OFFSETS)[rng.integers(len(OFFSETS))]
    length = float(np.round(10 ** rng.uniform(-3, np.log10(2.0)), 3))
    value = 0.0
    if kind == "value":
        value = float(rng.uniform(*SPAN[signal]))
    elif kind == "offset":
        value = float(OFFSETS[signal] * rng.uniform(-2.0, 2.0))
    elif kind == "scale":
        value = float(rng.uniform(0.5, 1.5))
    return EcuFault(signal, kind, start, start + max(length, 1e-3), value)


def draw_case(rng: np.random.Generator) -> tuple:
    """A manoeuvre drawn at random (see the module): ``("iso", km/h, mu)`` or ``("swd", times A, mu)``."""
    mu = float(np.round(rng.uniform(0.5, 1.0), 2))
    if rng.random() < 0.5:
        return "iso", float(np.round(rng.uniform(60.0, 100.0))), mu
    return "swd", float(np.round(rng.uniform(4.0, 6.5), 1)), mu


def build_case(case: tuple, p):
    """(label, manoeuvre, mu) of a drawn case for the ECU's vehicle ``p``."""
    kind, x, mu = case
    if kind == "iso":
        return f"ISO 3888-1 {x:.0f} km/h mu {mu:g}", make_maneuver("iso3888-1", p, x / 3.6), mu
    amp = x * steer_for_lateral_acceleration(p, 80 / 3.6, 0.3 * G)
    return f"sine with dwell 80 km/h {x:g} A mu {mu:g}", make_maneuver("sine-with-dwell", p, 80 / 3.6, amp), mu


@functools.lru_cache(maxsize=None)
def _car(plant: str):
    """(the ECU's vehicle, its ECU) for ``plant``: one per process, so its compiled loops are found again."""
    p = load_vehicle("compact-ev") if plant == "two-track" else wrong_nominal(int(plant.split(":")[1]))
    return p, loop_ecu("two-dof", p).ecu


def run_one(job: tuple) -> dict:
    """One run of the campaign: ``(plant, index, case, fault, seed)`` -> its row."""
    plant, i, case, fault, seed = job
    p, ecu = _car(plant)
    label, man, mu = build_case(case, p)
    road = Disturbances(friction=Friction(mu=mu))
    alone, _ = _simulate(p, plant, man, road, seed)
    clean, _ = _simulate(p, plant, man, road, seed, controller="two-dof", design=ecu)
    r, rolled = _simulate(p, plant, man, road, seed, controller="two-dof", design=ecu, ecu_fault=fault)
    finite = r is None or bool(np.all(np.isfinite(r.commands["steer_cmd"]))
                               and np.all(np.isfinite(r.commands["yaw_moment_cmd"])))
    peak, peak_alone, peak_clean = _peak(r), _peak(alone), _peak(clean)
    return {"car": plant, "run": i, "case": label, "seed": seed, "fault": fault.label, "start_s": fault.start,
            "finite": finite, "rolled_over_s": rolled, "peak_beta_deg": peak, "alone_peak_beta_deg": peak_alone,
            "no_fault_peak_beta_deg": peak_clean, "no_harm": finite and _no_worse(peak, peak_alone),
            "as_without_fault": finite and _no_worse(peak, peak_clean)}


def _simulate(p, plant, man, road, seed, **kw):
    """(the run, None), or (None, when the car rolled over) for a multi-body car that did."""
    try:
        return simulate(p, plant, man, disturbances=road, seed=seed, **kw), None
    except RolloverError as e:
        return None, float(e.t)


def _peak(r) -> float:
    """The run's peak sideslip [deg]; a car that rolled over: infinite."""
    return np.inf if r is None else peak_beta_deg(r)


def _no_worse(peak: float, reference: float) -> bool:
    """The no-harm rule; a run that rolled over is no worse than a reference that rolled over too."""
    return bool(np.isinf(reference) or no_harm(peak, reference))


def main(out, quick: bool = False, workers: int = 1) -> list[dict]:
    out = out_dir(out)
    rng = np.random.default_rng(SEED)
    jobs = []
    for plant, n in (QUICK_RUNS if quick else RUNS).items():
        for i in range(n):
            jobs.append((plant, i, draw_case(rng), draw_fault(rng), int(rng.integers(1000))))
    if workers > 1:  # the runs are independent; each worker loads the compiled loops from the cache
        import multiprocessing as mp
        with mp.get_context("spawn").Pool(workers) as pool:
            rows = pool.map(run_one, jobs, chunksize=1)
    else:
        rows = [run_one(j) for j in jobs]
    for row in rows:
        print(row, flush=True)
    write_table(rows, out / "firmware_campaign.csv")
    cars = list(dict.fromkeys(r["car"] for r in rows))
    name = lambda car: "compact-ev (two-track)" if car == "two-track" else f"{car} ({CAR_NAMES[car]}, +40 % stiffness model)"  # noqa: E731
    write_markdown(out / "firmware_campaign_summary.md",
                   ["car", "runs", "commands finite", "no worse than no control", "no worse than without the fault"],
                   [[name(car), sum(r["car"] == car for r in rows),
                     sum(r["finite"] for r in rows if r["car"] == car),
                     sum(r["no_harm"] for r in rows if r["car"] == car),
                     sum(r["as_without_fault"] for r in rows if r["car"] == car)] for car in cars]
                   + [["all", len(rows), sum(r["finite"] for r in rows), sum(r["no_harm"] for r in rows),
                       sum(r["as_without_fault"] for r in rows)]])
    bad = sorted((r for r in rows if not r["no_harm"]),
                 key=lambda r: -(r["peak_beta_deg"] - r["alone_peak_beta_deg"]) if r["finite"] else -np.inf)
    write_markdown(out / "firmware_campaign_worst.md",
                   ["car", "manoeuvre", "noise seed", "fault (from)", "peak sideslip: fault / no fault / no control [deg]"],
                   [[name(r["car"]), r["case"], r["seed"], f"{r['fault']} ({r['start_s']:.3f} s)",
                     f"{r['peak_beta_deg']:.2f} / {r['no_fault_peak_beta_deg']:.2f} / {r['alone_peak_beta_deg']:.2f}"]
                    for r in bad[:WORST_ROWS]] or [["-", "no run beyond the rule", "-", "-", "-"]])
    return rows


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "out/studies", quick="--quick" in sys.argv,
         workers=2 if "--parallel" in sys.argv else 1)
