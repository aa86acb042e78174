"""The tuning's cost and its gradient, compiled: a case's rollout of the loop from the same ``loop_step`` the
sweep compiles, differentiated along the tuned parameters ``phi`` (:class:`RolloutCost`).

Forward mode (the default): the step carries its tangents along ``phi`` and the cost's sums
(:func:`_forward_step`), rolled out as a lane kernel four runs at a time; it also gives the truth's lateral
acceleration and its derivative, which FMVSS 126's lateral displacement is linear in. Without a C compiler
for lane kernels: casadi's reverse mode through a ``mapaccum`` rollout generated as C
(:func:`_cost_function`). :mod:`toolkit.design.tuning` drives IPOPT with them.
"""

from __future__ import annotations

import ctypes

import casadi as ca
import numpy as np

from evstab.plants import TRUTH
from evstab.plants.errors import SettingsError

from ..kernels import lanes as lanes_mod
from ..kernels.compiled import CFunction, cache_key, compile_library
from ..loop import closed_loop, loop_program
from . import sweep
from .sweep import DesignPoint, SweepConfig


def _cost_errors(Y, E):
    """The cost's four error signals (sideslip estimate, yaw-rate tracking, sideslip tracking, yaw
    moment) from the truth ``Y`` and extra ``E`` (signals x samples, casadi or numpy)."""
    it, ie = TRUTH.index, closed_loop.EXTRA.index
    return (E[ie("beta_est"), :] - Y[it("beta"), :], Y[it("yaw_rate"), :] - E[ie("yaw_rate_ref"), :],
            Y[it("beta"), :] - E[ie("beta_ref"), :], E[ie("yaw_moment"), :])


def _cost_of_sums(sums, n: int, nz_max: float):
    """:func:`sweep.cost_of` from the error signals' sums of squares (in :func:`_cost_errors`' order)
    over ``n`` samples; linear in them, so their derivatives give the cost's."""
    return sweep.cost_of(sums[1] / n, sums[2] / n, sums[0] / n, sums[3] / n, nz_max)


def _forward_step(spec, k: int) -> ca.Function:
    """The loop step carrying its tangents along ``k`` parameter directions and the cost's sums:
    ``(z_aug, u, p, theta_aug) -> (z_aug_next, [a_y, d a_y])`` with ``z_aug = [z, vec(dz), s, vec(ds)]``
    (``dz`` the state's derivative (states x k), ``s`` the error signals' running sums of squares, ``ds``
    theirs (4 x k)), ``theta_aug = [theta, vec(dtheta)]`` and, every sample, the truth's lateral
    acceleration and its derivative (1 x k; FMVSS 126's lateral displacement is linear in it, see
    :class:`DisplacementRun`): forward-mode differentiation of the same SX
    step the sweep runs (casadi ``jtimes``), rolled out as a lane kernel. The schedule's tables and the
    tyres' shape function stay casadi's inline expressions here (the hat sums, the Magic Formula, within
    3e-15 of the tyre table the sweep's kernel reads): a call node has no derivative in a lane kernel."""
    step = closed_loop._build(spec, chunk=False)[0]
    nz, nth = step.nnz_in(0), step.nnz_in(3)
    z, u, pv, th = (ca.SX.sym(name, step.nnz_in(i)) for i, name in enumerate(("z", "u", "p", "theta")))
    dz, dth = ca.SX.sym("dz", nz, k), ca.SX.sym("dtheta", nth, k)
    s, ds = ca.SX.sym("s", 4), ca.SX.sym("ds", 4, k)
    zn, y, e, _ = step(z, u, pv, th)
    err = ca.vertcat(*_cost_errors(y, e))
    ay = y[TRUTH.index("ay")]
    tangent = ca.jtimes(ca.vertcat(zn, err, ay), ca.vertcat(z, th), ca.vertcat(dz, dth))
    ds_n = ds + 2 * ca.repmat(err, 1, k) * tangent[nz:nz + 4, :]
    return ca.Function("tune_forward", [ca.vertcat(z, ca.vec(dz), s, ca.vec(ds)), u, pv, ca.vertcat(th, ca.vec(dth))],
                       [ca.vertcat(zn, ca.vec(tangent[:nz, :]), s + err ** 2, ca.vec(ds_n)),
                        ca.vertcat(ay, tangent[nz + 4, :].T)])


FORWARD_CFLAGS = ("-O1",) + lanes_mod.CFLAGS[1:]
"""The forward-mode kernel is large (56k instructions for the two-track loop, 86k for the multi-body
car's): at -O1 gcc compiles it in half the time of -O3 and it runs a little slower (measured:
docs/internals.md, compiled kernels); the same IEEE arithmetic either way."""


FORWARD_WINDOW = 1024
"""The forward-mode kernel's instructions are reordered within runs of this many
(:func:`toolkit.kernels.lanes._schedule`): faster than casadi's order; reordered over the whole step its values
spill (measured: docs/internals.md, compiled kernels)."""


def _cost_function(prog, n: int, nz_max: float) -> ca.Function:
    phi = ca.MX.sym("phi", len(DesignPoint.TUNED))
    U = ca.MX.sym("U", prog.nin, n)
    z0 = ca.MX.sym("z0", sum(prog.sizes))
    pv = ca.MX.sym("p", len(prog.names))
    rest = ca.MX.sym("rest", len(closed_loop.CASE))  # gyro_bias, gyro_scale_error, mu_assumed
    # the loop's run-time parameters: the ECU's calibration with the tuned entries from phi
    base = prog.theta()
    names = prog.spec.theta_names
    tuned = {k: j for j, k in enumerate(DesignPoint.TUNED)}
    nc = len(names) - len(closed_loop.CASE)
    th = ca.vertcat(*[ca.exp(phi[tuned[k]]) if k in tuned else float(base[i]) for i, k in enumerate(names[:nc])],
                    rest)
    acc = prog.step.mapaccum("tune_acc", n)
    _, Ys, Es, _ = acc(z0, U, ca.repmat(pv, 1, n), ca.repmat(th, 1, n))
    cost = _cost_of_sums([ca.sumsqr(e) for e in _cost_errors(Ys, Es)], n, nz_max)
    grad = ca.jacobian(cost, phi)
    return ca.Function("tune_cost", [phi, U, z0, pv, rest], [cost, grad])


class RolloutCost:
    """Compiled ``(phi, case run) -> (cost, d cost / d phi)`` for one loop structure and rollout length.

    With a C compiler the runs go through the forward-mode lane kernel (:func:`_forward_step`), four
    at a time (:meth:`batch`); ``lanes=False``, or without one, through casadi's reverse-mode
    differentiation of the ``mapaccum`` rollout (:func:`_cost_function`), one run per call. The two
    agree to rounding (``tests/toolkit/test_design.py``)."""

    def __init__(self, cfg: SweepConfig, lanes: bool = True):
        self.cfg = cfg
        self.prog = loop_program.program(cfg.spec())
        self.n = int(round(sweep.MANEUVER_DURATION / cfg.dt))
        self.nz_max = cfg.base_design().nz_max
        k, spec = len(DesignPoint.TUNED), closed_loop.traced(self.prog.spec)  # one kernel for every calibration
        self.lanes = lanes_mod.compile_rollout(
            lambda: _forward_step(spec, k), cache_key("tune_lanes", "a_y out", spec, k, closed_loop.SLOTS,
                                                      lanes_mod.WIDTH, lanes_mod.machine_tag()),
            closed_loop.LANE_ROLES, flags=FORWARD_CFLAGS, window=FORWARD_WINDOW) if lanes else None
        self.cf = None
        if self.lanes is None:
            self.fn = _cost_function(self.prog, self.n, self.nz_max)
            lib = compile_library([self.fn], cache_key("tune", cfg.spec(), self.n))
            self.cf = CFunction(ctypes.CDLL(str(lib)), "tune_cost") if lib is not None else None

    def _theta(self, phi: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The run-time parameters at ``phi`` (the ECU's calibration with the tuned entries, then the
        case's ``rest``) and their derivative by ``phi``."""
        names, base = self.prog.spec.theta_names, self.prog.theta()
        tuned = {name: j for j, name in enumerate(DesignPoint.TUNED)}
        th = np.concatenate([base[:len(names) - len(rest)], rest])
        dth = np.zeros((len(names), len(phi)))
        for name, j in tuned.items():
            i = names.index(name)
            th[i] = dth[i, j] = np.exp(phi[j])
        return th, dth

    def _augmented(self, phi: np.ndarray, runs: list, rests: list):
        """The forward-mode step's inputs for runs of one length: ``(z_aug0, U, pv, theta_aug)`` with
        zero tangents and sums at the start and theta's derivative by ``phi`` (:func:`_forward_step`)."""
        k, nz = len(phi), len(runs[0][1])
        z0 = np.zeros((len(runs), nz * (1 + k) + 4 * (1 + k)))
        z0[:, :nz] = [z for _, z, _ in runs]
        thetas = [self._theta(phi, rest) for rest in rests]
        th = np.array([np.concatenate([t, d.ravel(order="F")]) for t, d in thetas])
        return z0, np.stack([U for U, _, _ in runs]), np.array([p for _, _, p in runs]), th

    def batch(self, phi: np.ndarray, runs: list, rests: list) -> list[tuple[float, np.ndarray]]:
        """:meth:`__call__` for many runs (``runs[i]`` with ``rests[i]``), one lane-kernel call."""
        if self.lanes is None:
            return [self(phi, run, rest) for run, rest in zip(runs, rests)]
        for U, _, _ in runs:
            if U.shape[0] != self.n:
                raise SettingsError(f"rollout has {U.shape[0]} samples, the compiled cost takes {self.n}")
        k, nz = len(phi), len(runs[0][1])
        z0, U, pv, th = self._augmented(phi, runs, rests)
        z_end, _ = self.lanes(z0, [U, pv, th], self.n, keep=())
        sums = z_end[:, nz * (1 + k):]
        return [(float(_cost_of_sums(q[:4], self.n, self.nz_max)),
                 _cost_of_sums(q[4:].reshape((4, k), order="F"), self.n, self.nz_max)) for q in sums]

    def lateral_acceleration(self, phi: np.ndarray, runs: list, rests: list) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per run (``(U, z0, pv)`` of any length, with its ``rests`` entry) the truth's lateral acceleration
        (samples,) and its derivative by ``phi`` (samples x parameters): the forward-mode lane kernel,
        the runs of one length in one call; without one, the same forward-mode step rolled out by
        casadi's virtual machine (slow, but the same numbers to rounding)."""
        out: list = [None] * len(runs)
        by_len: dict[int, list[int]] = {}
        for i, (U, _, _) in enumerate(runs):
            by_len.setdefault(U.shape[0], []).append(i)
        for n, idx in by_len.items():
            z0, U, pv, th = self._augmented(phi, [runs[i] for i in idx], [rests[i] for i in idx])
            if self.lanes is not None:
                _, (A,) = self.lanes(z0, [U, pv, th], n)
            else:
                fwd = self._forward_vm(n)
                A = np.stack([np.array(fwd(z0[q], U[q].T, pv[q], th[q])[1]).T for q in range(len(idx))])
            for q, i in enumerate(idx):
                out[i] = (A[q, :, 0].copy(), A[q, :, 1:].copy())
        return out

    def _forward_vm(self, n: int):
        if getattr(self, "_vm", (None,))[0] != n:
            spec = closed_loop.traced(self.prog.spec)
            self._vm = (n, _forward_step(spec, len(DesignPoint.TUNED)).mapaccum("tune_forward_acc", n))
        return self._vm[1]

    def __call__(self, phi: np.ndarray, run, rest: np.ndarray) -> tuple[float, np.ndarray]:
        U, z0, pv = run
        if U.shape[0] != self.n:
            raise SettingsError(f"rollout has {U.shape[0]} samples, the compiled cost takes {self.n}")
        if self.lanes is not None:
            return self.batch(phi, [run], [rest])[0]
        if self.cf is not None:
            # casadi matrices are column-major: a C-contiguous (samples x inputs) array is the
            # (inputs x samples) matrix the function takes, without a copy
            c, g = np.empty(1), np.empty(len(phi))
            self.cf([np.ascontiguousarray(phi, float), np.ascontiguousarray(U, float), np.ascontiguousarray(z0, float),
                     np.ascontiguousarray(pv, float), np.ascontiguousarray(rest, float)], [c, g])
            return float(c[0]), g
        c, g = self.fn(phi, U.T, z0, pv, rest)
        return float(c), np.array(g).ravel()
