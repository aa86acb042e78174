"""Speed scheduling by table interpolation: the lateral model's coefficients on a speed grid.

Firmware does not evaluate the bicycle model's rational functions of speed; it reads
them from tables. :class:`SpeedSchedule` holds, on a grid in ``x = 1 / v``, the rows
:data:`ROWS`: the seven coefficients of :func:`plants.bicycle.lateral_coefficients`
and the reference model's steady-state gains (seed 003 eq. 23-24).

Interpolation rule (the one the exported C uses): ``x = 1 / v`` is clamped to the
grid, then each row is interpolated linearly in ``x`` between the two neighbouring
grid points. In ``x`` the coefficients ``a11``, ``a22`` and ``b11`` are exactly
linear and ``a21``, ``b21``, ``b22`` constant, so the table reproduces them to
rounding; ``a12 = -1 + c x^2`` and the reference gains carry the interpolation error
(bounded by ``max|f''| h^2 / 8``; :meth:`SpeedSchedule.max_error` measures it).

With numbers the segment is looked up (the exported C does the same); with casadi
symbols the same interpolation is written as a sum over the grid's hat functions,
``w_i = max(0, min((x - x_{i-1}) / (x_i - x_{i-1}), (x_{i+1} - x) / (x_{i+1} - x_i)))``.
Traced inside :func:`plants.backend.call_nodes`, the sums go into one casadi function per table that the
trace calls (a ``never_inline`` call node), which a lane kernel (:mod:`toolkit.kernels.lanes`) runs
as the segment lookup, the firmware's arithmetic, instead of the 32-term sums; elsewhere
(differentiation, casadi's code generation) they stay inline. Any strictly increasing axis
works.

Notes
-----
Estimator and controller designs that carry a schedule use it instead of the exact
model: it is the firmware's model, so evstab's replay and the exported C run the
same arithmetic.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.backend import LANE_INTRINSICS, NUMPY, tracing_call_nodes
from evstab.plants.bicycle import lateral_coefficients, steady_state_gains
from evstab.plants.errors import ModelError

ROWS = ("a11", "a12", "a21", "a22", "b11", "b21", "b22", "k_beta_ss", "k_gamma_ss")
UNITS = ("1/s", "-", "1/s^2", "1/s", "1/s", "1/s^2", "1/(kg m^2)", "-", "1/s")
DESCRIPTIONS = (
    "beta' per beta", "beta' per yaw rate", "yaw rate' per beta", "yaw rate' per yaw rate",
    "beta' per front steer", "yaw rate' per front steer", "yaw rate' per yaw moment",
    "reference sideslip per road-wheel angle (steady state)", "reference yaw rate per road-wheel angle (steady state)")
RULE = ("x = 1/speed clamped to [inv_speed[0], inv_speed[-1]]; each row interpolated linearly in x between the two "
        "neighbouring grid points")


@dataclass(frozen=True)
class SpeedTable:
    """Rows tabulated over inverse speed and read by the interpolation rule :data:`RULE` (frozen,
    hashable). :class:`SpeedSchedule` is the lateral model's table; a filter's transition over one
    control period (:mod:`toolkit.estimation.transition`) is another on the same grid."""

    inv_speed: tuple[float, ...]
    """Grid of ``x = 1 / v`` [s/m], strictly increasing."""
    table: tuple[tuple[float, ...], ...]
    """The rows, one value per grid point."""

    def __post_init__(self):
        x = np.asarray(self.inv_speed, float)
        if x.ndim != 1 or len(x) < 2 or not np.all(np.isfinite(x)) or not np.all(np.diff(x) > 0) or x[0] <= 0:
            raise ModelError(f"speed schedule: 'inv_speed' must be >= 2 finite, positive, strictly increasing "
                             f"values [s/m], got {self.inv_speed!r}")
        if not self.table or any(len(r) != len(x) for r in self.table):
            raise ModelError(f"speed schedule: 'table' must have rows of {len(x)} values each")
        if not all(np.all(np.isfinite(r)) for r in self.table):
            raise ModelError("speed schedule: 'table' holds a value that is not finite")

    @property
    def speeds(self) -> np.ndarray:
        """The grid as speeds [m/s] (decreasing)."""
        return 1.0 / np.asarray(self.inv_speed)

    def values(self, v, o=NUMPY) -> tuple:
        """All rows at speed ``v`` [m/s]: numbers (``v`` scalar or array) or casadi symbols.

        With numbers the segment holding ``x`` is found and ``r_i + t (r_{i+1} - r_i)``,
        ``t = (x - x_i) / (x_{i+1} - x_i)``, evaluated: the exported C's arithmetic. With
        casadi symbols the same interpolation is the sum over the hat functions.
        """
        ax = np.asarray(self.inv_speed)
        n = len(ax)
        if o is NUMPY:
            x = np.clip(1.0 / np.maximum(np.asarray(v, float), 1e-300), ax[0], ax[-1])
            i = np.clip(np.searchsorted(ax, x, side="right") - 1, 0, n - 2)
            t = (x - ax[i]) / (ax[i + 1] - ax[i])
            tab = np.asarray(self.table)
            return tuple(tab[r, i] + t * (tab[r, i + 1] - tab[r, i]) for r in range(len(self.table)))
        if not tracing_call_nodes():
            return self._hat_sums(v, o)
        out = _casadi_function(self)(v)
        return tuple(out[r] for r in range(len(self.table)))

    def _hat_sums(self, v, o) -> tuple:
        ax = np.asarray(self.inv_speed)
        n = len(ax)
        x = o.fmin(o.fmax(1.0 / v, ax[0]), ax[n - 1])
        weights = []
        for i in range(n):
            left = (x - ax[i - 1]) / (ax[i] - ax[i - 1]) if i > 0 else None
            right = (ax[i + 1] - x) / (ax[i + 1] - ax[i]) if i < n - 1 else None
            w = right if left is None else left if right is None else o.fmin(left, right)
            weights.append(o.fmax(0.0, o.fmin(w, 1.0)))
        out = []
        for row in self.table:
            acc = weights[0] * row[0]
            for i in range(1, n):
                acc = acc + weights[i] * row[i]
            out.append(acc)
        return tuple(out)

    def lane_c(self, name: str) -> str:
        """C of the segment lookup on lane vectors (``EV_INLINE void name(const vd* in, vd* out)``,
        ``in[0]`` the speed): the numpy branch of :meth:`values` and the exported C, operation for
        operation, with ``x = 1 / v`` clamped as the casadi branch does."""
        n, nr = len(self.inv_speed), len(self.table)
        ax = ", ".join(repr(float(a)) for a in self.inv_speed)
        tab = ",\n        ".join(", ".join(repr(float(t)) for t in row) for row in self.table)
        return f"""EV_INLINE void {name}(const vd* in, vd* out) {{
    static const double ax[{n}] = {{{ax}}};
    static const double tab[{nr}][{n}] = {{
        {tab}}};
    vd x = ev_fmin(ev_fmax(1.0 / in[0], ev_splat(ax[0])), ev_splat(ax[{n - 1}]));
    vl i = (vl){{0}};
    for (int j = 1; j < {n - 1}; j++) i -= (vl)(x >= ev_splat(ax[j]));
    vd lo, hi;
    for (int l = 0; l < EV_W; l++) {{ lo[l] = ax[i[l]]; hi[l] = ax[i[l] + 1]; }}
    vd t = (x - lo) / (hi - lo);
    for (int r = 0; r < {nr}; r++) {{
        vd a, b;
        for (int l = 0; l < EV_W; l++) {{ a[l] = tab[r][i[l]]; b[l] = tab[r][i[l] + 1]; }}
        out[r] = a + t * (b - a);
    }}
}}
"""



@dataclass(frozen=True)
class SpeedSchedule(SpeedTable):
    """Lateral-model coefficients tabulated over inverse speed: the rows :data:`ROWS`."""

    def __post_init__(self):
        super().__post_init__()
        if len(self.table) != len(ROWS):
            raise ModelError(f"speed schedule: 'table' must have {len(ROWS)} rows ({', '.join(ROWS)}) of "
                             f"{len(self.inv_speed)} values each")

    @classmethod
    def build(cls, p: VehicleParams, v_min: float = 2.0, v_max: float = 70.0, n: int = 32) -> "SpeedSchedule":
        """Tabulate ``p``'s coefficients at ``n`` speeds spaced geometrically from ``v_max`` to ``v_min`` [m/s].

        Geometric spacing (constant ratio between neighbours) keeps the relative
        interpolation error of ``a12`` and the reference gains alike across speeds: with
        32 points from 2 to 70 m/s it is below 0.4 % for the bundled vehicles, against
        2-8 % for the same number of points uniform in speed or in ``1 / v``.
        """
        if not (0 < v_min < v_max and n >= 2):
            raise ModelError(f"speed schedule needs 0 < v_min < v_max and n >= 2, got {v_min}, {v_max}, {n}")
        x = 1.0 / np.geomspace(v_max, v_min, n)
        cols = [list(lateral_coefficients(p, 1.0 / xi)) + list(steady_state_gains(p, 1.0 / xi)) for xi in x]
        rows = np.array(cols, float).T
        return cls(tuple(float(v) for v in x), tuple(tuple(float(v) for v in r) for r in rows))


    def max_error(self, p: VehicleParams, points: int = 2000) -> dict:
        """Largest relative interpolation error of each row against the exact model between the grid's ends."""
        x = np.linspace(self.inv_speed[0], self.inv_speed[-1], points)
        exact = np.array([list(lateral_coefficients(p, 1.0 / xi)) + list(steady_state_gains(p, 1.0 / xi))
                          for xi in x]).T
        approx = np.array([self.values(1.0 / xi) for xi in x]).T
        scale = np.max(np.abs(exact), axis=1)
        return {name: float(np.max(np.abs(approx[r] - exact[r])) / scale[r]) if scale[r] > 0 else 0.0
                for r, name in enumerate(ROWS)}

    def to_dict(self) -> dict:
        return {"inv_speed_s_per_m": list(self.inv_speed), "speeds_m_per_s": [float(s) for s in self.speeds],
                "rule": RULE, "rows": {name: list(self.table[r]) for r, name in enumerate(ROWS)},
                "units": dict(zip(ROWS, UNITS))}

    @classmethod
    def from_dict(cls, doc: dict) -> "SpeedSchedule":
        try:
            rows = doc["rows"]
            return cls(tuple(float(v) for v in doc["inv_speed_s_per_m"]),
                       tuple(tuple(float(v) for v in rows[name]) for name in ROWS))
        except KeyError as e:
            raise ModelError(f"speed schedule: missing field {e}") from None
        except (TypeError, ValueError) as e:
            raise ModelError(f"speed schedule: {e}") from None


@lru_cache(maxsize=64)
def _casadi_function(sched: SpeedTable):
    """The casadi function ``v -> rows`` of a table (the hat sums), called as a ``never_inline``
    node; its lane-kernel form is registered under the same name."""
    import casadi as ca
    from evstab.plants.backend import CASADI
    name = "evstab_schedule_" + hashlib.sha256(repr((sched.inv_speed, sched.table)).encode()).hexdigest()[:16]
    v = ca.SX.sym("v")
    fn = ca.Function(name, [v], [ca.vertcat(*sched._hat_sums(v, CASADI))], ["v"], ["rows"], {"never_inline": True})
    LANE_INTRINSICS[name] = sched.lane_c(name)
    return fn
