"""C99 from a casadi SX function: straight-line code read off the function's algorithm.

casadi's own code generator writes a generic, exported API (``f(arg, res, iw, w,
mem)`` with unused parameters, non-static helpers, work-size queries) that does not
compile under ``-std=c99 -Wall -Wextra -Werror -pedantic`` and cannot name the
inputs after the firmware's structs and calibration symbols. The arithmetic,
though, is casadi's: an SX function is a list of scalar instructions (``OP_INPUT``,
``OP_ADD``, ``OP_IF_ELSE_ZERO``, ..., ``OP_OUTPUT``) over a work vector; this module
prints that list as C, one statement per instruction, in casadi's order, with every
input read and every output written through an expression the caller supplies
(a struct field, a ``static const`` calibration symbol, an array element). In
float64 the result therefore equals casadi's own evaluation to the last bit unless
the compiler contracts or reassociates (``-std=c99`` keeps ``-ffp-contract=off``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca

from evstab.plants.errors import ModelError


@dataclass(frozen=True)
class Precision:
    """How numbers are spelled for one floating-point type."""

    name: str
    """``float64`` or ``float32``."""

    @property
    def ctype(self) -> str:
        return "double" if self.name == "float64" else "float"

    @property
    def suffix(self) -> str:
        """Suffix of math functions (``sqrt`` / ``sqrtf``) and literals (``1.0`` / ``1.0f``)."""
        return "" if self.name == "float64" else "f"

    def literal(self, v: float) -> str:
        v = float(v)
        if math.isnan(v):
            return "NAN"
        if math.isinf(v):
            return "INFINITY" if v > 0 else "(-INFINITY)"
        text = repr(v) if self.name == "float64" else f"{v:.9g}"
        if not any(c in text for c in ".en"):
            text += ".0"
        return text + self.suffix

    def fn(self, name: str) -> str:
        return name + self.suffix


PRECISIONS = ("float64", "float32")


def _ops(p: Precision) -> dict:
    f = p.fn
    one = p.literal(1.0)
    return {
        ca.OP_ASSIGN: lambda a: a[0],
        ca.OP_ADD: lambda a: f"{a[0]} + {a[1]}",
        ca.OP_SUB: lambda a: f"{a[0]} - {a[1]}",
        ca.OP_MUL: lambda a: f"{a[0]} * {a[1]}",
        ca.OP_DIV: lambda a: f"{a[0]} / {a[1]}",
        ca.OP_NEG: lambda a: f"-{a[0]}",
        ca.OP_INV: lambda a: f"{one} / {a[0]}",
        ca.OP_SQ: lambda a: f"{a[0]} * {a[0]}",
        ca.OP_TWICE: lambda a: f"{a[0]} + {a[0]}",
        ca.OP_SQRT: lambda a: f"{f('sqrt')}({a[0]})",
        ca.OP_EXP: lambda a: f"{f('exp')}({a[0]})",
        ca.OP_LOG: lambda a: f"{f('log')}({a[0]})",
        ca.OP_POW: lambda a: f"{f('pow')}({a[0]}, {a[1]})",
        ca.OP_CONSTPOW: lambda a: f"{f('pow')}({a[0]}, {a[1]})",
        ca.OP_SIN: lambda a: f"{f('sin')}({a[0]})",
        ca.OP_COS: lambda a: f"{f('cos')}({a[0]})",
        ca.OP_TAN: lambda a: f"{f('tan')}({a[0]})",
        ca.OP_ATAN: lambda a: f"{f('atan')}({a[0]})",
        ca.OP_TANH: lambda a: f"{f('tanh')}({a[0]})",
        ca.OP_ATAN2: lambda a: f"{f('atan2')}({a[0]}, {a[1]})",
        ca.OP_FABS: lambda a: f"{f('fabs')}({a[0]})",
        # fmin/fmax inline: the x86-64 C library's result (the second operand when the two compare
        # equal, the other one when one is NaN), without a call. Spelled as a NaN test of the second
        # operand around the plain select, which a compiler turns into one minsd/maxsd (it returns the
        # second operand when either is NaN) and a test it can predict, not two compare-and-branches
        # (faster: docs/internals.md, compiled kernels)
        ca.OP_FMIN: lambda a: f"({a[1]} != {a[1]}) ? {a[0]} : (({a[0]} < {a[1]}) ? {a[0]} : {a[1]})",
        ca.OP_FMAX: lambda a: f"({a[1]} != {a[1]}) ? {a[0]} : (({a[0]} > {a[1]}) ? {a[0]} : {a[1]})",
        ca.OP_FLOOR: lambda a: f"{f('floor')}({a[0]})",
        ca.OP_CEIL: lambda a: f"{f('ceil')}({a[0]})",
        ca.OP_COPYSIGN: lambda a: f"{f('copysign')}({a[0]}, {a[1]})",
        ca.OP_LT: lambda a: f"{a[0]} < {a[1]}",
        ca.OP_LE: lambda a: f"{a[0]} <= {a[1]}",
        ca.OP_EQ: lambda a: f"{a[0]} == {a[1]}",
        ca.OP_NE: lambda a: f"{a[0]} != {a[1]}",
        # logic on reals as C reads a real in a condition (nonzero, NaN included, is true), spelled
        # as the comparison with zero (a condition essentially boolean: MISRA C:2012 14.4)
        ca.OP_NOT: lambda a: f"{a[0]} == {p.literal(0.0)}",
        ca.OP_AND: lambda a: f"({a[0]} != {p.literal(0.0)}) && ({a[1]} != {p.literal(0.0)})",
        ca.OP_OR: lambda a: f"({a[0]} != {p.literal(0.0)}) || ({a[1]} != {p.literal(0.0)})",
        ca.OP_IF_ELSE_ZERO: lambda a: f"({a[0]} != {p.literal(0.0)}) ? {a[1]} : {p.literal(0.0)}",
        ca.OP_SIGN: lambda a: f"{a[0]} < 0 ? -{one} : ({a[0]} > 0 ? {one} : {a[0]})",
    }


_OP_NAMES = {getattr(ca, k): k for k in dir(ca) if k.startswith("OP_")}


def emit_body(f: ca.Function, reads, writes, precision: Precision, indent: str = "    ") -> list[str]:
    """C statements evaluating SX function ``f``.

    ``reads[i](k)`` is the C expression of nonzero ``k`` of input ``i``;
    ``writes[j](k)`` the C lvalue of nonzero ``k`` of output ``j`` (``writes[j]`` None, or
    its value None: not written). Comparisons give 0 or 1 as in casadi. Work variables ``w0 ...`` are
    locals declared at the top.
    """
    if not f.is_a("SXFunction"):
        raise ModelError(f"C emitter: '{f.name()}' is not an SX function")
    ops = _ops(precision)
    lines, used = [], set()
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        ins, outs = f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_INPUT:
            lines.append(f"w{outs[0]} = {reads[ins[0]](ins[1])};")
            used.add(outs[0])
        elif op == ca.OP_OUTPUT:
            target = writes[outs[0]]
            lvalue = None if target is None else target(outs[1])
            if lvalue is not None:
                lines.append(f"{lvalue} = w{ins[0]};")
        elif op == ca.OP_CONST:
            lines.append(f"w{outs[0]} = {precision.literal(f.instruction_constant(k))};")
            used.add(outs[0])
        elif op in ops:
            text = ops[op]([f"w{i}" for i in ins])
            if op in (ca.OP_LT, ca.OP_LE, ca.OP_EQ, ca.OP_NE, ca.OP_NOT, ca.OP_AND, ca.OP_OR):
                # the 0/1 casadi gives, selected rather than cast from the boolean (MISRA C:2012 10.5)
                text = f"({text}) ? {precision.literal(1.0)} : {precision.literal(0.0)}"
            lines.append(f"w{outs[0]} = {text};")
            used.add(outs[0])
        else:
            raise ModelError(f"C emitter: casadi operation {_OP_NAMES.get(op, op)} in '{f.name()}' has no C "
                             f"translation here; add it to toolkit.firmware.cgen._ops")
    names = [f"w{i}" for i in sorted(used)]
    decl = [f"{precision.ctype} {name};" for name in names]  # one per declaration (MISRA C:2012 12.3)
    return [indent + s for s in decl + lines]


def c_identifier(name: str) -> str:
    out = "".join(ch if ch.isalnum() else "_" for ch in name)
    if not out or out[0].isdigit():
        out = "_" + out
    return out


def c_array(values, precision: Precision, per_line: int = 4, indent: str = "    ") -> str:
    """A brace-initialiser body, ``per_line`` numbers a line."""
    lits = [precision.literal(v) for v in values]
    rows = [", ".join(lits[i:i + per_line]) for i in range(0, len(lits), per_line)]
    return "{\n" + ",\n".join(indent + r for r in rows) + "\n}"
