"""The C side of the lane kernels (:mod:`toolkit.kernels.lanes`): vector types of ``EV_W`` lanes, the
branch-free vector ``sin``, ``cos``, ``atan``, ``atan2``, ``exp`` and ``tanh`` after the Cephes
library's algorithms (S. L. Moshier, *Methods and Programs for Mathematical Functions*, 1989; the
coefficients of netlib's ``cephes/double``), and the C expression of each casadi operation on
vector operands.

Arithmetic is IEEE elementwise (the kernels are built without contraction or fast-math); the
Cephes functions agree with glibc to a few units in the last place (``tests/toolkit/test_lanes.py``);
lanes a vector path cannot take, and every other libm function, go lane by lane through libm.
"""

from __future__ import annotations

from importlib import resources

import casadi as ca

MATH_C = (resources.files(__package__) / "lane_math.h").read_text()
"""The vector math's C (``lane_math.h``, shipped beside this module): every kernel prints it after
``#define EV_W <lanes>`` (:func:`math_c`)."""


def math_c(width: int) -> str:
    """The vector math for vectors of ``width`` lanes."""
    return f"#define EV_W {int(width)}\n" + MATH_C


# op code -> C expression on vector operands a, b (every other op: toolkit.kernels.lanes raises CompileError)
UNARY = {
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
BINARY = {
    ca.OP_ADD: "{a} + {b}", ca.OP_SUB: "{a} - {b}", ca.OP_MUL: "{a} * {b}", ca.OP_DIV: "{a} / {b}",
    ca.OP_LT: "ev_bool({a} < {b})", ca.OP_LE: "ev_bool({a} <= {b})", ca.OP_EQ: "ev_bool({a} == {b})",
    ca.OP_NE: "ev_bool({a} != {b})", ca.OP_AND: "ev_bool(({a} != 0.0) & ({b} != 0.0))",
    ca.OP_OR: "ev_bool(({a} != 0.0) | ({b} != 0.0))", ca.OP_IF_ELSE_ZERO: "ev_and({a} != 0.0, {b})",
    ca.OP_FMIN: "ev_fmin({a}, {b})", ca.OP_FMAX: "ev_fmax({a}, {b})", ca.OP_ATAN2: "ev_atan2({a}, {b})",
    ca.OP_POW: "EV_LANES2(pow, {a}, {b})", ca.OP_CONSTPOW: "EV_LANES2(pow, {a}, {b})",
    ca.OP_FMOD: "EV_LANES2(fmod, {a}, {b})", ca.OP_REMAINDER: "EV_LANES2(remainder, {a}, {b})",
    ca.OP_COPYSIGN: "EV_LANES2(copysign, {a}, {b})", ca.OP_HYPOT: "EV_LANES2(hypot, {a}, {b})",
}
