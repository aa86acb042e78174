"""Lane kernels: a casadi SX step function rolled out over many cases at once, in C.

casadi's own code generator writes one scalar C statement per SX instruction and rolls a step
out with ``mapaccum``: one case per call, and every ``sin``/``atan`` a call into libm. This
module writes the same instruction list as C on GCC vector types of :data:`WIDTH` lanes, so one
instruction advances ``WIDTH`` cases (structure-of-arrays: lane ``l`` of every variable belongs to
case ``c0 + l``), and the time loop is in C too (:func:`rollout_source`). A sweep is then one call
per block of cases and manoeuvre length instead of one call per case and chunk.

Arithmetic (``+ - * /``, ``sqrt``, comparisons, ``fmin``/``fmax``, ``if_else``) is IEEE
elementwise, so a lane computes exactly what a scalar evaluation of the same instruction list
computes, whatever its neighbours hold and whatever the vector width the compiler chooses: the
library is built without contraction (``-ffp-contract=off``) or fast-math. ``sin``, ``cos``,
``atan``, ``exp`` and ``tanh`` are branch-free vector versions (:mod:`toolkit.kernels.lane_math`) of the
Cephes library's algorithms (S. L. Moshier, *Methods and Programs for Mathematical Functions*, 1989; the coefficients of
netlib's ``cephes/double``): range reduction, then a polynomial or rational approximation,
with lanes outside the reduction's range (``|x| > 2^30`` for ``sin``/``cos``, ``exp`` beyond
+-708) handed to libm. They agree with glibc to a few units in the last place
(``tests/toolkit/test_lanes.py`` measures it), which is the only difference between a lane kernel
and casadi's generated C of the same function. Every other operation runs lane by lane through
libm.
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
import subprocess
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from evstab.plants.backend import LANE_INTRINSICS
from evstab.plants.errors import CompileError, DataError

from .compiled import compile_source, compiler, shared
from .lane_math import BINARY, UNARY, math_c

WIDTH = 4
"""Lanes per vector where nothing better is known (and of the tuning's large forward-mode kernel):
two SSE2 registers or one AVX2 register of doubles; the compiler splits a vector into the widest
registers the machine has."""

WIDE = 8
"""Lanes per vector of a loop kernel where ``-march=native`` has AVX-512 (:func:`native_width`)."""

NARROW = 2
"""Lanes per vector of the loop kernel that rolls out one or two cases (a single closed-loop run, a
run continued block by block) where :func:`native_width` is wider. A vector's step costs about as
much with one case in it as with all of them, and a narrow one about half a wide one, with the same
results bit for bit: two lanes hold two cases for the price of one (measured: docs/internals.md, compiled kernels)."""

CFLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fno-math-errno")
"""No fused multiply-add and no fast-math: every lane's arithmetic is IEEE, as in a scalar
evaluation. ``-fno-math-errno`` only lets ``sqrt`` and ``floor`` vectorise (errno is never read)."""


def kernel_flags(width: int) -> tuple[str, ...]:
    """The compiler flags of a loop kernel of ``width`` lanes: :data:`CFLAGS`, at ``-O2`` for
    :data:`WIDE` kernels, which ``-O3`` makes no faster and compiles more slowly (measured: docs/internals.md, compiled kernels); the same
    IEEE arithmetic either way."""
    return (("-O2",) + CFLAGS[1:]) if width >= WIDE else CFLAGS


@functools.lru_cache(maxsize=None)
def native_width() -> int:
    """The lanes per vector of a loop kernel on this machine: :data:`WIDE` where the C compiler's
    ``-march=native`` target has AVX-512F, else :data:`WIDTH`.

    A loop step is one long chain of dependent operations, so a vector's step waits on latencies
    more than on arithmetic. Eight lanes fill one AVX-512 register, and its 32 registers hold the
    step's working values: the two-track and multi-body loops run faster per case at 8 lanes than at 4,
    bit for bit the same results. Without AVX-512 the same 8 lanes are two AVX2 registers, the 16 of
    them spill, and the step is slower than at 4. The tuning's forward-mode kernel, seven times the
    values per step, stays at :data:`WIDTH` (measured: docs/internals.md, compiled kernels)."""
    cc = compiler()
    if cc is None:
        return WIDTH
    try:
        res = subprocess.run([cc, "-march=native", "-dM", "-E", "-x", "c", os.devnull], capture_output=True,
                             text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return WIDTH
    return WIDE if res.returncode == 0 and "__AVX512F__" in res.stdout else WIDTH


def _op_name(op: int) -> str:
    return next((n for n in dir(ca) if n.startswith("OP_") and getattr(ca, n) == op), str(op))


@dataclass(frozen=True)
class Roles:
    """What each input and output of a step function ``f(z, ...) -> (z_next, ...)`` is in a rollout:
    input 0 and output 0 are the carried state; ``stepped`` inputs have one row per sample, the
    other inputs one row per case; every output after the first is stored per sample."""

    stepped: tuple[int, ...]


_CALL_OUT = -1
"""Pseudo op of the SSA form: element ``src[0]`` of a call node's outputs."""


@dataclass
class _Node:
    op: int
    args: tuple = ()
    value: float = 0.0  # OP_CONST
    src: tuple = ()  # OP_INPUT: (input, element); OP_CALL: (intrinsic name, outputs); _CALL_OUT: (index,)
    invariant: bool = False


def _nodes(fn: ca.Function, const_inputs: set[int]):
    """The instruction list in SSA form: nodes (each computed once) and the outputs as
    (output, element, node). casadi reuses work-vector slots; here every value gets its own name."""
    nodes: list[_Node] = []
    slot: dict[int, int] = {}
    outputs = []
    sx = None
    for k in range(fn.n_instructions()):
        op = fn.instruction_id(k)
        o = fn.instruction_output(k)
        i = fn.instruction_input(k)
        if op == ca.OP_OUTPUT:
            outputs.append((o[0], o[1], slot[i[0]]))
            continue
        if op == ca.OP_CALL:
            sx = fn.instructions_sx() if sx is None else sx
            callee = sx[k].which_function()
            if callee.name() not in LANE_INTRINSICS:
                raise CompileError(f"{fn.name()}: it calls '{callee.name()}', which has no lane-kernel form")
            if callee.n_in() != 1 or callee.n_out() != 1 or callee.nnz_in(0) != len(i) or callee.nnz_out(0) != len(o):
                raise CompileError(f"{fn.name()}: call of '{callee.name()}' must take and return one dense vector")
            call = _Node(op, tuple(slot[a] for a in i), src=(callee.name(), len(o)))
            call.invariant = all(nodes[a].invariant for a in call.args)
            nodes.append(call)
            c = len(nodes) - 1
            for e, w in enumerate(o):
                if w >= 0:
                    nodes.append(_Node(_CALL_OUT, (c,), src=(e,), invariant=call.invariant))
                    slot[w] = len(nodes) - 1
            continue
        if op == ca.OP_CONST:
            node = _Node(op, value=float(fn.instruction_constant(k)), invariant=True)
        elif op == ca.OP_INPUT:
            node = _Node(op, src=(i[0], i[1]), invariant=i[0] in const_inputs)
        elif op in UNARY:
            node = _Node(op, (slot[i[0]],))
        elif op in BINARY:
            node = _Node(op, (slot[i[0]], slot[i[1]]))
        else:
            raise CompileError(f"{fn.name()}: operation {_op_name(op)} has no lane-kernel form")
        if node.args:
            node.invariant = all(nodes[a].invariant for a in node.args)
        nodes.append(node)
        slot[o[0]] = len(nodes) - 1
    return nodes, outputs


LATENCY = {ca.OP_DIV: 13.0, ca.OP_SQRT: 15.0, ca.OP_SIN: 40.0, ca.OP_COS: 40.0, ca.OP_TANH: 40.0,
           ca.OP_EXP: 30.0, ca.OP_ATAN2: 60.0, ca.OP_CALL: 40.0}
"""Rough latencies [cycles] of the operations slower than the 3 of an add or a product (a vector
division or square root; the vector math and the call intrinsics as tens of operations in a chain),
by which :func:`_schedule` orders a step."""


def _schedule(nodes: list[_Node], window: int | None = None) -> list[int]:
    """The order to write a step's nodes in: by the latency (:data:`LATENCY`, 3 for the others) of
    the longest chain of operations that leads to each from the step's inputs, ties in casadi's
    order; with ``window``, within each run of that many nodes of casadi's list, one run after
    another. Every node follows what it reads, and what the per-case inputs alone determine comes
    first, in casadi's order (the hoisted part).

    casadi writes an instruction list in the order the expressions were built: one wheel's tyre
    after another, RK4's stages one after another, so that neighbouring instructions mostly wait on
    each other. A loop step is thousands of instructions, more than a processor's out-of-order window
    looks ahead, so it finds the independent work only if it is written close together. Ordered by
    chain length, the work that can start together is written together, and the loop kernels run
    faster with the same bits (``tests/toolkit/test_lanes.py``). A kernel much larger than the
    registers can hold needs the window: the tuning's forward-mode step, reordered over the whole step,
    keeps its values alive long enough to spill, and is faster reordered within windows
    (:data:`toolkit.design.rollout.FORWARD_WINDOW`). The loop's kernels keep the whole step (measured: docs/internals.md, compiled kernels)."""
    depth = [0.0] * len(nodes)
    for n, node in enumerate(nodes):
        if node.invariant or node.op in (ca.OP_INPUT, ca.OP_CONST):
            continue
        d = max((depth[a] for a in node.args), default=0.0)
        depth[n] = d if node.op == _CALL_OUT else d + LATENCY.get(node.op, 3.0)  # a call's outputs: its time
    w = window or len(nodes)
    return sorted(range(len(nodes)), key=lambda n: (-1, 0.0, n) if nodes[n].invariant else (n // w, depth[n], n))


def _strength_reduce(nodes: list[_Node]) -> list[_Node]:
    """``a / d`` with ``d`` the same in every sample (a constant, or a function of the per-case
    inputs alone) becomes ``a * (1 / d)``, the reciprocal computed once per block of cases: a
    division costs 4-16 times a product. Exact when ``d`` is a power of two; otherwise the two
    differ by at most one unit in the last place."""
    out = list(nodes)
    recip: dict[int, int] = {}
    for n in range(len(nodes)):
        node = out[n]
        if node.op == ca.OP_DIV and not node.invariant and out[node.args[1]].invariant:
            d = node.args[1]
            if d not in recip:
                if out[d].op == ca.OP_CONST:
                    v = out[d].value
                    if v == 0.0 or not np.isfinite(v) or not np.isfinite(1.0 / v):
                        continue
                    out.append(_Node(ca.OP_CONST, value=1.0 / v, invariant=True))
                else:
                    out.append(_Node(ca.OP_INV, (d,), invariant=True))
                recip[d] = len(out) - 1
            out[n] = _Node(ca.OP_MUL, (node.args[0], recip[d]))
    return out


def _expr(nodes: list[_Node], n: int, name, sincos: dict) -> str:
    node = nodes[n]
    if node.op == ca.OP_CONST:
        v = node.value
        lit = repr(v) if np.isfinite(v) else ("NAN" if np.isnan(v) else ("INFINITY" if v > 0 else "-INFINITY"))
        return f"ev_splat({lit})"
    if n in sincos:
        return sincos[n]
    if node.op == _CALL_OUT:
        return f"{name(node.args[0])}[{node.src[0]}]"
    args = [name(a) for a in node.args]
    if node.op in UNARY:
        return UNARY[node.op].format(a=args[0])
    return BINARY[node.op].format(a=args[0], b=args[1])


def rollout_source(fn: ca.Function, fname: str, roles: Roles, width: int = WIDTH, schedule: bool = True,
                   window: int | None = None) -> str:
    """C source of ``int fname(long n_steps, long n_cases, const double* z0, const double* const* in,
    double* z_end, double* const* out, const long* st)``: ``n_steps`` samples of ``fn`` for ``n_cases`` cases.

    Layouts (float64): ``z0``/``z_end`` (cases, nz), C order; ``in[i]`` for input ``i >= 1``:
    (cases, n_steps, n_i) if stepped else (cases, n_i) (``in[0]`` unused), a stepped input with any
    strides, ``st[3 i]``, ``st[3 i + 1]`` and ``st[3 i + 2]`` (in doubles) along its three axes, so that
    its samples may lie signal by signal as well as sample by sample; ``out[j]`` for output
    ``j >= 1``: (cases, n_steps, m_j), or NULL (not stored). Cases go through in blocks of ``width`` lanes; a last, partial
    block repeats its last case in the spare lanes and stores only the real ones.

    What the per-case inputs alone determine is computed once per block, before the time loop,
    and divisions by it become products (:func:`_strength_reduce`); repeated subexpressions are
    computed once (:func:`toolkit.kernels.compiled.shared`); ``sin`` and ``cos`` of one argument share their
    range reduction. The step's instructions are written in the order of :func:`_schedule` (with
    ``window``; ``schedule=False``: casadi's), which changes the speed and not the bits.
    """
    if not fn.is_a("SXFunction"):
        raise CompileError(f"{fn.name()}: a lane kernel needs an SX function")
    n_in, n_out = fn.n_in(), fn.n_out()
    for i in range(n_in):
        if not fn.sparsity_in(i).is_dense() or fn.size2_in(i) != 1:
            raise CompileError(f"{fn.name()}: input {i} must be a dense column vector")
    for j in range(n_out):
        if not fn.sparsity_out(j).is_dense() or fn.size2_out(j) != 1:
            raise CompileError(f"{fn.name()}: output {j} must be a dense column vector")
    if fn.nnz_in(0) != fn.nnz_out(0):
        raise CompileError(f"{fn.name()}: the state (input 0, output 0) must keep its size")
    nz = fn.nnz_in(0)
    fn = shared(fn)
    stepped = set(roles.stepped)
    consts = [i for i in range(1, n_in) if i not in stepped]
    nodes, outputs = _nodes(fn, set(consts))
    nodes = _strength_reduce(nodes)

    def name(n):
        return f"h{n}" if nodes[n].invariant else f"v{n}"

    # sin and cos of the same value: one range reduction
    sincos: dict[int, str] = {}
    trig: dict[tuple[int, int], int] = {}
    for n, node in enumerate(nodes):
        if node.op in (ca.OP_SIN, ca.OP_COS):
            trig[(node.op, node.args[0])] = n
    pairs = []
    for (op, a), n in trig.items():
        if op == ca.OP_SIN and (ca.OP_COS, a) in trig and not nodes[n].invariant:
            m = trig[(ca.OP_COS, a)]
            pairs.append((min(n, m), n, m, a))
    pair_at = {}
    for first, ns, nc, a in pairs:
        sincos[ns], sincos[nc] = f"sc{first}.s", f"sc{first}.c"
        pair_at[first] = f"ev_sc sc{first} = ev_sincos2({name(a)});"

    order = _schedule(nodes, window) if schedule else list(range(len(nodes)))
    at = {n: i for i, n in enumerate(order)}
    pair_first = {min(ns, nc, key=at.__getitem__): first for first, ns, nc, _ in pairs}  # where a pair is written

    hoisted, body, used = [], [], set()
    for n in order:
        node = nodes[n]
        if node.op == ca.OP_INPUT:
            src, el = node.src
            if src == 0:
                body.append(f"const vd v{n} = zs[{el}];")
            elif src in stepped:
                body.append(f"vd v{n}; for (int l = 0; l < EV_W; l++) v{n}[l] = rp{src}[l][{el} * es{src}];")
            else:
                hoisted.append(f"const vd h{n} = c{src}[{el}];")
            continue
        if n in pair_first:
            body.append(pair_at[pair_first[n]])
        if node.op == ca.OP_CALL:
            ins = ", ".join(name(a) for a in node.args)
            line = f"vd {name(n)}[{node.src[1]}]; {node.src[0]}((const vd[]){{{ins}}}, {name(n)});"
            (hoisted if node.invariant else body).append(line)
            used.add(node.src[0])
            continue
        line = f"const vd {name(n)} = {_expr(nodes, n, name, sincos)};"
        (hoisted if node.invariant else body).append(line)
    stores: dict[int, dict[int, str]] = {}  # output -> element -> its value's name
    for dst, el, n in outputs:
        if dst == 0:  # after every read of the state: written over it (an element that stays as read is not)
            if not (nodes[n].op == ca.OP_INPUT and nodes[n].src == (0, el)):
                body.append(f"zs[{el}] = {name(n)};")
        else:
            stores.setdefault(dst, {})[el] = name(n)
    for dst in sorted(stores):  # an output passed as NULL is not stored
        # the sample's vectors side by side, then each case's row of them: one loop over the cases,
        # not one per element (faster: docs/internals.md, compiled kernels)
        m = fn.nnz_out(dst)
        vals = ", ".join(stores[dst][el] for el in range(m))  # dense outputs: every element is there
        body.append(f"if (out[{dst}]) {{")
        body.append(f"  const vd ob[{m}] = {{{vals}}};")
        body.append(f"  for (int l = 0; l < n_act; l++) for (int e = 0; e < {m}; e++) wp{dst}[l][e] = ob[e][l];")
        body.append("}")

    lines = [math_c(width), *(LANE_INTRINSICS[u] for u in sorted(used)),
             f"int {fname}(long n_steps, long n_cases, const double* z0, const double* const* in, double* z_end, "
             f"double* const* out, const long* st) {{",
             *(f"  const long cs{i} = st[{3 * i}], ks{i} = st[{3 * i + 1}], es{i} = st[{3 * i + 2}];"
               for i in sorted(stepped)),
             "  for (long c0 = 0; c0 < n_cases; c0 += EV_W) {",
             "    int n_act = (int)(n_cases - c0 < EV_W ? n_cases - c0 : EV_W);",
             "    long cs[EV_W];",
             "    for (int l = 0; l < EV_W; l++) cs[l] = c0 + (l < n_act ? l : n_act - 1);",
             f"    vd zs[{max(nz, 1)}];",
             f"    for (int e = 0; e < {nz}; e++) for (int l = 0; l < EV_W; l++) zs[e][l] = z0[cs[l] * {nz} + e];"]
    for c in consts:
        m = fn.nnz_in(c)
        lines.append(f"    vd c{c}[{max(m, 1)}];")
        lines.append(f"    for (int e = 0; e < {m}; e++) for (int l = 0; l < EV_W; l++) "
                     f"c{c}[e][l] = in[{c}][cs[l] * {m} + e];")
    lines.extend("    " + h for h in hoisted)
    lines.append("    for (long k = 0; k < n_steps; k++) {")
    for st in sorted(stepped):
        lines.append(f"      const double* rp{st}[EV_W];")
        lines.append(f"      for (int l = 0; l < EV_W; l++) rp{st}[l] = in[{st}] + cs[l] * cs{st} + k * ks{st};")
    for j in range(1, n_out):
        m = fn.nnz_out(j)
        lines.append(f"      double* wp{j}[EV_W];")
        lines.append(f"      if (out[{j}]) for (int l = 0; l < EV_W; l++) wp{j}[l] = out[{j}] + (cs[l] * n_steps + k) * {m};")
    lines.extend("      " + b for b in body)
    lines.append("    }")
    lines.append(f"    for (int e = 0; e < {nz}; e++) for (int l = 0; l < n_act; l++) "
                 f"z_end[(c0 + l) * {nz} + e] = zs[e][l];")
    lines.append("  }")
    lines.append("  return 0;")
    lines.append("}")
    return "\n".join(lines) + "\n"


def math_source(width: int = WIDTH) -> str:
    """C source of the vector math functions alone, with ``void ev_math_NAME(long n, const double* x,
    double* y)`` wrappers (``NAME`` sin, cos, atan, exp, tanh) for testing them against libm."""
    out = [math_c(width)]
    for f in ("sin", "cos", "atan", "exp", "tanh"):
        out.append(f"void ev_math_{f}(long n, const double* x, double* y) {{\n"
                   f"  for (long i = 0; i < n; i += EV_W) {{\n"
                   f"    vd a; for (int l = 0; l < EV_W; l++) a[l] = x[i + l < n ? i + l : n - 1];\n"
                   f"    vd r = ev_{f}(a);\n"
                   f"    for (int l = 0; l < EV_W && i + l < n; l++) y[i + l] = r[l];\n  }}\n}}")
    out.append("void ev_math_atan2(long n, const double* y, const double* x, double* z) {\n"
               "  for (long i = 0; i < n; i += EV_W) {\n"
               "    vd a, b; for (int l = 0; l < EV_W; l++) { a[l] = y[i + l < n ? i + l : n - 1]; "
               "b[l] = x[i + l < n ? i + l : n - 1]; }\n"
               "    vd r = ev_atan2(a, b);\n"
               "    for (int l = 0; l < EV_W && i + l < n; l++) z[i + l] = r[l];\n  }\n}")
    return "\n".join(out) + "\n"


def machine_tag() -> str:
    """What ``-march=native`` compiles for: part of a lane library's cache key (a cache shared
    between machines must not hand one the other's instructions)."""
    flags = ""
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((ln for ln in f if ln.startswith(("flags", "Features"))), "")
    except OSError:
        pass
    return f"{platform.machine()}|{flags.strip()}"


class LaneRollout:
    """A compiled lane kernel of a step function (see :func:`rollout_source`), called on numpy arrays."""

    def __init__(self, lib_path: Path, name: str, fn: ca.Function, roles: Roles, width: int = WIDTH):
        self._lib = ctypes.CDLL(str(lib_path))
        self.width = width
        """Lanes per vector (the cases one instruction advances)."""
        self._f = getattr(self._lib, name)
        self._f.restype = ctypes.c_int
        self._f.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                            ctypes.c_void_p, ctypes.c_void_p]
        self.n_in, self.n_out = fn.n_in(), fn.n_out()
        self.sizes_in = [fn.nnz_in(i) for i in range(self.n_in)]
        self.sizes_out = [fn.nnz_out(j) for j in range(self.n_out)]
        self.stepped = set(roles.stepped)

    def __call__(self, z0: np.ndarray, inputs: list, n_steps: int, outputs: list | None = None,
                 keep: tuple[int, ...] | None = None):
        """``z0`` (cases, nz); ``inputs`` for inputs 1.. (stepped: (cases, n_steps, n_i), else (cases, n_i));
        returns (z_end, [outputs 1..] as (cases, n_steps, m_j)), written into ``outputs`` when given.
        ``keep``: the outputs (numbered from 1) to store; the others come back as None.

        A stepped input is read where it lies, whatever its strides (a float64 array, aligned, with
        strides >= 0): say the transposed view of a (cases, n_i, n_steps) array, each signal's samples
        side by side, which is faster to fill signal by signal and no slower to read. Others are copied
        to C order first."""
        z0 = np.ascontiguousarray(z0, dtype=float)
        n_cases = z0.shape[0]
        if z0.shape != (n_cases, self.sizes_in[0]):
            raise DataError(f"lane rollout: z0 must be (cases, {self.sizes_in[0]}), got {z0.shape}")
        arrs: list = [None]
        strides = np.zeros(3 * self.n_in, dtype=np.int64)
        for i, a in enumerate(inputs, start=1):
            a = np.asarray(a, dtype=float)
            if i not in self.stepped or not (a.flags.aligned and all(s >= 0 and s % 8 == 0 for s in a.strides)):
                a = np.ascontiguousarray(a)
            if i in self.stepped and a.ndim == 3:
                strides[3 * i:3 * i + 3] = [s // 8 for s in a.strides]
            want = (n_cases, n_steps, self.sizes_in[i]) if i in self.stepped else (n_cases, self.sizes_in[i])
            if a.shape != want:
                raise DataError(f"lane rollout: input {i} must be {want}, got {a.shape}")
            arrs.append(a)
        if outputs is None:
            outputs = [np.empty((n_cases, n_steps, m)) if keep is None or j in keep else None
                       for j, m in enumerate(self.sizes_out[1:], start=1)]
        for j, a in enumerate(outputs, start=1):
            if a is None:
                continue
            if a.shape != (n_cases, n_steps, self.sizes_out[j]) or not a.flags.c_contiguous or a.dtype != float:
                raise DataError(f"lane rollout: output {j} must be a C-ordered float64 "
                                 f"{(n_cases, n_steps, self.sizes_out[j])} array")
        z_end = np.empty_like(z0)
        in_ptrs = (ctypes.c_void_p * self.n_in)(None, *[a.ctypes.data for a in arrs[1:]])
        out_ptrs = (ctypes.c_void_p * self.n_out)(None, *[None if a is None else a.ctypes.data for a in outputs])
        if n_cases and n_steps >= 0:
            if self._f(n_steps, n_cases, z0.ctypes.data, in_ptrs, z_end.ctypes.data, out_ptrs,
                       strides.ctypes.data) != 0:
                raise CompileError("lane rollout reported an error")
        else:
            z_end[:] = z0
        return z_end, outputs


def compile_rollout(fn, key: str, roles: Roles, name: str = "ev_rollout",
                    flags: tuple[str, ...] = CFLAGS, width: int = WIDTH,
                    window: int | None = None) -> LaneRollout | None:
    """The lane kernel of ``fn`` (a casadi SX function, or a callable returning one) from the compiled
    cache, built when missing (with ``flags``: :data:`CFLAGS` or others that keep its arithmetic IEEE;
    ``width`` lanes per vector, which ``key`` must name; ``window``: :func:`_schedule`'s, which ``key``
    must name where it varies); None without a C compiler or when the compiler fails."""
    if compiler() is None:
        return None
    fn = fn() if callable(fn) and not isinstance(fn, ca.Function) else fn
    lib = compile_source(lambda path: path.write_text(rollout_source(fn, name, roles, width, window=window)), key,
                         flags, "casadi's generated C")
    if lib is None:
        return None
    return LaneRollout(lib, name, fn, roles, width)
