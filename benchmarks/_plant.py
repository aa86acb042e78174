"""The plant's share of a compiled loop step: the two-track plant alone, as a lane kernel of its own.

The loop step (:func:`toolkit.loop.closed_loop.loop_step`) is the plant's output equation (the truth the
sensors sample, with the commands of the last period), the sensors, the ECU step, the actuators and
the plant's RK4 over the period. :func:`plant_kernel` compiles the plant's two parts alone, the same
functions (:func:`toolkit.kernels.compiled.rk4_step`, the model's ``h`` and command map) on the same lane
kernel machinery (:mod:`toolkit.kernels.lanes`), and :func:`plant_inputs` feeds it what a loop run applied, so
that it retraces that run's truth: what a loop step costs at the least, whatever the ECU does.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from evstab.plants import get_plant
from evstab.plants.backend import call_nodes
from evstab.plants.disturbances import DISTURBANCES
from evstab.plants.model import COMMANDS
from evstab.toolkit.loop import closed_loop as cl
from evstab.toolkit.kernels import lanes as lanes_mod
from evstab.toolkit.kernels.compiled import cache_key, rk4_step, symbolic_view

ROLES = lanes_mod.Roles(stepped=(1,))
"""The plant kernel's inputs: ``u`` (the last period's commands, this period's, the disturbances) per
sample, the plant parameters per case."""


def plant_step(spec: cl.LoopSpec, table: bool = True) -> ca.Function:
    """``(x, u, p) -> (x_next, truth)``: the plant's part of one loop sample, ``u`` = (commands of the
    last period, commands of this one, disturbances), each per :data:`plants.model.COMMANDS` and
    :data:`plants.disturbances.DISTURBANCES`. Traced as the loop's lane kernel is
    (:func:`toolkit.loop.closed_loop._lane_step`: the tyres read their table); ``table=False`` evaluates the
    Magic Formula instead (:func:`plants.tires.combined_forces` inline, 3e-15 from the table)."""
    if not table:
        return _plant_step(spec)
    with call_nodes():
        return _plant_step(spec)


def _plant_step(spec: cl.LoopSpec) -> ca.Function:
    model = get_plant(spec.plant)
    nc, nw = COMMANDS.size, DISTURBANCES.size
    x = ca.SX.sym("x", len(model.states))
    u = ca.SX.sym("u", 2 * nc + nw)
    pv = ca.SX.sym("p", len(spec.fields))
    sp = symbolic_view(cl._TEMPLATE, spec.fields, pv)
    cmd_prev, cmd, w = u[:nc], u[nc:2 * nc], u[2 * nc:]
    y = model.h(x, model.command_map(cmd_prev, x, sp), w, sp)
    x_next = rk4_step(model, sp, x, cmd, w, spec.dt, spec.n_sub)
    return ca.Function("plant_step", [x, u, pv], [x_next, y], ["x", "u", "p"], ["x_next", "truth"])


def plant_kernel(spec: cl.LoopSpec, table: bool = True, cases: int | None = None) -> lanes_mod.LaneRollout | None:
    """The lane kernel of :func:`plant_step` at the width and flags the loop's kernel has for ``cases``
    cases at once (:meth:`toolkit.loop.loop_program.LoopProgram.run_batch`: the narrow kernel for one or two,
    default the wide one); None without a C compiler."""
    wide = lanes_mod.native_width()
    width = lanes_mod.NARROW if cases is not None and cases <= lanes_mod.NARROW < wide else wide
    flags = lanes_mod.kernel_flags(width)
    return lanes_mod.compile_rollout(lambda: plant_step(spec, table), cache_key(
        "bench_plant", cl.traced(spec), table, width, flags, lanes_mod.machine_tag()), ROLES, flags=flags,
        width=width)


def plant_inputs(spec: cl.LoopSpec, U: np.ndarray, z0: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x0 (cases, states), u (cases, samples, inputs)) of :func:`plant_step` that retrace loop runs:
    ``U`` and ``z0`` their inputs and initial states, ``E`` their :data:`toolkit.loop.closed_loop.EXTRA`
    (what was applied over each period; nothing before the first)."""
    nc = COMMANDS.size
    ui, ex = cl.INPUTS.columns, cl.EXTRA.index
    n_cases, n = U.shape[:2]
    u = np.zeros((n_cases, n, 2 * nc + DISTURBANCES.size))
    for c in range(n_cases):
        cols = ui(U[c])
        applied = {"steer": E[c, :, ex("steer")], "yaw_moment": E[c, :, ex("yaw_moment")],
                   "steer_rate": E[c, :, ex("steer_rate")]}
        for k, name in enumerate(COMMANDS):
            if name in applied:
                u[c, 1:, k] = applied[name][:-1]  # the last period's (zero before the first)
                u[c, :, nc + k] = applied[name]
            elif name == "drive_on":  # this sample's, times the ECU's drive share: the last period's as the loop
                share = E[c, :, ex("drive_share")]  # holds it (1 less the cut it stores), this one's
                u[c, :, k] = cols[name] * (1.0 - np.concatenate([[0.0], 1.0 - share[:-1]]))
                u[c, :, nc + k] = cols[name] * share
            elif name == "speed_ref":  # this sample's, in both
                u[c, :, k] = u[c, :, nc + k] = cols[name]
            # the brakes: the loop applies none (zero, as u starts)
        u[c, :, 2 * nc:] = cols["disturbances"]
    return z0[:, spec.state_layout.slot("plant")].copy(), u


def retrace(spec: cl.LoopSpec, kernel: lanes_mod.LaneRollout, U, z0, pv, E, Y) -> tuple[np.ndarray, np.ndarray, float]:
    """The plant kernel's inputs for loop runs (:func:`plant_inputs`: x0 and u), and the largest
    difference of its truth from the loop's ``Y``: zero when the plant's part of the loop is what the
    kernel computes."""
    x0, u = plant_inputs(spec, U, z0, E)
    _, (Yp,) = kernel(x0, [u, pv], U.shape[1])
    return x0, u, float(np.max(np.abs(Yp - Y)))


def best_alternating(runs: dict, rounds: int = 7, pause: float = 0.02) -> dict:
    """The best of each callable of ``runs`` (name -> callable), run in ``rounds`` alternating passes
    ``pause`` s apart, so that all of them see the same spells of this shared machine's speed: its
    wall time [s], or what it returns when that is a number (a callable that times itself, as the
    yardstick's pass does)."""
    import time
    best = {k: np.inf for k in runs}
    for _ in range(rounds):
        for k, f in runs.items():
            t0 = time.perf_counter()
            r = f()
            t = time.perf_counter() - t0
            best[k] = min(best[k], float(r) if isinstance(r, (int, float)) else t)
            time.sleep(pause)
    return best
