"""Closed-loop sweep throughput: N model-error cases x 10 s at 1 kHz, compiled, on the process pool.

Every case drives the standard manoeuvre set (two 5 s manoeuvres = 10 s at 1 kHz)
through the whole loop (two-track plant -> sensors -> dakf -> 2-DOF controller ->
actuators), compiled once (run-time parameters: no recompilation per case) and
spread over a process pool (the ``local`` executor of ``evstab design``). Only the
rollouts and their metrics are timed (the linear stability verdicts are a separate
cost of the sweep, printed too). The reference is the same sweep case by case in a
plain Python loop: the simulator's numpy evaluation of the same loop step, one sample
at a time, on ``--ref-cases`` cases, scaled per case; the first cases' metrics are
checked to agree.

Run: ``python benchmarks/bench_sweep.py [--cases 1000] [--workers 2] [--ref-cases 2] [--plant two-track]``
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from evstab.plants import TRUTH, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.toolkit.design import sweep as sw
from evstab.toolkit.loop.closed_loop import EXTRA
from evstab.toolkit.loop.loop_program import program
from evstab.toolkit.loop.simulator import simulate


def random_cases(n: int, seed: int = 11) -> list[sw.Case]:
    rng = np.random.default_rng(seed)
    return [sw.Case(i, cf_scale=rng.uniform(0.6, 1.4), cr_scale=rng.uniform(0.6, 1.4), mu=rng.uniform(0.3, 1.0),
                    mass_scale=rng.uniform(0.8, 1.2), inertia_scale=rng.uniform(0.8, 1.2),
                    speed_kmh=float(rng.choice([40.0, 60.0, 80.0, 100.0, 120.0])),
                    gps_rate=float(rng.choice([1.0, 2.0, 5.0, 10.0, 20.0])),
                    gps_latency=float(rng.choice([0.0, 0.05, 0.1, 0.15])), gyro_bias=rng.uniform(-0.005, 0.005),
                    gyro_scale_error=rng.uniform(-0.02, 0.02), group="bench") for i in range(n)]


def python_loop_case(cfg: sw.SweepConfig, case: sw.Case) -> float:
    """The reference: the case's cost from the simulator's numpy evaluation of the loop step."""
    costs = []
    for man in sw.standard_maneuvers(cfg, case.speed_kmh / 3.6):
        r = simulate(case.plant_params(cfg.nominal), cfg.plant, man,
                     disturbances=Disturbances(friction=Friction(mu=case.mu)), sensors=case.sensors(cfg.sensors),
                     seed=case.seed, controller="two-dof", design=sw.PAPER.controller(cfg.base_design()),
                     estimator=cfg.filter_design(sw.PAPER), nominal=cfg.nominal, compile=False)
        Y = np.column_stack([r.truth[k] for k in TRUTH])
        E = np.column_stack([r.commands[k] for k in EXTRA])
        costs.append(sw.cost_value(sw.cost_terms(Y, E), cfg.base_design().nz_max))
    return float(np.mean(costs))


def kernel_shares(cfg: sw.SweepConfig, cases: list[sw.Case]) -> dict | None:
    """One block of cases (four vectors of the lane width, the first manoeuvre) in this process: the
    loop's lane kernel, the plant's part of it alone (:mod:`_plant`, retracing the block's
    runs), for the two-track the same plant with its tyres' Magic Formula evaluated instead of read from
    the table, and the yardstick, timed in alternating passes; ns per case and step (the yardstick: per
    step), and the largest difference of the plant kernel's truth from the loop's. None without a C
    compiler."""
    import _plant
    from _yardstick import yardstick_pass
    from evstab.toolkit.loop.closed_loop import samples
    from evstab.toolkit.kernels.lanes import native_width
    prog = program(cfg.spec())
    kernel, one_yardstick = _plant.plant_kernel(prog.spec), yardstick_pass()
    if prog.lanes is None or kernel is None or one_yardstick is None:
        return None
    block = cases[:4 * native_width()]
    setup = [sw.case_setup(cfg, c) for c in block]
    n = samples(prog.spec, setup[0][3][0])
    U = np.empty((len(block), n, prog.nin))
    z0_rows: list = []
    pv_rows: list = []
    for q, (true, sens, dist, mans) in enumerate(setup):
        _, z, p = prog.inputs(true, mans[0], dist, sens, block[q].seed, out=U[q])
        z0_rows.append(z)
        pv_rows.append(p)
    z0, pv = np.array(z0_rows), np.array(pv_rows)
    theta = sw.case_thetas(cfg, prog, sw.PAPER, block)
    Y, E = prog.run_batch(U, z0, pv, theta)
    x0, u, diff = _plant.retrace(prog.spec, kernel, U, z0, pv, E, Y)
    runs = {"loop": lambda: prog.lanes(z0, [U, pv, theta], n, keep=(1, 2)),
            "plant": lambda: kernel(x0, [u, pv], n), "yardstick": lambda: one_yardstick(200_000)}
    formula = _plant.plant_kernel(prog.spec, table=False) if cfg.plant == "two-track" else None
    if formula is not None:
        runs["formula"] = lambda: formula(x0, [u, pv], n)
    best = _plant.best_alternating(runs)
    per = len(block) * n
    return {"loop": best["loop"] / per * 1e9, "plant": best["plant"] / per * 1e9, "y": best["yardstick"],
            "formula": None if formula is None else best["formula"] / per * 1e9,
            "diff": diff, "cases": len(block), "seconds": n * cfg.dt}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--ref-cases", type=int, default=2)
    ap.add_argument("--plant", default="two-track", choices=["two-track", "bicycle-roll", "bicycle"])
    ap.add_argument("--md", help="also write the docs' table as Markdown to this file")
    args = ap.parse_args()
    cfg = sw.SweepConfig(load_vehicle("compact-ev"), plant=args.plant)
    cases = random_cases(args.cases)
    t0 = time.perf_counter()
    program(cfg.spec()).compile()
    print(f"compile (or load from cache): {time.perf_counter() - t0:.2f} s")
    # warm the pool's imports out of the timing: one tiny sweep first
    sw.run_sweep(cfg, cases[:args.workers], [sw.PAPER], workers=args.workers, progress=False, batch=1)
    t0 = time.perf_counter()
    rows = sw.run_sweep(cfg, cases, [sw.PAPER], workers=args.workers, progress=False, batch=25, linear=False)
    t_sweep = time.perf_counter() - t0
    steps = args.cases * 2 * int(round(sw.MANEUVER_DURATION / cfg.dt))
    print(f"compiled sweep ({args.plant}): {args.cases} cases x {2 * sw.MANEUVER_DURATION:g} s at 1 kHz on "
          f"{args.workers} worker(s): {t_sweep:.2f} s ({t_sweep / steps * 1e9:.0f} ns per loop step and case, "
          f"wall; target <= 2 s)")
    from _yardstick import yardstick_line
    print(yardstick_line(t_sweep / steps * 1e9, "sweep per loop step and case (wall, all workers)"))
    import resource
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest worker
    print(f"peak resident memory: {own:.0f} MiB in this process (the {len(rows)} summary rows), {child:.0f} MiB in "
          f"the largest worker (target < 2 GiB)")
    shares = kernel_shares(cfg, cases)
    worker = t_sweep * args.workers / steps * 1e9
    if shares is not None:
        k = shares
        print(f"where a worker's time goes (one process, one block of {k['cases']} cases x {k['seconds']:g} s, the "
              f"kernels and the yardstick ({k['y']:.0f} ns) in alternating passes): the loop's lane kernel "
              f"{k['loop']:.0f} ns per case and step = {k['loop'] / k['y']:.1f}x the yardstick; its {args.plant} plant "
              f"alone (RK4 and the output equation, retracing the block's truth to {k['diff']:.0e}) {k['plant']:.0f} ns"
              f" = {k['plant'] / k['y']:.1f}x, {100 * k['plant'] / k['loop']:.0f} % of the loop kernel; a sweep worker "
              f"{worker:.0f} ns in all (the rest: the runs' inputs and noise, the summaries); the target is "
              f"{2.1 * args.workers:.1f}x per worker")
        if k["formula"] is not None:
            print(f"the same plant with the tyres' Magic Formula evaluated instead of read from its table, in the same "
                  f"passes: {k['formula']:.0f} ns = {k['formula'] / k['y']:.1f}x; the table saves "
                  f"{100 * (1 - k['plant'] / k['formula']):.0f} % of the plant")
    t0 = time.perf_counter()
    sw.run_sweep(cfg, cases[:50], [sw.PAPER], workers=args.workers, progress=False, batch=5)
    t_lin = time.perf_counter() - t0
    print(f"linear multi-rate verdicts included, first 50 cases: {t_lin:.2f} s")
    t0 = time.perf_counter()
    ref = [python_loop_case(cfg, c) for c in cases[:args.ref_cases]]
    t_ref = (time.perf_counter() - t0) / args.ref_cases
    for c, v in zip(cases, ref):
        got = next(r["cost"] for r in rows if r["case_id"] == c.case_id)
        assert abs(got - v) <= 1e-6 * max(1.0, abs(v)), (c.case_id, got, v)
    print(f"plain Python loop (simulator, numpy loop step): {t_ref:.2f} s per case, measured on {args.ref_cases} case(s) "
          f"-> {t_ref * args.cases:.0f} s for {args.cases} cases")
    print(f"ratio: {t_ref * args.cases / t_sweep:.0f}x")
    if args.md:
        from pathlib import Path
        from _yardstick import yardstick_ns
        from evstab.studies._common import write_markdown
        y = yardstick_ns()
        per = t_sweep / steps * 1e9
        write_markdown(Path(args.md), [f"{args.cases} cases x {2 * sw.MANEUVER_DURATION:g} s at 1 kHz, {args.plant}, "
                                       f"{args.workers} workers", "wall", "per loop step and case"], [
            ["compiled sweep (rollouts only)", f"{t_sweep:.1f} s", f"{per:.0f} ns"
             + ("" if y is None else f" ({per / y:.1f}x the C Kalman yardstick, {y:.0f} ns)")],
            *([] if shares is None else [
                [f"one process, one block of {shares['cases']} cases: the loop's lane kernel alone", "",
                 f"{shares['loop']:.0f} ns ({shares['loop'] / shares['y']:.1f}x the yardstick timed beside it, "
                 f"{shares['y']:.0f} ns)"],
                [f"... its {args.plant} plant alone (RK4 and the output equation; the same truth to {shares['diff']:.0e})",
                 "", f"{shares['plant']:.0f} ns ({shares['plant'] / shares['y']:.1f}x; "
                     f"{100 * shares['plant'] / shares['loop']:.0f} % of the loop kernel)"],
                *([] if shares["formula"] is None else [
                    ["... the same plant with the tyres' Magic Formula evaluated, not read from its table", "",
                     f"{shares['formula']:.0f} ns ({shares['formula'] / shares['y']:.1f}x)"]]),
                ["a sweep worker in all (the kernel, the runs' inputs and noise, the summaries)", "",
                 f"{worker:.0f} ns (" + ("" if y is None else f"{worker / y:.1f}x the yardstick; ")
                 + f"target {2.1 * args.workers:.1f}x per worker)"]]),
            ["the first 50 cases with the linear multi-rate verdicts", f"{t_lin:.1f} s", ""],
            [f"plain Python loop (the simulator's numpy loop step; {args.ref_cases} cases measured, scaled)",
             f"{t_ref * args.cases:.0f} s", f"{t_ref / (2 * sw.MANEUVER_DURATION / cfg.dt) * 1e9 / 1e3:.0f} us "
             f"({t_ref * args.cases / t_sweep:.0f}x the compiled sweep)"],
            ["peak resident memory: this process / the largest worker", f"{own:.0f} / {child:.0f} MiB", ""]])


if __name__ == "__main__":
    main()
