"""Linear time-invariant models with named signals, continuous and discrete.

Continuous and discrete time are different types (as in ``scipy.signal``);
mixing them is an error. A discrete model remembers its sample time and the
discretisation method. ``to_control()`` hands python-control a named ``ss``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .errors import ModelError


def _frozen(a) -> np.ndarray:
    arr = np.array(a, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class _LTIBase:
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]

    def __post_init__(self) -> None:
        for name in "ABCD":
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        n, m, q = len(self.states), len(self.inputs), len(self.outputs)
        for name, shape in (("A", (n, n)), ("B", (n, m)), ("C", (q, n)), ("D", (q, m))):
            if getattr(self, name).shape != shape:
                raise ModelError(f"{name} has shape {getattr(self, name).shape}, expected {shape} "
                                 f"for states {self.states}, inputs {self.inputs}, outputs {self.outputs}")

    def index(self, kind: str, name: str) -> int:
        names = getattr(self, kind)
        try:
            return names.index(name)
        except ValueError:
            raise ModelError(f"no {kind[:-1]} named '{name}'; available: {', '.join(names)}") from None

    def select(self, inputs=None, outputs=None):
        """The same model restricted to some inputs and outputs, by name."""
        inputs = tuple(inputs) if inputs is not None else self.inputs
        outputs = tuple(outputs) if outputs is not None else self.outputs
        iu = [self.index("inputs", n) for n in inputs]
        iy = [self.index("outputs", n) for n in outputs]
        return self._replace(B=self.B[:, iu], C=self.C[iy, :], D=self.D[np.ix_(iy, iu)],
                             inputs=inputs, outputs=outputs)

    def _replace(self, **kw):
        import dataclasses
        return dataclasses.replace(self, **kw)


@dataclass(frozen=True)
class ContinuousLTI(_LTIBase):
    """``x' = A x + B u``, ``y = C x + D u`` with named states, inputs and outputs."""

    def discretize(self, dt: float, method: str = "zoh") -> "DiscreteLTI":
        """Exact zero-order-hold discretisation (block matrix exponential).

        ``[[A, B], [0, 0]] * dt`` exponentiates to ``[[Ad, Bd], [0, I]]`` with
        ``Ad = e^(A dt)`` and ``Bd = int_0^dt e^(A s) ds B`` (seed 003 eq. 13).
        """
        if method != "zoh":
            raise ModelError(f"I don't know the discretisation method '{method}'. But I know: 'zoh'")
        if not (dt > 0.0 and np.isfinite(dt)):
            raise ModelError(f"sample time must be a positive finite number, got {dt!r}")
        n, m = self.B.shape
        block = np.zeros((n + m, n + m))
        block[:n, :n] = self.A
        block[:n, n:] = self.B
        e = scipy.linalg.expm(block * dt)
        return DiscreteLTI(A=e[:n, :n], B=e[:n, n:], C=self.C, D=self.D, states=self.states,
                           inputs=self.inputs, outputs=self.outputs, dt=float(dt), method=method)

    def to_control(self, name: str | None = None):
        """A python-control ``StateSpace`` carrying the signal names."""
        import control
        return control.ss(self.A, self.B, self.C, self.D, states=list(self.states),
                          inputs=list(self.inputs), outputs=list(self.outputs), name=name)

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)


@dataclass(frozen=True)
class DiscreteLTI(_LTIBase):
    """``x[k+1] = A x[k] + B u[k]`` sampled at ``dt`` seconds, made by ``method``."""

    dt: float = field(default=0.0)
    method: str = field(default="zoh")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.dt > 0.0:
            raise ModelError(f"a discrete model needs a positive sample time, got {self.dt!r}")

    def discretize(self, dt: float, method: str = "zoh"):
        raise ModelError(f"this model is already discrete (dt = {self.dt} s, method '{self.method}')")

    def to_control(self, name: str | None = None):
        """A python-control discrete ``StateSpace`` (dt set) carrying the signal names."""
        import control
        return control.ss(self.A, self.B, self.C, self.D, self.dt, states=list(self.states),
                          inputs=list(self.inputs), outputs=list(self.outputs), name=name)

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)
