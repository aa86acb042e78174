"""The firmware's C printer (:mod:`toolkit.firmware.cgen`) and the exported step's in-place state
writes (:func:`toolkit.firmware.csource.state_writes`), against casadi's own evaluation of the
same SX functions, bit for bit (float64, ``-std=c99 -O2``: no contraction, no reassociation)."""

import ctypes
import ctypes.util
import itertools
import math
import subprocess

import casadi as ca
import numpy as np
import pytest

from evstab.toolkit.kernels.compiled import compiler
from evstab.toolkit.firmware.cgen import Precision, emit_body
from evstab.toolkit.firmware.csource import state_targets, state_writes

CC = compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]


def _library(tmp_path, fn: ca.Function, in_place: bool):
    """``void step(double *z, const double *u, double *y)``: ``fn(z, u) -> (z_next, y)`` printed by
    :func:`emit_body`, the next state written over ``z`` (``in_place``, by :func:`state_writes`) or into
    ``y`` after the outputs."""
    p = Precision("float64")
    ny = fn.nnz_out(1)
    if in_place:
        target, declare, finish = state_targets(fn, "z", "double")
    else:
        target, declare, finish = (lambda k: f"y[{ny + k}]"), [], []
    body = emit_body(fn, [lambda k: f"z[{k}]", lambda k: f"u[{k}]"], [target, lambda k: f"y[{k}]"], p)
    src = ["#include <math.h>", "void step(double *z, const double *u, double *y);",
           "void step(double *z, const double *u, double *y)", "{", "    (void)z; (void)u; (void)y;"]
    src += ["    " + line for line in declare] + body + ["    " + line for line in finish] + ["}"]
    c, lib = tmp_path / f"{fn.name()}.c", tmp_path / f"{fn.name()}.so"
    c.write_text("\n".join(src) + "\n")
    subprocess.run([CC, *STRICT, "-shared", "-fPIC", "-o", str(lib), str(c), "-lm"], check=True, capture_output=True)
    f = ctypes.CDLL(str(lib)).step
    f.restype = None
    f.argtypes = [np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")] * 3
    return f


def _bits(a) -> list[int]:
    """The IEEE bit patterns (NaNs as one pattern: casadi and C may carry different payloads)."""
    a = a.full() if hasattr(a, "full") else a  # a casadi DM: its numbers (numpy on a DM is deprecated)
    return [0x7FF8000000000000 if math.isnan(v) else int(np.float64(v).view(np.int64)) for v in np.ravel(a)]


@needs_cc
def test_fmin_and_fmax_print_as_the_c_library_evaluates_them(tmp_path):
    """NaN on either side, both, signed zeros and ties: the printed select returns what the C
    library's ``fmin``/``fmax`` return (the other operand when one is NaN), to the bit, zero signs
    included. The C library is the reference because the replay's casadi-generated C calls it;
    casadi's own virtual machine returns the first operand of a tie of signed zeros instead."""
    a, b = ca.SX.sym("a"), ca.SX.sym("b")
    z = ca.SX.sym("z", 1)
    fn = ca.Function("minmax", [z, ca.vertcat(a, b)],
                     [z, ca.vertcat(ca.fmin(a, b), ca.fmax(a, b), ca.fmin(b, a), ca.fmax(b, a))])
    step = _library(tmp_path, fn, in_place=False)
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    for name in ("fmin", "fmax"):
        getattr(libm, name).restype = ctypes.c_double
        getattr(libm, name).argtypes = [ctypes.c_double, ctypes.c_double]
    values = [math.nan, -0.0, 0.0, 1.0, -1.0, 2.5, math.inf, -math.inf]
    for x, w in itertools.product(values, repeat=2):
        y = np.zeros(5)
        step(np.zeros(1), np.array([x, w]), y)
        want = [libm.fmin(x, w), libm.fmax(x, w), libm.fmin(w, x), libm.fmax(w, x)]
        assert _bits(y[:4]) == _bits(want), (x, w, y[:4], want)


def test_state_writes_sort_the_next_state_by_when_it_may_be_written():
    """``z_next = (2 z1, z0 + z1, z2)``: element 0 is known before ``z0`` is read (kept back), element 1
    after its last read (in place), element 2 is ``z2`` itself (not written)."""
    z, u = ca.SX.sym("z", 3), ca.SX.sym("u", 1)
    fn = ca.Function("f", [z, u], [ca.vertcat(2.0 * z[1], z[0] + z[1], z[2]), z[0] * u])
    assert state_writes(fn) == {0: "defer", 1: "in place", 2: "skip"}


@needs_cc
def test_a_step_writing_its_state_in_place_equals_casadi(tmp_path):
    """A step whose next state is read again after it is known (the deferred case), over 50 steps of
    random inputs (seeded): state and outputs equal casadi's evaluation to the bit."""
    z, u = ca.SX.sym("z", 4), ca.SX.sym("u", 2)
    zn = ca.vertcat(0.9 * z[1] + u[0], z[0] - 0.1 * z[1] * z[2], z[2], ca.fmax(z[3], z[0] * u[1]))
    fn = ca.Function("g", [z, u], [zn, ca.vertcat(z[0] + z[3], ca.sin(z[1]) * u[1])])
    kinds = state_writes(fn)
    assert "defer" in kinds.values() and "in place" in kinds.values() and "skip" in kinds.values()
    step = _library(tmp_path, fn, in_place=True)
    rng = np.random.default_rng(5)
    zc, zk = np.array([0.3, -0.2, 1.5, 0.0]), ca.DM([0.3, -0.2, 1.5, 0.0])
    for _ in range(50):
        uk = rng.normal(size=2)
        y = np.zeros(2)
        step(zc, uk, y)
        zk, yk = fn(zk, uk)
        assert _bits(zc) == _bits(zk) and _bits(y) == _bits(yk)
