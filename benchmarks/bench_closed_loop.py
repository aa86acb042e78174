"""Closed stability loop speed: the compiled loop vs python-control, same loop, same process.

The loop: two-track plant -> sensors -> the ECU step (dakf, 2-DOF law) -> actuators ->
plant, micro EV, 25 km/h, 5 deg step steer, wind, 1 kHz. evstab runs it as one call of the
lane kernel of :func:`toolkit.loop.closed_loop.loop_step` (:mod:`toolkit.kernels.lanes`; the time includes
making the run's inputs and noise). The reference gives python-control
the same step: a discrete ``nlsys`` whose update is the numpy evaluation of that
function (the loop is closed inside it; python-control integrates and bookkeeps), run by
``control.input_output_response``. python-control is slow, so it runs the first
``--ref-seconds`` and is compared per step.

Run: ``python benchmarks/bench_closed_loop.py [--ref-seconds 0.5]``
"""

from __future__ import annotations

import argparse
import time

import control
import numpy as np

from evstab.plants import TRUTH, get_plant, load_vehicle
from evstab.plants.backend import NUMPY
from evstab.plants.disturbances import Disturbances, default_wind
from evstab.plants.maneuvers import step_steer
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.loop import closed_loop as cl, loop_program


def python_control_loop(spec, p, U, z0, theta, seconds, dt=1e-3):
    """The loop step as a python-control discrete system, driven by the same inputs."""
    model = get_plant(spec.plant)
    nz, nt = len(z0), len(TRUTH)

    def update(t, z, u, params):
        return np.asarray(cl.loop_step(spec, model, p, z, u, theta, NUMPY)[0], float).ravel()

    def output(t, z, u, params):  # the truth at the sample (the step's second output)
        return np.asarray(cl.loop_step(spec, model, p, z, u, theta, NUMPY)[1], float).ravel()

    sys = control.nlsys(update, output, dt=dt, name="loop", inputs=U.shape[1], outputs=nt, states=nz)
    n = int(round(seconds / dt))
    t = np.arange(n) * dt
    t0 = time.perf_counter()
    resp = control.input_output_response(sys, t, U[:n].T, z0)
    return time.perf_counter() - t0, resp


def plant_alone(spec, prog, U, z0, pv, Y, E, one_yardstick) -> dict | None:
    """The run's plant part alone (:mod:`_plant`: the plant's lane kernel fed what the loop applied, ``E``),
    the same with the Magic Formula evaluated instead of the tyre table, the loop and the yardstick
    timed in 15 alternating passes: the best seconds per step of the plants and the loop, the
    yardstick's ns per step, and the largest difference of each plant's truth from the loop's. None
    without a C compiler or a lane kernel."""
    import _plant
    # at the width the loop's one-case run has (the narrow kernel), so that the two compare
    kernel, formula = _plant.plant_kernel(spec, cases=1), _plant.plant_kernel(spec, table=False, cases=1)
    if kernel is None or formula is None or prog.lanes is None or one_yardstick is None:
        return None
    x0, u, diff = _plant.retrace(spec, kernel, U[None], z0[None], pv[None], E[None], Y[None])
    *_, diff_f = _plant.retrace(spec, formula, U[None], z0[None], pv[None], E[None], Y[None])
    n = len(Y)
    best = _plant.best_alternating({"loop": lambda: prog.run(U, z0, pv, prog.theta()),
                                    "plant": lambda: kernel(x0, [u, pv[None]], n),
                                    "formula": lambda: formula(x0, [u, pv[None]], n),
                                    "yardstick": lambda: one_yardstick(200_000)}, rounds=15)
    return {"loop": best["loop"] / n, "plant": best["plant"] / n, "formula": best["formula"] / n,
            "y": best["yardstick"], "diff": diff, "diff_formula": diff_f}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref-seconds", type=float, default=0.5)
    ap.add_argument("--md", help="also write the docs' table as Markdown to this file")
    args = ap.parse_args(argv)
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.2, duration=10.0)
    dist = Disturbances(wind=default_wind(p))
    sens = SensorConfig()
    spec = cl.loop_spec(p, sensors=sens)
    prog = loop_program.program(spec).compile()  # build and compile once
    # the runs alternate with runs of the yardstick's C (200,000 steps, about 20 ms), 20 ms apart, the best
    # of each: both figures come from the same spells of this shared machine's speed
    from _yardstick import yardstick_pass
    one_yardstick = yardstick_pass()
    best, y_best = np.inf, np.inf
    for _ in range(15):
        t0 = time.perf_counter()
        U, z0, pv = prog.inputs(p, man, dist, sens, 0)
        Y, E = prog.run(U, z0, pv, prog.theta())
        best = min(best, time.perf_counter() - t0)
        if one_yardstick is not None:
            y_best = min(y_best, one_yardstick(200_000))
        time.sleep(0.02)
    y = None if one_yardstick is None else y_best
    n = len(Y)
    plant = plant_alone(spec, prog, U, z0, pv, Y, E, one_yardstick)
    t_ref, resp = python_control_loop(spec, p, U, z0, prog.theta(), args.ref_seconds)
    m = resp.outputs.shape[1]
    diff = np.abs(resp.outputs[TRUTH.index("yaw_rate")] - Y[:m, TRUTH.index("yaw_rate")]).max()
    per_c, per_ref = best / n, t_ref / m
    print(f"closed loop, 10 s at 1 kHz: evstab compiled {best * 1e3:.1f} ms per run ({per_c * 1e6:.2f} us/step); "
          f"python-control nlsys + input_output_response {per_ref * 1e6:.0f} us/step over {args.ref_seconds:g} s "
          f"-> ratio {per_ref / per_c:.0f}x (target 250x, <= 5 ms per run); yaw-rate difference {diff:.1e} rad/s")
    # python-control's own linear interconnection of the same loop: the loop step's Jacobian at
    # straight running (toolkit.design.stability.loop_linearisation, a fix every sample: one matrix per
    # sample), as a discrete-time ss, its initial-condition response over the same 10 s
    from evstab.controllers.two_dof import TwoDofDesign
    from evstab.toolkit.estimation import design_filter
    from evstab.toolkit.design.stability import loop_linearisation
    lin = loop_linearisation(TwoDofDesign(p.as_nominal()), design_filter("dakf", p, control=True), 25 / 3.6, true_params=p)
    A = lin.monodromy
    k = A.shape[0]
    lsys = control.ss(A, np.zeros((k, 1)), np.eye(k), np.zeros((k, 1)), dt=1e-3)
    tl = np.arange(n) * 1e-3
    x0 = np.full(k, 1e-3)
    t0 = time.perf_counter()
    control.initial_response(lsys, tl, x0)
    per_lin = (time.perf_counter() - t0) / n
    print(f"python-control linear ss of the same loop (its {k}-state feedback core at 25 km/h, linearised by "
          f"evstab), initial_response over 10 s: {per_lin * 1e6:.2f} us/step (evstab compiled nonlinear / linear "
          f"= {per_c / per_lin:.2f})")
    from _yardstick import yardstick_line
    print(yardstick_line(per_c * 1e9, "closed loop per step", y) + " (timed in alternating runs)")
    if plant is not None:
        print(f"its two-track plant alone (RK4 and the output equation, retracing the run's truth to "
              f"{plant['diff']:.0e}), timed alternately with the loop and the yardstick: {plant['plant'] * 1e6:.2f} "
              f"us per step = {plant['plant'] * 1e9 / plant['y']:.1f}x the yardstick ({plant['y']:.0f} ns), the loop "
              f"{plant['loop'] * 1e6:.2f} us = {plant['loop'] * 1e9 / plant['y']:.1f}x (target for the whole loop "
              f"5.3x); the plant is {100 * plant['plant'] / plant['loop']:.0f} % of the loop step")
        print(f"the same plant with the tyres' Magic Formula evaluated instead of read from its table (the run's "
              f"truth to {plant['diff_formula']:.0e}), in the same passes: {plant['formula'] * 1e6:.2f} us per step = "
              f"{plant['formula'] * 1e9 / plant['y']:.1f}x the yardstick; the table saves "
              f"{100 * (1 - plant['plant'] / plant['formula']):.0f} % of the plant")
    if args.md:
        from pathlib import Path
        from evstab.studies._common import write_markdown
        write_markdown(Path(args.md), ["10 s closed loop at 1 kHz (micro-ev, two-track, dakf + 2-DOF)", "per run",
                                       "per step", "ratio"], [
            ["evstab compiled (`loop_step` traced, lane kernel in C: toolkit.kernels.lanes)", f"{best * 1e3:.1f} ms", f"{per_c * 1e6:.2f} us", "1"],
            [f"python-control `nlsys` + `input_output_response` on the same step (over {args.ref_seconds:g} s)",
             f"{per_ref * n:.1f} s", f"{per_ref * 1e6:.0f} us", f"{per_ref / per_c:.0f}x slower"],
            [f"python-control linear `ss` of the same loop ({k}-state core), `initial_response`",
             f"{per_lin * n * 1e3:.1f} ms", f"{per_lin * 1e6:.2f} us", f"{per_lin / per_c:.2f}"],
            ["yardstick: hand-written dense 5-state Kalman step in C, gcc -O2, timed in alternating runs", "",
             "-" if y is None else f"{y:.0f} ns", "-" if y is None else f"loop step = {per_c * 1e9 / y:.1f}x it"],
            *([] if plant is None else [
                [f"the loop's two-track plant alone (RK4 and the output equation, the run's truth to "
                 f"{plant['diff']:.0e}), timed alternately with the loop and the yardstick",
                 f"{plant['plant'] * n * 1e3:.1f} ms", f"{plant['plant'] * 1e6:.2f} us",
                 f"{plant['plant'] * 1e9 / plant['y']:.1f}x the yardstick ({plant['y']:.0f} ns; the loop "
                 f"{plant['loop'] * 1e9 / plant['y']:.1f}x in the same passes)"],
                [f"... the same plant with the tyres' Magic Formula evaluated, not read from its table (the run's "
                 f"truth to {plant['diff_formula']:.0e}), in the same passes",
                 f"{plant['formula'] * n * 1e3:.1f} ms", f"{plant['formula'] * 1e6:.2f} us",
                 f"{plant['formula'] * 1e9 / plant['y']:.1f}x the yardstick"]])])


if __name__ == "__main__":
    main()
