"""Plant simulation speed: evstab's compiled rollout vs python-control, same model, same process.

Each plant runs a 0.5 Hz sine steer at 60 km/h for 10 s at 1 kHz through
:class:`toolkit.kernels.compiled.CompiledPlant` (casadi-generated C, one call per 2000
samples; and casadi's virtual machine when no compiler is used), and through
``control.input_output_response`` of a ``control.nlsys`` whose update function
is the same numpy ``f(x, u, w, p)``. python-control is slow, so by default it
runs the first ``--ref-seconds`` of the same run and its cost is reported per
step; the ratio printed is per-step time (python-control / evstab).

The CommonRoad multi-body car (``commonroad-mb:1``) is compared with the package's own
Python function ``vehiclemodels.vehicle_dynamics_mb`` instead, stepped by the same RK4 in
Python with the same servo and speed hold, with the package's tyre ``sign`` replaced by
evstab's smoothed one so that both integrate one model (the final-state difference says so).

Run: ``python benchmarks/bench_plants.py [--vehicle compact-ev] [--ref-seconds 1]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import control
import numpy as np

from evstab.plants import COMMANDS, DISTURBANCES, PLANTS, default_disturbance, load_vehicle
from evstab.toolkit.kernels.compiled import CompiledPlant


def best_of(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="compact-ev")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--ref-seconds", type=float, default=1.0, help="horizon run through python-control")
    ap.add_argument("--dt", type=float, default=1e-3)
    ap.add_argument("--md", help="also write the table as Markdown to this file (the docs' table)")
    args = ap.parse_args(argv)
    p = load_vehicle(args.vehicle)
    n = int(round(args.seconds / args.dt))
    t = np.arange(n) * args.dt
    v = 60 / 3.6
    steer = np.radians(2.0) * np.sin(2 * np.pi * 0.5 * t)
    cmd = COMMANDS.pack(steer=steer, yaw_moment=np.zeros(n), speed_ref=np.full(n, v), drive_on=np.ones(n),
                        steer_rate=np.zeros(n))
    rows = []
    w = default_disturbance(p.mu)
    print(f"vehicle {p.name}, {args.seconds:g} s at {1 / args.dt:g} Hz ({n} steps); "
          f"python-control over the first {args.ref_seconds:g} s")
    print(f"{'plant':14s} {'evstab C':>12s} {'evstab VM':>12s} {'python-control':>15s} {'ratio C':>9s} {'ratio VM':>9s}")
    for name, model in PLANTS.items():
        x0 = model.initial_state(p, v)
        cp_c = CompiledPlant(model, p, args.dt, compile=True)
        cp_v = CompiledPlant(model, p, args.dt, compile=False)
        tc, (Xc, _) = best_of(lambda: cp_c.rollout(x0, cmd, w), 5)
        tv, _ = best_of(lambda: cp_v.rollout(x0, cmd, w), 2)

        def upd(_t, x, u, _params, model=model):
            return model.f(x, model.command_map(u[:len(COMMANDS)], x, p), u[len(COMMANDS):], p)

        sys = control.nlsys(upd, None, inputs=len(COMMANDS) + len(DISTURBANCES), states=list(model.states),
                            outputs=list(model.states), name=name)
        m = int(round(args.ref_seconds / args.dt))
        U = np.vstack([cmd[:, :m], np.repeat(w[:, None], m, axis=1)])
        t0 = time.perf_counter()
        resp = control.input_output_response(sys, t[:m], U, x0, solve_ivp_kwargs={"max_step": args.dt})
        tref = time.perf_counter() - t0
        err = np.abs(resp.states[:, -1] - Xc[:, m - 1]).max()
        per_c, per_v, per_ref = tc / n, tv / n, tref / m
        print(f"{name:14s} {per_c * 1e6:9.3f} us {per_v * 1e6:9.3f} us {per_ref * 1e6:12.1f} us "
              f"{per_ref / per_c:8.0f}x {per_ref / per_v:8.0f}x   (final-state diff {err:.1e}; "
              f"backend {cp_c.backend}, {cp_c.n_sub} RK4 sub-step(s))")
        rows.append([name, f"{per_c * 1e6:.3g} us", f"{per_v * 1e6:.3g} us", f"{per_ref * 1e6:.0f} us",
                     f"{per_ref / per_c:.0f}x", f"{per_ref / per_v:.0f}x"])
    rows.append(multibody(args, cmd, t, n))
    if args.md:
        from evstab.studies._common import write_markdown
        write_markdown(Path(args.md), ["plant", "evstab (C)", "evstab (casadi VM)", "python-control", "ratio C",
                                       "ratio VM"], rows)


def multibody(args, cmd, t, n) -> list[str]:
    """commonroad-mb:1 compiled against the package's Python function stepped by RK4 in Python."""
    import vehiclemodels.utils.tire_model as tm
    from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    from evstab.plants import commonroad_mb as mb, get_plant
    from evstab.plants.backend import NUMPY
    model = get_plant("commonroad-mb:1")
    p = load_vehicle("commonroad-1")
    c = COMMANDS.as_dict(cmd)
    v = c["speed_ref"][0]
    x0 = model.initial_state(p, v)
    cp = CompiledPlant(model, p, args.dt, compile=True)
    cmd = COMMANDS.pack(c, steer_rate=np.diff(c["steer"], prepend=c["steer"][:1]) / args.dt)
    w = default_disturbance()
    tc, (Xc, _) = best_of(lambda: cp.rollout(x0, cmd, w), 5)
    P = mb.package_parameters(1)
    tm.sign = lambda g: float(mb.smooth_sign(g, NUMPY))  # the same tyre as the port (this process only)
    h = args.dt / cp.n_sub
    i_st = mb.STATES.index("steer")

    def rhs(x, c):
        u = model.command_map(c, x, p)  # servo and speed hold: the plant's own map
        rate = u[1] + mb.SERVO_GAIN * (u[0] - x[i_st])
        fs = vehicle_dynamics_mb(list(x[:29] * mb.SAE_SIGN), [-rate, u[2]], P)
        return np.append(np.asarray(fs) * mb.SAE_SIGN, u[5])

    m = int(round(args.ref_seconds / args.dt))
    x = x0.copy()
    t0 = time.perf_counter()
    for k in range(m):
        c = cmd[:, k]
        for _ in range(cp.n_sub):
            k1 = rhs(x, c)
            k2 = rhs(x + h / 2 * k1, c)
            k3 = rhs(x + h / 2 * k2, c)
            k4 = rhs(x + h * k3, c)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    tref = time.perf_counter() - t0
    err = np.abs(x - Xc[:, m]).max()
    per_c, per_ref = tc / n, tref / m
    print(f"{'commonroad-mb:1':14s} {per_c * 1e6:9.3f} us {'':>12s} {per_ref * 1e6:12.1f} us "
          f"{per_ref / per_c:8.0f}x {'':>9s}   (against the package's vehicle_dynamics_mb in Python; "
          f"final-state diff {err:.1e}; {cp.n_sub} RK4 sub-steps)")
    return ["commonroad-mb:1", f"{per_c * 1e6:.3g} us", "", f"{per_ref * 1e6:.0f} us", f"{per_ref / per_c:.0f}x", ""]


if __name__ == "__main__":
    main()
