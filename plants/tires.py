"""Combined-slip tire model: Magic Formula on the normalised slip vector.

The model is Pacejka's Magic Formula applied to the magnitude of a
stiffness-normalised combined slip vector (the "similarity" / normalised-slip
approach of Pacejka, *Tire and Vehicle Dynamics*, 3rd ed., sec. 4.3.2, with the
isotropic simplification). For one tire with vertical load ``F_z``, friction
``mu``, cornering stiffness ``C_a`` and longitudinal slip stiffness ``C_k``
(both at the nominal load ``F_z0``, scaled linearly with load):

``u_x = C_k kappa / (mu F_z0)``,   ``u_y = C_a tan(alpha) / (mu F_z0)``,
``u = sqrt(u_x^2 + u_y^2)``,
``F(u) = sin(C atan(B u - E (B u - atan(B u))))`` with ``B = 1 / C``,
``F_x = mu F_z F(u) u_x / u``,   ``F_y = -mu F_z F(u) u_y / u``.

``F'(0) = 1``, so for small slip ``F_x = C_k (F_z/F_z0) kappa`` and
``F_y = -C_a (F_z/F_z0) tan(alpha)``: exactly the linear tire of the bicycle
model, and the sum over an axle is unchanged by lateral load transfer. The
resultant never exceeds ``mu F_z`` (the friction circle), and a longitudinal
force uses up lateral grip: the coupling the two-track plant must show when the
rear motors make a yaw moment. Shape ``C`` and curvature ``E`` are vehicle
parameters (defaults 1.3 and -2.0: peak at ``u = 2.01``, i.e. where the linear
tire would ask for twice the available grip, sliding at ``sin(1.3 pi/2) = 0.89`` of
peak).

Sign conventions (ISO 8855 wheel axes): ``kappa = (omega R - v_x) / v_ref``
positive when driving; slip angle ``alpha = atan(v_y / v_ref)`` of the wheel
centre velocity, and the lateral force opposes it.

The shape function is evaluated from a table where it is hot (:class:`ShapeTable`): for the
default shape and curvature, numbers and lane kernels (:mod:`toolkit.kernels.lanes`) read ``F(u) / u`` from
quintic Hermite segments on ``w = 1 / (1 + u)`` (512 of them, exact values and first two
derivatives at the grid points), one division and a degree-5 polynomial in place of two
arc tangents, a sine and a division. It equals the formula to 9e-16 in ``F / u`` and 3e-15
relative in the force (:meth:`ShapeTable.max_error`); casadi's inline expressions (differentiation, casadi's code
generation) keep the formula, and any other shape or curvature is evaluated from it.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache

import numpy as np

from .backend import CASADI, LANE_INTRINSICS, NUMPY, tracing_call_nodes
from .errors import ModelError

EPS_SLIP = 1e-9
"""Regularises |u| at zero slip (keeps F and its derivatives finite)."""


def magic_formula_normalised(u, shape, curvature, ops):
    """Normalised Magic Formula ``F(u)`` with unit initial slope (peak value 1); ``shape`` C and ``curvature`` E
    numbers or casadi symbols."""
    b = 1.0 / shape
    bu = b * u
    return ops.sin(shape * ops.arctan(bu - curvature * (bu - ops.arctan(bu))))


def combined_forces(kappa, tan_alpha, fz, fz0, mu, c_alpha, c_kappa, shape, curvature, ops):
    """Longitudinal and lateral tire force [N] in wheel axes for combined slip."""
    ux = c_kappa * kappa / (mu * fz0)
    uy = c_alpha * tan_alpha / (mu * fz0)
    u = ops.sqrt(ux * ux + uy * uy + EPS_SLIP**2)
    if ops is NUMPY and _tabulated(shape, curvature):
        scale = mu * fz * shape_table().ratio(u)
    elif ops is not NUMPY and tracing_call_nodes():
        scale = mu * fz * _casadi_function(shape_table())(ops.stack([u, shape, curvature]))
    else:
        scale = mu * fz * magic_formula_normalised(u, shape, curvature, ops) / u
    return scale * ux, -scale * uy


TABLE_SHAPE = 1.3
"""The shape factor ``C`` of :func:`shape_table` (:class:`plants.VehicleParams`' default, every
bundled vehicle's)."""
TABLE_CURVATURE = -2.0
"""The curvature factor ``E`` of :func:`shape_table` (the default, every bundled vehicle's)."""
TABLE_SEGMENTS = 512
"""Segments of :func:`shape_table` on ``w`` in [0, 1] (24 KiB of coefficients): the quintic's error
falls with the sixth power of the segment length, and at 512 it is below the formula's own rounding
(:meth:`ShapeTable.max_error`; 128 segments: 2e-12)."""


def _tabulated(shape, curvature) -> bool:
    return np.ndim(shape) == 0 and np.ndim(curvature) == 0 and float(shape) == TABLE_SHAPE \
        and float(curvature) == TABLE_CURVATURE


class ShapeTable:
    """``G(u) = F(u) / u`` of one shape and curvature (:func:`magic_formula_normalised`), tabulated on
    ``w = 1 / (1 + u)`` in [0, 1] (``u`` >= 0 from 0 to infinity) in :data:`TABLE_SEGMENTS` equal
    segments, on each a quintic Hermite polynomial in ``s = w n - i`` through the exact ``G``,
    ``dG/dw`` and ``d2G/dw2`` at both ends: exact at the grid points, continuous with two
    derivatives between segments.

    Read (:meth:`ratio`, and the lane kernels' C, operation for operation): ``w = 1 / (1 + u)``,
    ``x = w n``, ``i = min(trunc(x), n - 1)``, ``s = x - i``, ``c5 s + c4`` and so on by Horner.

    The grid-point derivatives come from two exact forms of ``G`` (casadi's automatic differentiation):
    ``F(u) / u`` with ``u = (1 - w) / w`` where ``u <= 1``, and where ``u >= 1``, with ``z = 1 / u``,
    ``z sin(C (pi/2 - atan(z / ((1 - E) B + E z (pi/2 - atan(C z))))))`` (``atan(a) = pi/2 - atan(1/a)``
    for ``a > 0``: regular at ``u`` = infinity, where ``G`` = 0); at ``u = 0``, ``G = 1``,
    ``dG/dw = 0`` and ``d2G/dw2 = 2 f3``, ``F = u + f3 u^3 + ...`` with
    ``f3 = -(1 + E) / (3 C^2) - 1/6``."""

    def __init__(self, shape: float, curvature: float, segments: int = TABLE_SEGMENTS):
        if not (1.0 <= shape < 2.0 and curvature < 1.0 and segments >= 2):  # F(inf) = sin(C pi/2) > 0
            raise ModelError(f"shape table: needs 1 <= shape < 2, curvature < 1, segments >= 2; got {shape}, "
                             f"{curvature}, {segments}")
        self.shape, self.curvature, self.segments = float(shape), float(curvature), int(segments)
        n = self.segments
        w = np.arange(n + 1) / n
        val, dg, ddg = _grid_derivatives(self.shape, self.curvature, w)
        h = 1.0 / n
        y0, d0, e0 = val[:-1], dg[:-1] * h, ddg[:-1] * h * h
        y1, d1, e1 = val[1:], dg[1:] * h, ddg[1:] * h * h
        dy = y1 - y0  # exact (neighbours within a factor 2): the higher coefficients round relative to it
        # the quintic Hermite basis in powers of s (rows: s^0 .. s^5)
        self.coeffs = np.stack([
            y0, d0, 0.5 * e0,
            10.0 * dy - 6.0 * d0 - 4.0 * d1 - 1.5 * e0 + 0.5 * e1,
            -15.0 * dy + 8.0 * d0 + 7.0 * d1 + 1.5 * e0 - e1,
            6.0 * dy - 3.0 * d0 - 3.0 * d1 - 0.5 * e0 + 0.5 * e1], axis=1)
        self.coeffs.setflags(write=False)
        self.name = "evstab_tyre_" + hashlib.sha256(repr((self.shape, self.curvature, n)).encode()).hexdigest()[:16]

    def ratio(self, u):
        """``G(u) = F(u) / u`` for numbers ``u`` >= 0 (scalar or array)."""
        u = np.asarray(u, float)
        x = (1.0 / (1.0 + u)) * float(self.segments)
        with np.errstate(invalid="ignore"):  # NaN: any segment, the result is NaN
            i = np.clip(x.astype(np.int64), 0, self.segments - 1)
        s = x - i
        c = self.coeffs[i]
        return ((((c[..., 5] * s + c[..., 4]) * s + c[..., 3]) * s + c[..., 2]) * s + c[..., 1]) * s + c[..., 0]

    def max_error(self, points: int = 200001) -> dict:
        """The table against the formula (numpy, double precision), on ``points`` values of ``w`` spaced
        evenly in [0, 1] and on ``u`` spaced logarithmically from 1e-9 to 1e9: the largest absolute
        difference of ``G`` (at most 1) and the largest relative difference of the force ``F = G u``."""
        w = np.linspace(0.0, 1.0, points)[1:-1]
        u = (1.0 - w) / w
        exact = magic_formula_normalised(u, self.shape, self.curvature, NUMPY) / u
        us = np.geomspace(1e-9, 1e9, points)
        f_exact = magic_formula_normalised(us, self.shape, self.curvature, NUMPY)
        return {"G_abs": float(np.max(np.abs(self.ratio(u) - exact))),
                "F_rel": float(np.max(np.abs(self.ratio(us) * us - f_exact) / np.abs(f_exact)))}

    def lane_c(self) -> str:
        """C of :meth:`ratio` on lane vectors (``EV_INLINE void name(const vd* in, vd* out)``, ``in[0]``
        the slip ``u``, ``in[1]`` and ``in[2]`` the shape and curvature): lanes with this table's shape
        and curvature read the table, others evaluate the formula (the casadi function's body, the
        Cephes functions of :mod:`toolkit.kernels.lane_math`)."""
        n = self.segments
        rows = ",\n        ".join("{" + ", ".join(repr(float(c)) for c in row) + "}" for row in self.coeffs)
        return f"""EV_INLINE void {self.name}(const vd* in, vd* out) {{
    static const double tab[{n}][6] = {{
        {rows}}};
    const vd u = in[0];
    const vl mine = (in[1] == {self.shape!r}) & (in[2] == {self.curvature!r});
    vd r = ev_splat(0.0);
    if (!ev_all(mine)) {{
        const vd c = in[1], e = in[2];
        const vd bu = (1.0 / c) * u;
        r = ev_sin(c * ev_atan(bu - e * (bu - ev_atan(bu)))) / u;
    }}
    if (!ev_all(~mine)) {{
        const vd x = (1.0 / (1.0 + u)) * {float(n)!r};
        vl i = __builtin_convertvector(x, vl);
        i = i & ~(i < 0);  /* NaN converts to the most negative integer: segment 0, the result NaN */
        const vl top = i > {n - 1};
        i = (i & ~top) | (top & {n - 1});
        const vd s = x - __builtin_convertvector(i, vd);
        vd c[6];
        for (int k = 0; k < 6; k++) for (int l = 0; l < EV_W; l++) c[k][l] = tab[i[l]][k];
        const vd t = ((((c[5] * s + c[4]) * s + c[3]) * s + c[2]) * s + c[1]) * s + c[0];
        r = ev_sel(mine, t, r);
    }}
    out[0] = r;
}}
"""


def _grid_derivatives(shape: float, curvature: float, w: np.ndarray) -> np.ndarray:
    """``G``, ``dG/dw`` and ``d2G/dw2`` at ``w`` (see :class:`ShapeTable`), three arrays."""
    import casadi as ca
    c, e, b = shape, curvature, 1.0 / shape
    ws = ca.SX.sym("w")
    u = (1.0 - ws) / ws
    small = magic_formula_normalised(u, c, e, CASADI) / u
    z = ws / (1.0 - ws)
    large = z * ca.sin(c * (np.pi / 2 - ca.atan(z / ((1.0 - e) * b + e * z * (np.pi / 2 - ca.atan(c * z))))))
    out = np.empty((len(w), 3))
    for expr, sel in ((small, (w > 0.5) & (w < 1.0)), (large, w <= 0.5)):
        d1 = ca.jacobian(expr, ws)
        f = ca.Function("g", [ws], [expr, d1, ca.jacobian(d1, ws)])
        if sel.any():
            out[sel] = np.array(f.map(int(sel.sum()))(w[sel][None, :])).T.reshape(-1, 3)
    f3 = -(1.0 + e) / (3.0 * c * c) - 1.0 / 6.0
    out[w == 1.0] = (1.0, 0.0, 2.0 * f3)
    return out.T


@lru_cache(maxsize=None)
def shape_table() -> ShapeTable:
    """The table of :data:`TABLE_SHAPE` and :data:`TABLE_CURVATURE` (built once, about 10 ms), its lane
    form registered in :data:`plants.backend.LANE_INTRINSICS`."""
    t = ShapeTable(TABLE_SHAPE, TABLE_CURVATURE)
    LANE_INTRINSICS[t.name] = t.lane_c()
    return t


@lru_cache(maxsize=None)
def _casadi_function(table: ShapeTable):
    """The casadi function ``(u, C, E) -> F(u) / u`` (the formula), called as a ``never_inline`` node; its
    lane-kernel form (:meth:`ShapeTable.lane_c`) reads the table where the shape and curvature are the
    table's."""
    import casadi as ca
    v = ca.SX.sym("v", 3)
    u = v[0]
    return ca.Function(table.name, [v], [magic_formula_normalised(u, v[1], v[2], CASADI) / u], ["v"], ["ratio"],
                       {"never_inline": True})


def peak_normalised_slip(shape: float, curvature: float) -> float:
    """The normalised slip ``u`` at which ``F(u)`` peaks (numerically)."""
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda u: -magic_formula_normalised(np.array(u), shape, curvature, NUMPY),
                          bounds=(1e-3, 100.0), method="bounded", options={"xatol": 1e-10})
    return float(res.x)
