"""Replay a drive log through the ECU step (estimator and controller, open loop).

``evstab replay`` and ``evstab estimate --design`` run here. The step is the
casadi trace of :func:`toolkit.ecu.step.ecu_step` (the graph the exported C is
written from), rolled out by ``mapaccum`` and compiled by casadi's own code
generator (cached), or run in casadi's virtual machine without a compiler; a
Python loop over the numpy step is the reference (``backend="numpy"``). Like the
filter runner, each sample takes the branch without the course update when it
carries no fix.

Log columns read (the drive-log schema, docs/formats.md): ``t``, ``speed``, ``steer``, ``yaw_rate``,
``gps_course`` (required), ``ay``, ``yaw_moment``, ``gps_speed``, ``gps_hdop``,
``gps_sats`` (optional), and the ECU's own inputs when the log has them:
``steer_driver`` (driver's road-wheel angle command; default ``steer``),
``steer_limited_last`` and ``yaw_moment_limited_last`` (actuator limit flags of
the previous period; default 0). ``*_true`` columns are never read.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import casadi as ca
import numpy as np

from evstab.plants.backend import NUMPY

from ..kernels.compiled import cache_key, load_chunk_library, run_chunks
from ..ecu import guard as guard_mod
from ..ecu.step import INPUTS, OUTPUTS, EcuDesign, ecu_core, ecu_guard, traced_guard, traced_steps
from ..logs.drivelog import LogFormatError

CHUNK = 2000
LOG_COLUMNS = ("ay", "yaw_moment", "gps_speed", "gps_hdop", "gps_sats", "steer_driver", "steer_limited_last",
               "yaw_moment_limited_last", "wheel_speed_rl", "wheel_speed_rr")
"""Optional drive-log columns the replay reads (besides the schema's required ones)."""


def ecu_inputs(log, mu: float, dt0: float = 1e-3, wheel_radius: float | None = None) -> np.ndarray:
    """The (N, len(INPUTS)) ECU input matrix of a drive log (a :class:`DriveLog` or a mapping of columns).

    ``dt`` of the first row is the second row's spacing (``dt0`` for a one-row log);
    no fix where ``gps_course`` is NaN; HDOP 1 and 99 satellites where unknown; wheel
    speeds ``speed / wheel_radius`` (no slip) where the log has none (``wheel_radius``: the ECU's); no driver's
    brake pressure where the log has no ``brake_pressure_driver``.
    """
    cols = log.columns if hasattr(log, "columns") else log
    get = lambda k: np.asarray(cols[k], float) if k in cols else None  # noqa: E731
    t = np.asarray(cols["t"], float)
    n = len(t)
    U = INPUTS.zeros(n)
    col = INPUTS.columns(U)  # views: writing them fills U
    col["dt"][0] = dt0 if n < 2 else t[1] - t[0]
    col["dt"][1:] = np.diff(t)
    course = np.asarray(cols["gps_course"], float)
    fix = np.isfinite(course)
    col["speed"][:], col["steer"][:], col["yaw_rate"][:] = get("speed"), get("steer"), get("yaw_rate")
    col["gps_valid"][:] = fix
    col["gps_course"][:] = np.where(fix, course, 0.0)

    def opt(name, default, missing=None):
        v = get(name)
        return np.full(n, default) if v is None else np.where(np.isfinite(v), v, default if missing is None else missing)

    col["ay"][:] = opt("ay", 0.0)
    col["gps_speed"][:] = opt("gps_speed", 0.0)
    col["gps_hdop"][:] = opt("gps_hdop", 1.0)
    col["gps_sats"][:] = opt("gps_sats", 99.0)
    col["yaw_moment_applied"][:] = opt("yaw_moment", 0.0)
    drv = get("steer_driver")
    col["steer_cmd_driver"][:] = col["steer"] if drv is None else drv
    col["steer_limited"][:] = opt("steer_limited_last", 0.0)
    col["yaw_moment_limited"][:] = opt("yaw_moment_limited_last", 0.0)
    col["mu"][:] = mu
    col["brake_pressure_driver"][:] = opt("brake_pressure_driver", 0.0)
    for side in ("rl", "rr", "fl", "fr"):
        w = get(f"wheel_speed_{side}")
        if w is None or not np.all(np.isfinite(w)):
            if wheel_radius is None:
                raise LogFormatError(f"the log has no (finite) wheel_speed_{side} column; give the ECU's wheel radius")
            fill = col["speed"] / wheel_radius
            w = fill if w is None else np.where(np.isfinite(w), w, fill)
        col[f"wheel_speed_{side}"][:] = w
    return U


class EcuProgram:
    """An ECU design ready to replay logs; ``backend`` is ``c``, ``vm`` or ``numpy``."""

    def __init__(self, d: EcuDesign, backend: str = "auto"):
        self.design = d
        self.cal = np.array([c.value for c in d.calibration()])
        self.backend = "numpy" if backend == "numpy" else "vm"
        self._chunk: ca.Function | None = None
        self._guard_chunk: ca.Function | None = None
        self._c = self._gc = None
        if backend in ("auto", "c"):
            self._c = load_chunk_library(cache_key("ecu", d, CHUNK), lambda: self.chunk_fn, "ecu_chunk", required=backend == "c")
            self._gc = load_chunk_library(cache_key("ecu_guard", d, CHUNK), lambda: self.guard_chunk_fn, "guard_chunk",
                                          required=backend == "c")
            if self._c is not None and self._gc is not None:
                self.backend = "c"

    @property
    def guard_chunk_fn(self) -> ca.Function:
        """``(zg0, U) -> (zg_end, speed)`` over :data:`CHUNK` samples: the input guard alone, its state started from
        ``zg0`` and the rest of the step's state at 0, and its guarded speed (the schedule's tables are read at
        it): the speed's checks read the inputs and the guard's own speed history alone, so it is
        the step's; the rest of the guard reads the law's authority and command too (the vote, the two steer angles,
        the applied yaw moment), which the step (:attr:`chunk_fn`) runs the guard with."""
        if self._guard_chunk is None:
            d = self.design
            ng = guard_mod.STATE.size
            g = traced_guard(d)
            lay = d.layout
            nc = len(d.calibration())
            zg, u, c = ca.MX.sym("zg", ng), ca.MX.sym("u", INPUTS.size), ca.MX.sym("c", nc)
            z_full = ca.vertcat(ca.MX.zeros(lay.index("guard")), zg)
            zn, uc = g(z_full, u, c)
            zg_n = zn[lay.index("guard"):]
            step = ca.Function("guard_step", [zg, u, c], [zg_n, uc[INPUTS.index("speed")]])
            acc = step.mapaccum("guard_acc", CHUNK)
            z0, U, C = ca.MX.sym("z0", ng), ca.MX.sym("U", INPUTS.size, CHUNK), ca.MX.sym("c", nc)
            Z, Y = acc(z0, U, ca.repmat(C, 1, CHUNK))
            self._guard_chunk = ca.Function("guard_chunk", [z0, U, C], [Z[:, -1], Y])
        return self._guard_chunk

    @property
    def chunk_fn(self) -> ca.Function:
        """``(z0, U, S, cal) -> (z_end, Y)`` over :data:`CHUNK` samples (built on first use): per sample the input
        guard on the whole state (as the exported ``evstab_step``), then the step after it on the inputs it passed,
        ``S`` the schedule's rows at the guarded speed."""
        if self._chunk is None:
            d = self.design
            guard = traced_guard(d)
            nofix, fix = traced_steps(d)
            switch = ca.Function.conditional("ecu_switch", [nofix], fix)
            nz, nu, ns, nc = (nofix.size1_in(i) for i in range(4))
            z, u, s, c = ca.MX.sym("z", nz), ca.MX.sym("u", nu), ca.MX.sym("s", ns), ca.MX.sym("c", nc)
            zg, uc = guard(z, u, c)
            zn, y = switch(ca.if_else(uc[INPUTS.index("gps_valid")] > 0.5, 1, 0), zg, uc, s, c)
            step = ca.Function("ecu_step", [z, u, s, c], [zn, y])
            acc = step.mapaccum("ecu_acc", CHUNK)
            z0, U, S = ca.MX.sym("z0", nz), ca.MX.sym("U", nu, CHUNK), ca.MX.sym("S", ns, CHUNK)
            C = ca.MX.sym("c", nc)
            Z, Y = acc(z0, U, S, ca.repmat(C, 1, CHUNK))
            self._chunk = ca.Function("ecu_chunk", [z0, U, S, C], [Z[:, -1], Y])
        return self._chunk

    def run(self, U: np.ndarray, z0: np.ndarray | None = None) -> np.ndarray:
        """``U`` is (N, len(INPUTS)); returns Y (N, len(OUTPUTS)) from ``z0`` (default: the initial state)."""
        d = self.design
        n, ny = U.shape[0], OUTPUTS.size
        z = d.initial_state() if z0 is None else np.array(z0, float)
        ifix, ispeed = INPUTS.index("gps_valid"), INPUTS.index("speed")
        ig = d.layout.index("guard")
        if self.backend == "numpy":
            Y = np.empty((n, ny))
            for k in range(n):
                zg, uc = ecu_guard(d, z, U[k], NUMPY)
                z = np.concatenate([z[:ig], zg])
                z, Y[k] = ecu_core(d, z, uc, d.schedule_inputs(uc[ispeed]), NUMPY, with_course=bool(uc[ifix] > 0.5))
            return Y
        # the guarded speed first (the schedule's tables are read at it), then the step with its guard per sample
        speed = run_chunks(z[ig:], [U], 1, CHUNK, c_fn=self._gc if self.backend == "c" else None,
                           casadi_fn=self.guard_chunk_fn, constants=[self.cal])
        S = d.schedule_inputs(speed[:, 0])
        return run_chunks(z, [np.ascontiguousarray(U, dtype=float), S], ny, CHUNK,
                          c_fn=self._c if self.backend == "c" else None, casadi_fn=self.chunk_fn, constants=[self.cal],
                          fix_column=ifix)


def for_log_periods(d: EcuDesign, U: np.ndarray) -> EcuDesign:
    """``d`` for a replay of the ECU inputs ``U``: its input guard's band on the period (``GuardSettings.dt_band``)
    lifted when the log's median period lies outside it (a log recorded at another rate than the design's
    period runs with the periods it has, up to ``dt_max``, as the step took them before the band), else ``d``.
    The exported C keeps the design's band: on such a log it uses its nominal period."""
    band = d.guard.dt_band
    if band is None or len(U) == 0:
        return d
    T = d.filter.dt_nominal
    median = float(np.median(INPUTS.columns(U)["dt"]))
    if (1.0 - band) * T <= median <= (1.0 + band) * T:
        return d
    return dataclasses.replace(d, guard=dataclasses.replace(d.guard, dt_band=None))


@lru_cache(maxsize=16)
def ecu_program(d: EcuDesign, backend: str = "auto") -> EcuProgram:
    return EcuProgram(d, backend)


def replay(d: EcuDesign, log, mu: float | None = None, backend: str = "auto") -> dict:
    """Run the ECU over a drive log; returns ``t`` and the :data:`OUTPUTS` columns."""
    mu = d.controller.params.mu if mu is None else mu
    U = ecu_inputs(log, mu, d.filter.dt_nominal, d.wheel_radius)
    Y = ecu_program(for_log_periods(d, U), backend).run(U)
    cols = log.columns if hasattr(log, "columns") else log
    out = {"t": np.asarray(cols["t"], float)}
    out.update(OUTPUTS.columns(Y))
    return out
