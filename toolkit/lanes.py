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
``atan``, ``exp`` and ``tanh`` are branch-free vector versions of the Cephes library's algorithms
(S. L. Moshier, *Methods and Programs for Mathematical Functions*, 1989; the coefficients of
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

WIDTH = 4
"""Lanes per vector where nothing better is known (and of the tuning's large forward-mode kernel):
two SSE2 registers or one AVX2 register of doubles; the compiler splits a vector into the widest
registers the machine has."""

WIDE = 8
"""Lanes per vector of a loop kernel where ``-march=native`` has AVX-512 (:func:`native_width`)."""

CFLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fno-math-errno")
"""No fused multiply-add and no fast-math: every lane's arithmetic is IEEE, as in a scalar
evaluation. ``-fno-math-errno`` only lets ``sqrt`` and ``floor`` vectorise (errno is never read)."""


def kernel_flags(width: int) -> tuple[str, ...]:
    """The compiler flags of a loop kernel of ``width`` lanes: :data:`CFLAGS`, at ``-O2`` for
    :data:`WIDE` kernels, which ``-O3`` makes no faster and compiles more slowly (the micro-ev's
    two-track loop: 469 against 475 ns per case and step, 3.8 against 6.6 s to compile; the
    multi-body car's 1.75 against 1.81 us, 17.4 against 17.7 s); the same IEEE arithmetic either way."""
    return (("-O2",) + CFLAGS[1:]) if width >= WIDE else CFLAGS


@functools.lru_cache(maxsize=None)
def native_width() -> int:
    """The lanes per vector of a loop kernel on this machine: :data:`WIDE` where the C compiler's
    ``-march=native`` target has AVX-512F, else :data:`WIDTH`.

    A loop step is one long chain of dependent operations, so a vector's step waits on latencies
    more than on arithmetic. Eight lanes fill one AVX-512 register, and its 32 registers hold the
    step's working values: on a 2-core AMD EPYC (Zen 4), a two-track loop step took 449 ns per case
    at 8 lanes against 687 ns at 4 and the multi-body car's 1.47 against 2.61 us, bit for bit the
    same results (the bicycle's, short enough for 4 lanes, 207 against 197 ns). Without AVX-512 the same 8 lanes are two AVX2
    registers, the 16 of them spill, and the two-track step took 1.55 us per case against 0.78 at 4
    lanes (the same machine, ``-mno-avx512f``). The tuning's forward-mode kernel, seven times the
    values per step, stays at :data:`WIDTH` (18.1 against 15.9 ms per run at 8 lanes)."""
    from .compiled import compiler
    cc = compiler()
    if cc is None:
        return WIDTH
    try:
        res = subprocess.run([cc, "-march=native", "-dM", "-E", "-x", "c", os.devnull], capture_output=True,
                             text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return WIDTH
    return WIDE if res.returncode == 0 and "__AVX512F__" in res.stdout else WIDTH


MATH_C = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>
#define EV_W %(width)d
typedef double vd __attribute__((vector_size(EV_W * 8)));
typedef long long vl __attribute__((vector_size(EV_W * 8)));
#define EV_SIGN ((long long)0x8000000000000000ULL)
#define EV_ABS ((long long)0x7fffffffffffffffLL)

#define EV_INLINE static inline __attribute__((always_inline))
static inline vd ev_splat(double x) { vd r; for (int l = 0; l < EV_W; l++) r[l] = x; return r; }
static inline vd ev_and(vl m, vd a) { return (vd)(m & (vl)a); }
static inline vd ev_sel(vl m, vd a, vd b) { return (vd)((m & (vl)a) | (~m & (vl)b)); }
static inline vd ev_bool(vl m) { return ev_and(m, ev_splat(1.0)); }
static inline vd ev_fabs(vd a) { return (vd)((vl)a & EV_ABS); }
static inline vd ev_fmin(vd a, vd b) { return ev_sel((a < b) | (b != b), a, b); }
static inline vd ev_fmax(vd a, vd b) { return ev_sel((a > b) | (b != b), a, b); }
#define EV_LANES1(f, a) ({ vd _a = (a), _r; for (int _l = 0; _l < EV_W; _l++) _r[_l] = f(_a[_l]); _r; })
#define EV_LANES2(f, a, b) ({ vd _a = (a), _b = (b), _r; \
    for (int _l = 0; _l < EV_W; _l++) _r[_l] = f(_a[_l], _b[_l]); _r; })
static inline double ev_sign1(double x) { return x < 0 ? -1.0 : (x > 0 ? 1.0 : x); }
static inline vd ev_sqrt(vd a) { return EV_LANES1(sqrt, a); }
static inline vd ev_floor(vd a) {  /* exact; |a| >= 2^52 is integral already */
    vd t = __builtin_convertvector(__builtin_convertvector(a, vl), vd);
    t = t - ev_and(t > a, ev_splat(1.0));
    t = (vd)((vl)t | ((vl)a & EV_SIGN));
    return ev_sel(ev_fabs(a) < 4503599627370496.0, t, a);
}
static inline int ev_all(vl m) { long long a = -1; for (int l = 0; l < EV_W; l++) a &= m[l]; return a != 0; }
/* the lanes a vector path cannot take, through libm (out of line: rare) */
static __attribute__((noinline, cold)) vd ev_libm1(double (*f)(double), vd x, vd r, vl ok) {
    for (int l = 0; l < EV_W; l++)
        if (!ok[l]) r[l] = f(x[l]);
    return r;
}

/* Cephes atan: |x| reduced to [0, 0.66] by pi/2 - atan(1/x) above tan(3 pi/8) and
   pi/4 + atan((x-1)/(x+1)) above 0.66; x + x z P(z)/Q(z) with z = x^2. Out of line: as fast
   as inlined in the loop's kernel (measured), and the kernel compiles a fifth faster. */
static __attribute__((noinline)) vd ev_atan(vd x) {
    vl sgn = (vl)x & EV_SIGN;
    vd a = ev_fabs(x);
    vl big = a > 2.41421356237309504880;
    vl mid = (a > 0.66) & ~big;
    vd one = ev_splat(1.0);
    vd xr = ev_sel(big, -one, ev_sel(mid, a - 1.0, a)) / ev_sel(big, a, ev_sel(mid, a + 1.0, one));
    vd y0 = ev_sel(big, ev_splat(1.57079632679489661923), ev_and(mid, ev_splat(7.85398163397448309616E-1)));
    vd more = ev_sel(big, ev_splat(6.123233995736765886130E-17), ev_and(mid, ev_splat(0.5 * 6.123233995736765886130E-17)));
    vd z = xr * xr;
    vd p = (((-8.750608600031904122785E-1 * z - 1.615753718733365076637E1) * z - 7.500855792314704667340E1) * z
            - 1.228866684490136173410E2) * z - 6.485021904942025371773E1;
    vd q = ((((z + 2.485846490142306297962E1) * z + 1.650270098316988542046E2) * z + 4.328810604912902668951E2) * z
            + 4.853903996359136964868E2) * z + 1.945506571482613964425E2;
    z = z * p / q;
    z = xr * z + xr;
    z = ev_sel(big | mid, z + more, z);
    vd y = y0 + z;
    return (vd)((vl)y ^ sgn);
}

/* Cephes sin/cos: j = floor(|x| 4/pi) made even, z = |x| - j pi/4 in three parts
   (exact for |x| < 2^30), then the sine and cosine polynomials, chosen by octant. */
EV_INLINE vd ev_sin_poly(vd z, vd zz) {
    vd p = ((((1.58962301576546568060E-10 * zz - 2.50507477628578072866E-8) * zz + 2.75573136213857245213E-6) * zz
             - 1.98412698295895385996E-4) * zz + 8.33333333332211858878E-3) * zz - 1.66666666666666307295E-1;
    return z + z * (zz * p);
}
EV_INLINE vd ev_cos_poly(vd zz) {
    vd p = ((((-1.13585365213876817300E-11 * zz + 2.08757008419747316778E-9) * zz - 2.75573141792967388112E-7) * zz
             + 2.48015872888517045348E-5) * zz - 1.38888888888730564116E-3) * zz + 4.16666666666665929218E-2;
    return 1.0 - zz * 0.5 + zz * zz * p;
}
typedef struct { vd s, c; } ev_sc;
EV_INLINE ev_sc ev_sincos2(vd x) {
    vd a = ev_fabs(x);
    vl ok = a <= 1.073741824e9;
    vl j = __builtin_convertvector(ev_and(ok, a) * 1.27323954473516268615, vl);  /* floor: a >= 0 */
    vd y = __builtin_convertvector(j, vd);
    vl odd = j & 1;
    j = j + odd;
    y = y + __builtin_convertvector(odd, vd);
    j = j & 7;
    vl flip = j > 3;
    j = j - (flip & 4);
    vl ssgn = ((vl)x & EV_SIGN) ^ (flip & EV_SIGN);
    vl csgn = (flip & EV_SIGN) ^ ((j > 1) & EV_SIGN);
    vd z = ((a - y * 7.85398125648498535156E-1) - y * 3.77489470793079817668E-8) - y * 2.69515142907905952645E-15;
    vd zz = z * z;
    vd ps = ev_sin_poly(z, zz), pc = ev_cos_poly(zz);
    vl other = (j == 1) | (j == 2);
    ev_sc r;
    r.s = (vd)((vl)ev_sel(other, pc, ps) ^ ssgn);
    r.c = (vd)((vl)ev_sel(other, ps, pc) ^ csgn);
    if (__builtin_expect(!ev_all(ok), 0)) {
        r.s = ev_libm1(sin, x, r.s, ok);
        r.c = ev_libm1(cos, x, r.c, ok);
    }
    return r;
}
EV_INLINE vd ev_sin(vd x) { return ev_sincos2(x).s; }
EV_INLINE vd ev_cos(vd x) { return ev_sincos2(x).c; }

/* Cephes exp: n = floor(x log2(e) + 1/2), r = x - n ln2 in two parts, e^r by a Pade form,
   times 2^n built in the exponent bits; libm beyond [-708, 709]. */
EV_INLINE vd ev_exp(vd x) {
    vl ok = (x > -708.0) & (x < 709.0);
    vd xs = ev_and(ok, x);
    vd px = ev_floor(1.4426950408889634073599 * xs + 0.5);
    vl n = __builtin_convertvector(px, vl);
    vd r = xs - px * 6.93145751953125E-1;
    r = r - px * 1.42860682030941723212E-6;
    vd rr = r * r;
    vd p = r * ((1.26177193074810590878E-4 * rr + 3.02994407707441961300E-2) * rr + 9.99999999999999999910E-1);
    vd q = ((3.00198505138664455042E-6 * rr + 2.52448340349684104192E-3) * rr + 2.27265548208155028766E-1) * rr
           + 2.00000000000000000009E0;
    r = p / (q - p);
    r = 1.0 + 2.0 * r;
    r = r * (vd)((n + 1023) << 52);
    if (__builtin_expect(!ev_all(ok), 0)) r = ev_libm1(exp, x, r, ok);
    return r;
}

/* Cephes tanh: x + x^3 P(x^2)/Q(x^2) below 0.625, else 1 - 2/(e^{2|x|} + 1) (which is 1
   exactly from |x| = 19.1 on, so the exponential's argument is capped at 40). */
EV_INLINE vd ev_tanh(vd x) {
    vd a = ev_fabs(x);
    if (ev_all(a >= 19.5))  /* 1 - 2/(e^{2|x|} + 1) rounds to 1 from |x| = 19.06 on */
        return (vd)((vl)ev_splat(1.0) | ((vl)x & EV_SIGN));
    vl lg = a >= 0.625;
    vd s = ev_exp(2.0 * ev_fmin(a, ev_splat(20.0)));
    vd xx = x * x;
    vd p = (-9.64399179425052238628E-1 * xx - 9.92877231001918586564E1) * xx - 1.61468768441708447952E3;
    vd q = ((xx + 1.12811678491632931402E2) * xx + 2.23548839060100448583E3) * xx + 4.84406305325125486048E3;
    vd ratio = ev_sel(lg, ev_splat(2.0), p) / ev_sel(lg, s + 1.0, q);  /* one division for both branches */
    vd large = (vd)((vl)(1.0 - ratio) | ((vl)x & EV_SIGN));
    vd small = x + x * xx * ratio;
    return ev_sel(lg, large, ev_sel(x == 0.0, x, small));
}

/* Cephes atan2: atan(y/x), plus pi or -pi (by the sign of y) for x < 0; the axes and
   signed zeros as C99's atan2 (infinite arguments through libm) */
static __attribute__((noinline, cold)) vd ev_atan2_libm(vd y, vd x, vd r, vl ok) {
    for (int l = 0; l < EV_W; l++)
        if (!ok[l]) r[l] = atan2(y[l], x[l]);
    return r;
}
EV_INLINE vd ev_atan2(vd y, vd x) {
    vd pi = ev_splat(3.14159265358979323846);
    vl ysgn = (vl)y & EV_SIGN;
    vd z = ev_atan(y / x);
    vd w = (vd)((vl)pi | ysgn);
    vl xneg = (x < 0.0) | ((x == 0.0) & (((vl)x & EV_SIGN) != 0));
    z = ev_sel(xneg, w + z, z);
    /* y = +-0: +-0 for x > +0 or x = +0, +-pi for x < -0 or x = -0 */
    z = ev_sel(y == 0.0, (vd)((vl)ev_and(xneg, w) | ysgn), z);
    /* x = +-0, y != 0: +-pi/2 */
    z = ev_sel((x == 0.0) & (y != 0.0), (vd)((vl)ev_splat(1.57079632679489661923) | ysgn), z);
    vl ok = (ev_fabs(x) <= 1.7976931348623157e308) & (ev_fabs(y) <= 1.7976931348623157e308);
    if (__builtin_expect(!ev_all(ok), 0)) z = ev_atan2_libm(y, x, z, ok);
    return z;
}
"""

# op code -> C expression on vector operands a, b (every other op raises CompileError)
_UNARY = {
    ca.OP_ASSIGN: "{a}", ca.OP_NEG: "-{a}", ca.OP_SQ: "{a} * {a}", ca.OP_TWICE: "2.0 * {a}", ca.OP_INV: "1.0 / {a}",
    ca.OP_FABS: "ev_fabs({a})", ca.OP_SQRT: "ev_sqrt({a})", ca.OP_NOT: "ev_bool({a} == 0.0)",
    ca.OP_SIN: "ev_sin({a})", ca.OP_COS: "ev_cos({a})", ca.OP_ATAN: "ev_atan({a})", ca.OP_EXP: "ev_exp({a})",
    ca.OP_TANH: "ev_tanh({a})", ca.OP_FLOOR: "ev_floor({a})", ca.OP_CEIL: "EV_LANES1(ceil, {a})",
    ca.OP_SIGN: "EV_LANES1(ev_sign1, {a})", ca.OP_LOG: "EV_LANES1(log, {a})", ca.OP_TAN: "EV_LANES1(tan, {a})",
    ca.OP_ASIN: "EV_LANES1(asin, {a})", ca.OP_ACOS: "EV_LANES1(acos, {a})", ca.OP_SINH: "EV_LANES1(sinh, {a})",
    ca.OP_COSH: "EV_LANES1(cosh, {a})", ca.OP_ASINH: "EV_LANES1(asinh, {a})", ca.OP_ACOSH: "EV_LANES1(acosh, {a})",
    ca.OP_ATANH: "EV_LANES1(atanh, {a})", ca.OP_ERF: "EV_LANES1(erf, {a})", ca.OP_LOG1P: "EV_LANES1(log1p, {a})",
    ca.OP_EXPM1: "EV_LANES1(expm1, {a})",
}
_BINARY = {
    ca.OP_ADD: "{a} + {b}", ca.OP_SUB: "{a} - {b}", ca.OP_MUL: "{a} * {b}", ca.OP_DIV: "{a} / {b}",
    ca.OP_LT: "ev_bool({a} < {b})", ca.OP_LE: "ev_bool({a} <= {b})", ca.OP_EQ: "ev_bool({a} == {b})",
    ca.OP_NE: "ev_bool({a} != {b})", ca.OP_AND: "ev_bool(({a} != 0.0) & ({b} != 0.0))",
    ca.OP_OR: "ev_bool(({a} != 0.0) | ({b} != 0.0))", ca.OP_IF_ELSE_ZERO: "ev_and({a} != 0.0, {b})",
    ca.OP_FMIN: "ev_fmin({a}, {b})", ca.OP_FMAX: "ev_fmax({a}, {b})", ca.OP_ATAN2: "ev_atan2({a}, {b})",
    ca.OP_POW: "EV_LANES2(pow, {a}, {b})", ca.OP_CONSTPOW: "EV_LANES2(pow, {a}, {b})",
    ca.OP_FMOD: "EV_LANES2(fmod, {a}, {b})", ca.OP_REMAINDER: "EV_LANES2(remainder, {a}, {b})",
    ca.OP_COPYSIGN: "EV_LANES2(copysign, {a}, {b})", ca.OP_HYPOT: "EV_LANES2(hypot, {a}, {b})",
}


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
        elif op in _UNARY:
            node = _Node(op, (slot[i[0]],))
        elif op in _BINARY:
            node = _Node(op, (slot[i[0]], slot[i[1]]))
        else:
            raise CompileError(f"{fn.name()}: operation {_op_name(op)} has no lane-kernel form")
        if node.args:
            node.invariant = all(nodes[a].invariant for a in node.args)
        nodes.append(node)
        slot[o[0]] = len(nodes) - 1
    return nodes, outputs


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
    if node.op in _UNARY:
        return _UNARY[node.op].format(a=args[0])
    return _BINARY[node.op].format(a=args[0], b=args[1])


def rollout_source(fn: ca.Function, fname: str, roles: Roles, width: int = WIDTH) -> str:
    """C source of ``int fname(long n_steps, long n_cases, const double* z0, const double* const* in,
    double* z_end, double* const* out)``: ``n_steps`` samples of ``fn`` for ``n_cases`` cases.

    Layouts (C order, float64): ``z0``/``z_end`` (cases, nz); ``in[i]`` for input ``i >= 1``:
    (cases, n_steps, n_i) if stepped else (cases, n_i) (``in[0]`` unused); ``out[j]`` for output
    ``j >= 1``: (cases, n_steps, m_j), or NULL (not stored). Cases go through in blocks of ``width`` lanes; a last, partial
    block repeats its last case in the spare lanes and stores only the real ones.

    What the per-case inputs alone determine is computed once per block, before the time loop,
    and divisions by it become products (:func:`_strength_reduce`); repeated subexpressions are
    computed once (:func:`toolkit.compiled.shared`); ``sin`` and ``cos`` of one argument share their range reduction.
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
    from .compiled import shared
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

    hoisted, body, used = [], [], set()
    for n, node in enumerate(nodes):
        if node.op == ca.OP_INPUT:
            src, el = node.src
            if src == 0:
                body.append(f"const vd v{n} = zs[{el}];")
            elif src in stepped:
                body.append(f"vd v{n}; for (int l = 0; l < EV_W; l++) v{n}[l] = rp{src}[l][{el}];")
            else:
                hoisted.append(f"const vd h{n} = c{src}[{el}];")
            continue
        if n in pair_at:
            body.append(pair_at[n])
        if node.op == ca.OP_CALL:
            ins = ", ".join(name(a) for a in node.args)
            line = f"vd {name(n)}[{node.src[1]}]; {node.src[0]}((const vd[]){{{ins}}}, {name(n)});"
            (hoisted if node.invariant else body).append(line)
            used.add(node.src[0])
            continue
        line = f"const vd {name(n)} = {_expr(nodes, n, name, sincos)};"
        (hoisted if node.invariant else body).append(line)
    stores: dict[int, list[str]] = {}
    for dst, el, n in outputs:
        if dst == 0:
            body.append(f"zn[{el}] = {name(n)};")
        else:
            stores.setdefault(dst, []).append(f"for (int l = 0; l < n_act; l++) wp{dst}[l][{el}] = {name(n)}[l];")
    for dst in sorted(stores):  # an output passed as NULL is not stored
        body.append(f"if (out[{dst}]) {{")
        body.extend("  " + ln for ln in stores[dst])
        body.append("}")

    lines = [MATH_C % {"width": width}, *(LANE_INTRINSICS[u] for u in sorted(used)),
             f"int {fname}(long n_steps, long n_cases, const double* z0, const double* const* in, double* z_end, "
             f"double* const* out) {{",
             "  for (long c0 = 0; c0 < n_cases; c0 += EV_W) {",
             "    int n_act = (int)(n_cases - c0 < EV_W ? n_cases - c0 : EV_W);",
             "    long cs[EV_W];",
             "    for (int l = 0; l < EV_W; l++) cs[l] = c0 + (l < n_act ? l : n_act - 1);",
             f"    vd zs[{max(nz, 1)}], zn[{max(nz, 1)}];",
             f"    for (int e = 0; e < {nz}; e++) for (int l = 0; l < EV_W; l++) zs[e][l] = z0[cs[l] * {nz} + e];"]
    for c in consts:
        m = fn.nnz_in(c)
        lines.append(f"    vd c{c}[{max(m, 1)}];")
        lines.append(f"    for (int e = 0; e < {m}; e++) for (int l = 0; l < EV_W; l++) "
                     f"c{c}[e][l] = in[{c}][cs[l] * {m} + e];")
    lines.extend("    " + h for h in hoisted)
    lines.append("    for (long k = 0; k < n_steps; k++) {")
    for st in sorted(stepped):
        m = fn.nnz_in(st)
        lines.append(f"      const double* rp{st}[EV_W];")
        lines.append(f"      for (int l = 0; l < EV_W; l++) rp{st}[l] = in[{st}] + (cs[l] * n_steps + k) * {m};")
    for j in range(1, n_out):
        m = fn.nnz_out(j)
        lines.append(f"      double* wp{j}[EV_W];")
        lines.append(f"      if (out[{j}]) for (int l = 0; l < EV_W; l++) wp{j}[l] = out[{j}] + (cs[l] * n_steps + k) * {m};")
    lines.extend("      " + b for b in body)
    lines.append("      memcpy(zs, zn, sizeof(zs));")
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
    out = [MATH_C % {"width": width}]
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
                            ctypes.c_void_p]
        self.n_in, self.n_out = fn.n_in(), fn.n_out()
        self.sizes_in = [fn.nnz_in(i) for i in range(self.n_in)]
        self.sizes_out = [fn.nnz_out(j) for j in range(self.n_out)]
        self.stepped = set(roles.stepped)

    def __call__(self, z0: np.ndarray, inputs: list, n_steps: int, outputs: list | None = None,
                 keep: tuple[int, ...] | None = None):
        """``z0`` (cases, nz); ``inputs`` for inputs 1.. (stepped: (cases, n_steps, n_i), else (cases, n_i));
        returns (z_end, [outputs 1..] as (cases, n_steps, m_j)), written into ``outputs`` when given.
        ``keep``: the outputs (numbered from 1) to store; the others come back as None."""
        z0 = np.ascontiguousarray(z0, dtype=float)
        n_cases = z0.shape[0]
        if z0.shape != (n_cases, self.sizes_in[0]):
            raise DataError(f"lane rollout: z0 must be (cases, {self.sizes_in[0]}), got {z0.shape}")
        arrs = [None]
        for i, a in enumerate(inputs, start=1):
            a = np.ascontiguousarray(a, dtype=float)
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
            if self._f(n_steps, n_cases, z0.ctypes.data, in_ptrs, z_end.ctypes.data, out_ptrs) != 0:
                raise CompileError("lane rollout reported an error")
        else:
            z_end[:] = z0
        return z_end, outputs


def compile_rollout(fn, key: str, roles: Roles, name: str = "ev_rollout",
                    flags: tuple[str, ...] = CFLAGS, width: int = WIDTH) -> LaneRollout | None:
    """The lane kernel of ``fn`` (a casadi SX function, or a callable returning one) from the compiled
    cache, built when missing (with ``flags``: :data:`CFLAGS` or others that keep its arithmetic IEEE;
    ``width`` lanes per vector, which ``key`` must name); None without a C compiler or when the
    compiler fails."""
    from .compiled import compile_source, compiler
    if compiler() is None:
        return None
    fn = fn() if callable(fn) and not isinstance(fn, ca.Function) else fn
    lib = compile_source(lambda path: path.write_text(rollout_source(fn, name, roles, width)), key, flags,
                         "casadi's generated C")
    if lib is None:
        return None
    return LaneRollout(lib, name, fn, roles, width)
