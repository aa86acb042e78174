"""The compiled closed loop: :class:`LoopProgram` traces :func:`toolkit.loop.closed_loop.loop_step` for one
:class:`toolkit.loop.closed_loop.LoopSpec` and compiles it once (a lane kernel, :mod:`toolkit.kernels.lanes`, or
casadi's generated C); :func:`program` caches one per traced spec. Both are also names of
:mod:`toolkit.loop.closed_loop`."""

from __future__ import annotations

import ctypes
import warnings
from types import SimpleNamespace

import casadi as ca
import numpy as np

from evstab.plants import TRUTH, VehicleParams, get_plant
from evstab.plants.disturbances import Disturbances
from evstab.plants.errors import CompileError
from evstab.plants.maneuvers import Maneuver
from evstab.plants.sensors import SensorConfig

from ..kernels import lanes as lanes_mod
from .closed_loop import (CHUNK, EXTRA, LANE_ROLES, MEAS, SLOTS, LoopError, LoopSpec, _build, _lane_step, loop_inputs,
                          loop_theta, n_inputs, traced)
from ..kernels.compiled import CFunction, cache_key, compile_library

_CACHE: dict = {}


class LoopProgram:
    """A loop for one :class:`LoopSpec`, traced and compiled; :meth:`run` takes everything that varies by case.

    Compiled, the loop runs as a lane kernel (:mod:`toolkit.kernels.lanes`: :func:`lanes.native_width` cases per
    vector instruction, the time loop in C); :meth:`run_batch` rolls many cases out in one call and
    :meth:`run` is its one-case form. One or two cases run on a narrow kernel of
    :data:`toolkit.kernels.lanes.NARROW` lanes instead, built when first needed. Where the kernel cannot be
    built, casadi's generated C of the same step runs instead (``mapaccum`` over chunks of
    :data:`CHUNK` samples), and without a C compiler casadi's virtual machine.
    """

    def __init__(self, spec: LoopSpec, compile: bool = True, lanes: bool = True):
        """``compile``: build C (else casadi's virtual machine); ``lanes``: the lane kernel (else
        casadi's generated C, the reference the kernel is checked against). Tracing and compiling
        happen when first needed: a run builds the kernel, :meth:`jacobian` and the tuning the
        casadi trace."""
        self.spec = spec
        self.model = get_plant(spec.plant)
        self.sizes = spec.sizes
        self.names = spec.fields
        self.nin = n_inputs()
        self._jac: tuple | None = None
        # shared with the with_spec copies, so that one build serves them all
        self._lazy = SimpleNamespace(trace=None, compiled=False, lanes=None, kernels={}, lane_step=None, cf=None,
                                     cstep=None, compile=compile, use_lanes=lanes)

    # --- built on first use
    def _trace(self):
        if self._lazy.trace is None:
            self._lazy.trace = _build(self.spec)
        return self._lazy.trace

    @property
    def step(self) -> ca.Function:
        """The traced step ``(z, u, p, theta) -> (z_next, truth, extra, meas)`` (casadi SX)."""
        return self._trace()[0]

    @property
    def chunk(self) -> ca.Function:
        return self._trace()[1]

    @property
    def _sym(self):
        return self._trace()[2]

    def _build_code(self):
        lz = self._lazy
        if lz.compiled:
            return lz
        lz.compiled = True
        if lz.compile and lz.use_lanes:
            lz.lanes = self._lane_kernel(lanes_mod.native_width())
        if lz.compile and lz.lanes is None:
            lib = compile_library([self.chunk, self.step], cache_key("loop", self.spec, CHUNK, SLOTS))
            if lib is not None:
                dll = ctypes.CDLL(str(lib))
                lz.cf, lz.cstep = CFunction(dll, "loop_chunk"), CFunction(dll, "loop_step")
        return lz

    def _lane_kernel(self, width: int):
        """The lane kernel of ``width`` lanes per vector, built (or loaded from the cache) on first use;
        None where it cannot be built (warned once)."""
        lz, spec = self._lazy, self.spec
        if width not in lz.kernels:
            flags = lanes_mod.kernel_flags(width)

            def traced_step():  # traced once for the kernels of both widths
                if lz.lane_step is None:
                    lz.lane_step = _lane_step(spec)
                return lz.lane_step
            try:
                lz.kernels[width] = lanes_mod.compile_rollout(traced_step, cache_key(
                    "loop_lanes", spec, SLOTS, width, flags, lanes_mod.machine_tag()), LANE_ROLES, flags=flags,
                    width=width)
            except CompileError as e:
                warnings.warn(f"evstab: no {width}-lane kernel for this loop ({e}); using "
                              + ("the wide kernel" if width == lanes_mod.NARROW else "casadi's generated C"))
                lz.kernels[width] = None
        return lz.kernels[width]

    def _kernel_for(self, n_cases: int):
        """The lane kernel that rolls out ``n_cases`` together: the narrow one
        (:data:`toolkit.kernels.lanes.NARROW` lanes) for as many cases as it holds where the machine's vectors
        are wider, else the wide one (:attr:`lanes`); None where neither is built (casadi's C runs)."""
        lz = self._lazy
        if (lz.compile and lz.use_lanes and n_cases <= lanes_mod.NARROW < lanes_mod.native_width()
                and self._lane_kernel(lanes_mod.NARROW) is not None):
            return lz.kernels[lanes_mod.NARROW]
        return self.lanes

    @property
    def lanes(self):
        """The wide lane kernel (:class:`toolkit.kernels.lanes.LaneRollout`, :func:`toolkit.kernels.lanes.native_width`
        lanes), or None."""
        return self._build_code().lanes

    @property
    def cf(self):
        return self._build_code().cf

    @property
    def cstep(self):
        return self._build_code().cstep

    @property
    def backend(self) -> str:
        """``lanes`` (a lane kernel), ``c`` (casadi's generated C) or ``casadi`` (its virtual machine). A
        lane kernel already built answers it; otherwise the wide one is built to find out."""
        if any(k is not None for k in self._lazy.kernels.values()):
            return "lanes"  # not the wide kernel's build for a program that has run only narrow
        return "lanes" if self.lanes is not None else ("c" if self.cf is not None else "casadi")

    def compile(self) -> "LoopProgram":
        """Build the compiled code now (it is otherwise built by the first run)."""
        self._build_code()
        return self

    def with_spec(self, spec: LoopSpec) -> "LoopProgram":
        """The same compiled program, with ``spec`` (equal up to calibration) for its defaults."""
        if traced(spec) != traced(self.spec):
            raise LoopError("with_spec: the specs differ in more than the calibration")
        other = object.__new__(LoopProgram)
        other.__dict__.update(self.__dict__)
        other.spec = spec
        return other

    def theta(self, **kw) -> np.ndarray:
        """See :func:`loop_theta`."""
        return loop_theta(self.spec, **kw)

    def inputs(self, params: VehicleParams, maneuver: Maneuver, disturbances: Disturbances, sensors: SensorConfig,
               seed: int, **kw):
        """See :func:`loop_inputs`."""
        return loop_inputs(self.spec, params, maneuver, disturbances, sensors, seed, **kw)

    # --- evaluation
    def run(self, U: np.ndarray, z0: np.ndarray, pv: np.ndarray, theta: np.ndarray, final_state: bool = False,
            meas: bool = False):
        """Roll the loop out over ``U``; returns (truth Y, extra E[, readings M]) as samples x signals
        arrays, and with ``final_state`` the loop state after the last sample too (to continue a run
        block by block; ``U``'s length must then be a multiple of :data:`CHUNK`)."""
        if final_state and U.shape[0] % CHUNK:
            raise LoopError(f"final_state needs a multiple of {CHUNK} samples, got {U.shape[0]}")
        if self._kernel_for(1) is not None:
            out = self.run_batch(np.asarray(U, float)[None], np.asarray(z0, float)[None],
                                 np.asarray(pv, float)[None], np.asarray(theta, float)[None], meas=meas,
                                 final_state=final_state)
            return tuple(a[0] for a in out)
        n, nin = U.shape
        n_pad = -(-n // CHUNK) * CHUNK
        Up = np.empty((n_pad, nin))
        Up[:n] = U
        Up[n:] = U[-1]
        Y = np.empty((n_pad, len(TRUTH)))
        E = np.empty((n_pad, len(EXTRA)))
        M = np.empty((n_pad, len(MEAS)))
        z = np.array(z0, float)
        theta = np.ascontiguousarray(theta, float)
        pv = np.ascontiguousarray(pv, float)
        if self.cf is not None:
            zn = np.empty_like(z)
            for s in range(0, n_pad, CHUNK):
                self.cf([z, Up.ctypes.data + s * Up.strides[0], pv, theta],
                        [zn, Y.ctypes.data + s * Y.strides[0], E.ctypes.data + s * E.strides[0],
                         M.ctypes.data + s * M.strides[0]])
                z, zn = zn, z
        else:
            for s in range(0, n_pad, CHUNK):
                zs, ys, es, ms = self.chunk(z, Up[s:s + CHUNK].T, pv, theta)
                z = np.array(zs).ravel()
                Y[s:s + CHUNK], E[s:s + CHUNK], M[s:s + CHUNK] = np.array(ys).T, np.array(es).T, np.array(ms).T
        out = (Y[:n], E[:n]) + ((M[:n],) if meas else ())
        return out + (z,) if final_state else out

    def run_batch(self, U: np.ndarray, z0: np.ndarray, pv: np.ndarray, theta: np.ndarray, *, meas: bool = False,
                  final_state: bool = False, out: tuple[np.ndarray, np.ndarray] | None = None):
        """:meth:`run` for many cases at once: ``U`` (cases, samples, inputs), ``z0`` (cases, states),
        ``pv`` (cases, plant parameters), ``theta`` (cases, run-time parameters); returns Y, E[, M][, z]
        with a leading cases axis. One call of the lane kernel; case by case on the other backends.
        ``out``: C-ordered float arrays (cases, samples, truth) and (cases, samples, extra) that receive
        Y and E (a caller that rolls out block after block reuses its memory instead of faulting in
        fresh pages every call)."""
        U = np.asarray(U, float)
        if U.ndim != 3 or U.shape[2] != self.nin:
            raise LoopError(f"run_batch: U must be (cases, samples, {self.nin}), got {U.shape}")
        n_cases, n = U.shape[:2]
        z0, pv, theta = (np.atleast_2d(np.asarray(a, float)) for a in (z0, pv, theta))
        for what, a, k in (("z0", z0, sum(self.sizes)), ("pv", pv, len(self.names)),
                           ("theta", theta, len(self.spec.theta_names))):
            if a.shape != (n_cases, k):
                raise LoopError(f"run_batch: {what} must be ({n_cases}, {k}), got {a.shape}")
        if out is not None:
            for what, a, k in (("out[0] (truth)", out[0], len(TRUTH)), ("out[1] (extra)", out[1], len(EXTRA))):
                if not (isinstance(a, np.ndarray) and a.shape == (n_cases, n, k) and a.dtype == float
                        and a.flags.c_contiguous):
                    raise LoopError(f"run_batch: {what} must be a C-ordered float ({n_cases}, {n}, {k}) array, got "
                                    f"{getattr(a, 'dtype', type(a).__name__)} {getattr(a, 'shape', '')}")
        kernel = self._kernel_for(n_cases)
        if kernel is None:
            runs = [self.run(U[c], z0[c], pv[c], theta[c], meas=meas, final_state=final_state) for c in range(n_cases)]
            res = tuple(np.stack([r[i] for r in runs]) for i in range(len(runs[0]))) if runs else ()
            if out is not None and runs:
                out[0][...], out[1][...] = res[0], res[1]
                res = tuple(out) + res[2:]
            return res
        if out is None:
            z_end, (Y, E, M) = kernel(z0, [U, pv, theta], n, keep=(1, 2, 3) if meas else (1, 2))
        else:
            M = np.empty((n_cases, n, len(MEAS))) if meas else None
            z_end, (Y, E, M) = kernel(z0, [U, pv, theta], n, outputs=[out[0], out[1], M])
        res = (Y, E) + ((M,) if meas else ())
        return res + (z_end,) if final_state else res

    def step_once(self, z, u, pv, theta):
        """One sample through the compiled step (casadi's VM without a compiler): (z_next, y, e, m)."""
        kernel = self._kernel_for(1)
        if kernel is not None:
            z_end, outs = kernel(np.asarray(z, float)[None], [np.asarray(u, float)[None, None],
                                                                  np.asarray(pv, float)[None],
                                                                  np.asarray(theta, float)[None]], 1)
            return (z_end[0],) + tuple(a[0, 0] for a in outs)  # one case, one sample
        if self.cstep is not None:
            outs = [np.empty(sum(self.sizes)), np.empty(len(TRUTH)), np.empty(len(EXTRA)), np.empty(len(MEAS))]
            self.cstep([np.ascontiguousarray(z, float), np.ascontiguousarray(u, float), pv, theta], outs)
            return tuple(outs)
        return tuple(np.array(v).ravel() for v in self.step(z, u, pv, theta))

    def jacobian(self, keep: list[int] | None = None) -> ca.Function:
        """``(z, u, p, theta) -> d z_next[keep] / d z[keep]`` (dense; ``keep`` default all): the same
        traced step, differentiated by casadi."""
        key = tuple(range(sum(self.sizes))) if keep is None else tuple(keep)
        if self._jac is None or self._jac[0] != key:
            Z, U, pv, th, Zn = self._sym
            rows = ca.vertcat(*[Zn[i] for i in key])
            J = ca.jacobian(rows, Z)[:, list(key)]
            self._jac = (key, ca.Function("loop_jac", [Z, U, pv, th], [ca.densify(J)]))
        return self._jac[1]


def program(spec: LoopSpec) -> LoopProgram:
    """The (cached) program of ``spec``: traced and compiled once per :func:`traced` spec; its
    :meth:`LoopProgram.theta` defaults are ``spec``'s own calibration."""
    key = traced(spec)
    if key not in _CACHE:
        _CACHE[key] = LoopProgram(key)
    base = _CACHE[key]
    if spec == key:
        return base
    prog = _CACHE.get(spec)
    if prog is None:
        prog = _CACHE[spec] = _CACHE[key].with_spec(spec)
    return prog
