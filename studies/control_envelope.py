"""The envelope (:mod:`toolkit.verdicts.envelope`): every manoeuvre, five noise seeds, three cars, the car
alone and the default ECU, judged by the envelope's rules.

Cars: compact-ev on the two-track (the ECU's model exact), and CommonRoad's multi-body Escort
(``commonroad-mb:1``) and Vanagon (``commonroad-mb:3``), whose ECU believes the bundled nominal
file with both cornering stiffnesses +40 % (a wrong model; :func:`studies.control_mb_fmvss126.wrong_nominal`).
The ECU is evstab's default (seed 003's gains, the supervision, ``dakf``; :class:`controllers.two_dof.TwoDofDesign`
of the nominal), in the loop with real rear-wheel torques, not told the road. The car alone has no
noise in its loop (the driver reads the truth), so it runs once per case; the controlled car runs
once per seed (0-4), and a case is judged on its median and its worst seed.

Writes ``envelope.csv`` (one row per car, case and seed), ``envelope_table.md`` (per car and case:
the car alone, the controlled car's median and worst seed, the rules broken) and
``envelope_summary.md`` (per car and subset: cases, cases with a rule broken).

Run: ``python -m evstab.studies.control_envelope OUT_DIR [--quick]`` (about 5 minutes on one core;
quick, for the test suite: compact-ev, the six cases of :data:`QUICK`, two seeds).
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.studies.control_mb_fmvss126 import wrong_nominal
from evstab.toolkit.verdicts import envelope as ev

SEEDS = (0, 1, 2, 3, 4)
CARS = ("two-track", "commonroad-mb:1", "commonroad-mb:3")
QUICK = ("step 80 km/h mu 1", "step 100 km/h mu 0.3", "slalom 40 km/h mu 1", "lift-off 80 km/h mu 1",
         "crosswind 100 km/h mu 1", "random-steer 80 km/h mu 1")
"""The quick run's cases (compact-ev): a design case, a validation case where the car alone slides,
a human driver in normal driving, lift-off, the gust and random steering."""


def nominal(plant: str):
    """What the ECU believes on ``plant``."""
    return load_vehicle("compact-ev") if plant == "two-track" else wrong_nominal(int(plant.rsplit(":", 1)[1]))


def car_name(plant: str) -> str:
    return {"two-track": "two-track (compact-ev)", "commonroad-mb:1": "commonroad-mb:1 (Escort, +40 %)",
            "commonroad-mb:3": "commonroad-mb:3 (Vanagon, +40 %)"}[plant]


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    seeds = SEEDS[:2] if quick else SEEDS
    rows, table, summary = [], [], []
    for plant in CARS[:1] if quick else CARS:
        p = nominal(plant)
        cases = ev.cases(plant)
        if quick:
            cases = [c for c in cases if c.label in QUICK]
        broken_cases = {s: 0 for s in ev.SUBSETS}
        n_cases = {s: 0 for s in ev.SUBSETS}
        for case in cases:
            alone = ev.run(case, p, plant, controller=None)
            runs = [(seed, ev.run(case, p, plant, seed=seed)) for seed in seeds]
            for seed, met in runs:
                broken = ev.judge(met, alone, case.mu_min, case.disturbance)
                rows.append({"car": plant, "case": case.label, "subset": case.subset, "seed": seed,
                             "alone_beta_deg": alone.peak_beta_deg, "alone_cones": alone.cones_hit,
                             "alone_ay": alone.peak_ay, "alone_deviation_m": alone.deviation_m,
                             "beta_deg": met.peak_beta_deg, "cones": met.cones_hit, "ay": met.peak_ay,
                             "added_steer_deg": met.added_steer_deg, "yaw_moment_Nm": met.peak_yaw_moment,
                             "deviation_m": met.deviation_m, "rules_broken": "; ".join(broken) or "-"})
            table.append(_row(plant, case, alone, runs))
            n_cases[case.subset] += 1
            broken_cases[case.subset] += table[-1][-1] != "-"
        for s in ev.SUBSETS:
            if n_cases[s]:
                summary.append([car_name(plant), s, n_cases[s], broken_cases[s]])
    write_table(rows, out / "envelope.csv")
    write_markdown(out / "envelope_table.md", [
        "car", "case", "subset", "car alone: peak sideslip [deg] / cones", "controlled, median seed", "worst seed",
        "worst added steer [deg] / yaw moment [N m]", "rules broken (seeds)"], table)
    write_markdown(out / "envelope_summary.md", ["car", "subset", "cases", "cases with a rule broken"], summary)
    return rows


def _beta(x: float) -> str:
    return "lost" if not np.isfinite(x) else f"{x:.2f}"


def _row(plant: str, case, alone, runs) -> list:
    """One line of the docs' table: the car alone, the controlled car's median and worst seed (by cones
    hit, then peak sideslip; the crosswind by deviation), and the rules broken, each as its worst seed
    broke it, with the number of seeds that broke it."""
    mets = [m for _, m in runs]
    # worst: the most cones, then the largest sideslip (the crosswind: the largest deviation)
    key = (lambda m: m.deviation_m) if case.kind == "crosswind" else (lambda m: (m.cones_hit, m.peak_beta_deg))
    order = sorted(mets, key=key)
    median, worst = order[len(order) // 2], order[-1]

    def cell(m):
        text = f"{_beta(m.peak_beta_deg)} / {m.cones_hit}"
        return text + (f", {m.deviation_m:.2f} m" if np.isfinite(m.deviation_m) else "")

    counts: dict = {}
    for m in reversed(order):  # worst first: each rule's message is its worst seed's
        for b in ev.judge(m, alone, case.mu_min, case.disturbance):
            rule = b.split(":", 1)[0]
            counts.setdefault(rule, [0, b])[0] += 1
    broken = "; ".join(f"{b} ({k}/{len(mets)})" for k, b in counts.values()) or "-"
    return [car_name(plant), case.label, case.subset, cell(alone), cell(median), cell(worst),
            f"{max(m.added_steer_deg for m in mets):.2f} / {max(m.peak_yaw_moment for m in mets):.0f}", broken]


if __name__ == "__main__":
    cli(main)
