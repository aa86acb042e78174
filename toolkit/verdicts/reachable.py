"""What the ECU's actuators can reach at all on an envelope case: the smallest peak sideslip that any
command sequence of the front steer correction and the rear motors gives, found by optimal control.

Where the envelope's *stabilise* rule is broken (:mod:`toolkit.verdicts.envelope`), the question is
whether physics forbids the rule -- a yaw controller cannot add grip -- or the law falls short. This
module answers it by construction on the two-track plant (:mod:`plants.two_track`, the envelope's own
equations): from the car alone's state at ``start`` it searches the commands that keep the largest
``|beta|`` up to ``end`` as small as they can be, where

* up to ``react`` the car is driven as the car alone (the driver's steer; the speed hold's rear torques
  from :func:`plants.two_track.command_map`), so no command may anticipate the event;
* from ``react`` on, the road-wheel angle is the driver's plus a correction within the steer authority
  (``controllers.two_dof.STEER_AUTHORITY``, 20 deg, at most ``STEER_AUTHORITY_RATE``, 100 deg/s, as the
  default ECU's) and each rear wheel's torque is free within the motor's limit (``max_motor_torque``: the
  ECU's speed hold and yaw moment together span no more); the front wheels carry no torque.

The search (casadi's ``Opti`` with IPOPT) is a direct collocation of the plant's equations (Radau IIA,
3 points per step of ``step`` s: stable for the wheel-spin modes, whose time constant is a few
milliseconds at speed), minimising ``s`` subject to ``|beta| <= s`` at every collocation point. It knows
the road after ``react`` (clairvoyant) and leaves out the actuators' lags, so what it reaches is what the
tyres and the actuators' ranges allow, not what a causal law can achieve; and IPOPT's optimum is local, so
the figure is reachable (:func:`replay` integrates the commands found through the plant with scipy's
``solve_ivp`` to show it), not proven the smallest. A reachable peak below the rule says that the rule's
failure is the law's, not physics'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants import VehicleParams, two_track
from evstab.plants.disturbances import disturbance_profile
from evstab.plants.errors import DesignError
from evstab.plants.model import COMMANDS, DISTURBANCES
from evstab.controllers.two_dof import STEER_AUTHORITY, STEER_AUTHORITY_RATE
from evstab.toolkit.loop.simulator import simulate
from evstab.toolkit.verdicts.envelope import Case, run_setup

RADAU_POINTS = 3
"""Collocation points per step (Radau IIA, order 5)."""


@dataclass(frozen=True)
class Reachable:
    """The commands found and what they give (arrays on the step grid ``t``, the commands per step)."""

    case: str
    react: float
    """[s] Time from which the commands are free."""
    peak_beta_deg: float
    """The smallest peak ``|beta|`` found over ``[start, end]`` [deg]."""
    alone_peak_beta_deg: float
    """The car alone's peak ``|beta|`` over the same window [deg] (the simulator's run)."""
    t: np.ndarray
    x: np.ndarray
    """Plant states (:data:`plants.two_track.STATES`) at the step grid, shape (14, len(t))."""
    correction: np.ndarray
    """Steer correction [rad] at the step grid (linear between)."""
    torques: np.ndarray
    """Rear torques (RL, RR) [N m] per step, shape (2, len(t) - 1), held over the step; NaN before ``react``
    (the speed hold's, a function of the state)."""
    status: str
    """IPOPT's return status."""


def _state(run, i: int) -> np.ndarray:
    """The two-track state at sample ``i`` of a simulator run (the load-transfer lags at the accelerations)."""
    tr = run.truth
    names = {"ax_f": "ax", "ay_f": "ay", **{f"omega_{c}": f"wheel_speed_{c}" for c in ("fl", "fr", "rl", "rr")}}
    return np.array([tr[names.get(n, n)][i] for n in two_track.STATES], float)


def _road(road, t: float) -> np.ndarray:
    """The disturbance vector (:data:`plants.model.DISTURBANCES`) of ``road`` at time ``t``."""
    return disturbance_profile(road, np.array([t]))[:, 0]


def _free_inputs(steer, t_rl, t_rr) -> list:
    """The two-track's physical inputs (:data:`plants.two_track.INPUTS`) of a searched step: the road-wheel
    angle and the rear motors' torques; no front torque, no brake."""
    given = {"steer": steer, "torque_rl": t_rl, "torque_rr": t_rr}
    return [given.get(name, 0.0) for name in two_track.INPUTS]


def _driver_command(man, t: float):
    """The car alone's commands (:data:`plants.model.COMMANDS`) at time ``t``: the driver's steer and speed hold."""
    at = np.array([t])
    return COMMANDS.pack(steer=float(man.steer(at)[0]), yaw_moment=0.0, speed_ref=float(man.speed_ref(at)[0]),
                         drive_on=float(man.drive_on(at)[0]), steer_rate=0.0)


def search(case: Case, p: VehicleParams, *, start: float, react: float, end: float, step: float = 0.02,
           guess=None, warm: Reachable | None = None, authority: float = STEER_AUTHORITY,
           authority_rate: float = STEER_AUTHORITY_RATE, max_iter: int = 500) -> Reachable:
    """The commands that keep the peak sideslip of ``case`` on the two-track car ``p`` smallest over
    ``[start, end]``, free from ``react`` (see the module's docstring). ``guess``: a simulator run whose
    states and commands start the search (default the default ECU's, seed 0: from the car alone's spin the
    search ends in a spin of its own). ``warm``: a search on the same grid whose commands and states start
    this one instead (a later reaction's: its commands are open to an earlier one). Raises :class:`DesignError` where the
    car has no rear motor limit or the window is empty."""
    import casadi as ca
    if p.max_motor_torque is None:
        raise DesignError(f"{p.name}: the reachable set needs the vehicle's 'max_motor_torque'")
    if not start < end:
        raise DesignError(f"reachable: the window [{start}, {end}] s is empty")
    man, road, truth = run_setup(case, p)
    if truth is not None or not man.open_loop:
        raise DesignError(f"reachable: '{case.label}' is not an open-loop manoeuvre on the car's own parameters")
    alone = simulate(p, "two-track", man, disturbances=road, controller=None)
    if guess is None:  # the car alone spins where the question matters: the search would follow it
        guess = simulate(p, "two-track", man, disturbances=road, controller="two-dof")
    n = int(round((end - start) / step))
    t = start + step * np.arange(n + 1)
    tau = ca.collocation_points(RADAU_POINTS, "radau")
    C, D, _ = ca.collocation_coeff(tau)  # the interpolant through the step's start and points: slopes, end value
    nx = len(two_track.STATES)
    xs, us, ws = ca.SX.sym("x", nx), ca.SX.sym("u", len(two_track.INPUTS)), ca.SX.sym("w", len(DISTURBANCES))
    f = ca.Function("f", [xs, us, ws], [two_track.f(xs, us, ws, p)])
    cs = ca.SX.sym("c", len(COMMANDS))
    hold = ca.Function("hold", [cs, xs], [two_track.command_map(cs, xs, p)])
    beta = ca.Function("beta", [xs], [ca.atan2(xs[1], xs[0])])
    tm = float(p.max_motor_torque)

    opti = ca.Opti()
    X = opti.variable(nx, n + 1)
    corr = opti.variable(1, n + 1)
    rate = opti.variable(1, n)
    torque = opti.variable(2, n)          # per unit of the motor limit
    peak = opti.variable()
    points = []
    i0 = int(np.searchsorted(alone.t, start))
    opti.subject_to(X[:, 0] == _state(alone, i0))
    opti.subject_to(corr[0] == 0.0)
    for k in range(n):
        free = t[k] >= react - 1e-9
        opti.subject_to(corr[k + 1] == corr[k] + step * rate[k])
        opti.subject_to(opti.bounded(-authority_rate, rate[k], authority_rate))
        opti.subject_to(opti.bounded(-authority, corr[k + 1], authority))
        opti.subject_to(opti.bounded(-1.0, torque[:, k], 1.0))
        if not free:
            opti.subject_to(rate[k] == 0.0)
            opti.subject_to(torque[:, k] == 0.0)
        xc = opti.variable(nx, RADAU_POINTS)
        points.append(xc)
        z = ca.horzcat(X[:, k], xc)
        slopes = z @ C
        for j in range(RADAU_POINTS):
            tj = t[k] + tau[j] * step
            if free:
                steer = float(man.steer(np.array([tj]))[0]) + corr[k] + tau[j] * step * rate[k]
                u = ca.vertcat(*_free_inputs(steer, tm * torque[0, k], tm * torque[1, k]))
            else:
                u = hold(_driver_command(man, tj), xc[:, j])
            # the road just inside the step: a change at a grid time (the friction drop) starts the next step
            opti.subject_to(step * f(xc[:, j], u, _road(road, tj - 1e-6 * step)) == slopes[:, j])
            opti.subject_to(opti.bounded(-peak, beta(xc[:, j]), peak))
            opti.set_initial(xc[:, j], _state(guess, min(int(np.searchsorted(guess.t, tj)), len(guess.t) - 1)))
        opti.subject_to(X[:, k + 1] == z @ D)
    # a vanishing cost on the commands' motion picks one of the many sequences with the same peak
    opti.minimize(peak + 1e-6 * ca.sumsqr(rate) + 1e-6 * ca.sumsqr(torque))
    for k in range(n + 1):
        i = min(int(np.searchsorted(guess.t, t[k])), len(guess.t) - 1)
        opti.set_initial(X[:, k], _state(guess, i))
        if "steer_driver" in guess.commands:
            opti.set_initial(corr[k], float(np.clip(guess.commands["steer"][i] - guess.commands["steer_driver"][i],
                                                    -authority, authority)))
    opti.set_initial(peak, float(np.max(np.abs(guess.truth["beta"][i0:int(np.searchsorted(guess.t, end)) + 1]))))
    if warm is not None:
        if len(warm.t) != n + 1 or not np.allclose(warm.t, t):
            raise DesignError("reachable: the warm start's grid is not this search's")
        opti.set_initial(X, warm.x)
        opti.set_initial(corr, warm.correction.reshape(1, -1))
        opti.set_initial(rate, (np.diff(warm.correction) / step).reshape(1, -1))
        opti.set_initial(torque, np.nan_to_num(warm.torques, nan=0.0) / tm)
        opti.set_initial(peak, np.radians(warm.peak_beta_deg))
        for k, xc in enumerate(points):
            opti.set_initial(xc, warm.x[:, [k]] + np.outer(warm.x[:, k + 1] - warm.x[:, k], tau))
    opti.solver("ipopt", {"print_time": False}, {"max_iter": max_iter, "print_level": 0, "tol": 1e-7, "sb": "yes"})
    # a search stopped short (its iteration limit) still gives commands: what they reach is what replay shows
    sol = opti.solve_limited()
    status = str(sol.stats().get("return_status", "failed"))
    tq = np.atleast_2d(sol.value(torque)) * tm
    tq[:, t[:-1] < react - 1e-9] = np.nan
    j_end = int(np.searchsorted(alone.t, end)) + 1
    return Reachable(case=case.label, react=float(react), peak_beta_deg=float(np.degrees(sol.value(peak))),
                     alone_peak_beta_deg=float(np.degrees(np.max(np.abs(alone.truth["beta"][i0:j_end])))),
                     t=t, x=np.asarray(sol.value(X)), correction=np.atleast_1d(sol.value(corr)), torques=tq,
                     status=status)


def replay(r: Reachable, case: Case, p: VehicleParams, *, rtol: float = 1e-9, atol: float = 1e-9) -> np.ndarray:
    """The sideslip [rad] at ``r.t`` when the commands of ``r`` drive the two-track car from ``r``'s first
    state, integrated by scipy's ``solve_ivp`` (Radau, variable step, ``rtol``/``atol``) step by step: an
    integrator independent of the search's collocation."""
    from scipy.integrate import solve_ivp
    man, road, _ = run_setup(case, p)
    x = r.x[:, 0].copy()
    out = [float(np.arctan2(x[1], x[0]))]
    for k in range(len(r.t) - 1):
        t0, t1 = r.t[k], r.t[k + 1]
        rate = (r.correction[k + 1] - r.correction[k]) / (t1 - t0)
        free = not np.isnan(r.torques[0, k])

        def rhs(t, x, k=k, t0=t0, t1=t1, rate=rate, free=free):
            if free:
                steer = float(man.steer(np.array([t]))[0]) + r.correction[k] + (t - t0) * rate
                u = np.array(_free_inputs(steer, r.torques[0, k], r.torques[1, k]))
            else:
                u = np.asarray(two_track.command_map(np.asarray(_driver_command(man, t), float), x, p), float)
            return np.asarray(two_track.f(x, u, _road(road, min(t, t1 - 1e-6 * (t1 - t0))), p), float)
        sol = solve_ivp(rhs, (t0, t1), x, method="Radau", rtol=rtol, atol=atol)
        x = sol.y[:, -1]
        out.append(float(np.arctan2(x[1], x[0])))
    return np.array(out)
