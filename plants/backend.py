"""One set of math operations that works on numpy arrays and on casadi symbols.

Every model in :mod:`plants` is written once as ``f(x, u, w, p)`` with the
functions of the namespace returned by :func:`ops_for`; the same code then
evaluates numerically (numpy, also batched with arrays shaped ``(n, N)``) and
symbolically (casadi ``SX``/``MX``), so simulation, linearisation, sweeps and
code generation share one definition.
"""

from __future__ import annotations

from contextlib import contextmanager
from types import SimpleNamespace

import casadi as ca
import numpy as np
from .errors import ModelError

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)

LANE_INTRINSICS: dict[str, str] = {}
"""C for casadi functions that a traced step calls (``never_inline`` call nodes): casadi function
name -> C text defining ``EV_INLINE void <name>(const vd* in, vd* out)`` on lane vectors. A lane
kernel (:mod:`toolkit.kernels.lanes`) runs it in place of the call; casadi's own C and virtual machine
evaluate the function's body."""

_CALL_NODES = [False]


@contextmanager
def call_nodes():
    """Within: what has a lane-kernel form (:data:`LANE_INTRINSICS`) is traced as a call node of its
    casadi function (a speed schedule's read, the tyre's shape function); elsewhere (differentiation,
    casadi's code generation) the same quantity is traced inline."""
    old, _CALL_NODES[0] = _CALL_NODES[0], True
    try:
        yield
    finally:
        _CALL_NODES[0] = old


def tracing_call_nodes() -> bool:
    """Whether a trace is inside :func:`call_nodes`."""
    return _CALL_NODES[0]


def is_symbolic(*values) -> bool:
    """True if any value is a casadi matrix (then casadi operations are used)."""
    return any(isinstance(v, _CASADI_TYPES) for v in values)


def _np_stack(items):
    arrays = [np.asarray(i, dtype=float) for i in items]
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    if not shape:  # all scalars (one sample): one array, no broadcasting
        return np.array(arrays)
    return np.stack([np.broadcast_to(a, shape) for a in arrays])


def _ca_stack(items):
    return ca.vertcat(*items)


def _np_zeros(n, m=1):
    return np.zeros((n, m)) if m != 1 else np.zeros(n)


def _ca_zeros(n, m=1):
    return ca.SX.zeros(n, m)


NUMPY = SimpleNamespace(
    name="numpy", zeros=_np_zeros, eye=np.eye, if_else=np.where, outer=np.outer,
    reshape=lambda v, n, m: np.reshape(v, (n, m), order="F"), flatten=lambda M: np.ravel(M, order="F"),
    concat=lambda items: np.concatenate([np.atleast_1d(i) for i in items]),
    sin=np.sin, cos=np.cos, tan=np.tan, arctan=np.arctan, arctan2=np.arctan2,
    sqrt=np.sqrt, tanh=np.tanh, exp=np.exp, fabs=np.abs, fmax=np.maximum, fmin=np.minimum,
    stack=_np_stack,
)

CASADI = SimpleNamespace(
    name="casadi", zeros=_ca_zeros, eye=ca.SX.eye, if_else=ca.if_else, outer=lambda a, b: ca.mtimes(a, b.T),
    reshape=lambda v, n, m: ca.reshape(v, n, m), flatten=lambda M: ca.vec(M),
    concat=lambda items: ca.vertcat(*items),
    sin=ca.sin, cos=ca.cos, tan=ca.tan, arctan=ca.atan, arctan2=ca.atan2,
    sqrt=ca.sqrt, tanh=ca.tanh, exp=ca.exp, fabs=ca.fabs, fmax=ca.fmax, fmin=ca.fmin,
    stack=_ca_stack,
)


def ops_for(*values) -> SimpleNamespace:
    """The operation namespace (numpy or casadi) suited to ``values``."""
    return CASADI if is_symbolic(*values) else NUMPY


def unpack(vec, names):
    """Split a state/input vector into a namespace of named rows.

    Works for numpy arrays shaped ``(n,)`` or ``(n, N)`` and for casadi column
    vectors; raises if the length does not match ``names``.
    """
    n = vec.shape[0]
    if n != len(names):
        raise ModelError(f"expected a vector of {len(names)} signals {tuple(names)}, got length {n}")
    return SimpleNamespace(**{name: vec[i] for i, name in enumerate(names)})


def smooth_abs(x, eps, ops):
    """sqrt(x^2 + eps^2): |x| without the kink at 0 (keeps derivatives finite)."""
    return ops.sqrt(x * x + eps * eps)


def smooth_max(a, b, eps, ops):
    """0.5 (a + b + sqrt((a - b)^2 + eps^2)): max(a, b) rounded over a width ~eps."""
    d = a - b
    return 0.5 * (a + b + ops.sqrt(d * d + eps * eps))
