"""Named signal layouts: the one description of every vector that crosses a module boundary.

A :class:`Layout` names the entries of a vector (filter inputs and outputs, controller
signals, ECU inputs and outputs, loop and filter state), with units and meaning, and packs
and unpacks it for numpy (``(n,)``, or ``(n, N)`` for N cases at once, or ``(N, n)``
tables through :meth:`Layout.columns`) and casadi (column vectors). An entry may be a block
of several numbers (a covariance, a set of noise channels); its offset and slice come from
the layout, so no code outside this module indexes a signal vector by position.

A layout is a tuple of its entry names, so ``name in layout``, iteration and ``len`` read as
they would for the plain tuple of names.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from .errors import ModelError


@dataclass(frozen=True)
class Signal:
    """One entry of a :class:`Layout`."""

    name: str
    unit: str = "-"
    """SI unit (ISO 8855 signs), ``-`` for a number without one."""
    doc: str = ""
    size: int = 1
    """Numbers the entry takes (1 for a scalar; a block otherwise)."""
    ctype: str = "real"
    """``real`` or ``int``: how the firmware's C interface declares it."""
    default: float | None = None
    """Value :meth:`Layout.pack` puts where the entry is not given (None: it must be given, unless it
    is optional)."""
    optional: bool = False
    """May be left off the end of a vector (with every entry after it): a reader sees it as None."""


def _as_signal(s) -> Signal:
    if isinstance(s, Signal):
        return s
    if isinstance(s, str):
        return Signal(s)
    return Signal(*s)


def _length(vec) -> int:
    shape = getattr(vec, "shape", None)
    if shape is None:
        return len(vec)
    return int(shape[0])


class Layout(tuple[str, ...]):
    """An ordered set of named entries of a vector (see the module docstring).

    ``Layout("ecu inputs", [Signal("dt", "s", "..."), ...])``; entries may also be given as
    names or as ``(name, unit, doc)`` tuples.
    """

    title: str
    signals: tuple["Signal", ...]
    _offsets: dict[str, int]
    size: int

    def __new__(cls, title: str, signals):
        sigs = tuple(_as_signal(s) for s in signals)
        names = tuple(s.name for s in sigs)
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ModelError(f"layout '{title}': entries named twice: {', '.join(dup)}")
        self = super().__new__(cls, names)
        self.title = title
        self.signals = sigs
        offsets, k = {}, 0
        for s in sigs:
            if s.size < 0:
                raise ModelError(f"layout '{title}': entry '{s.name}' has negative size {s.size}")
            offsets[s.name] = k
            k += s.size
        self._offsets = offsets
        self.size = k
        """Numbers in the vector (the sum of the entries' sizes)."""
        return self

    def __reduce__(self):
        return (Layout, (self.title, self.signals))

    def __repr__(self):
        return f"Layout({self.title!r}, {tuple(self)!r})"

    # ---------------------------------------------------------------- where an entry lives
    def index(self, name: str) -> int:  # type: ignore[override]  # (tuple.index's meaning: the offset of ``name``)
        """Offset of entry ``name`` in the vector."""
        try:
            return self._offsets[name]
        except KeyError:
            raise ModelError(f"layout '{self.title}' has no entry '{name}'; entries: {', '.join(self)}") from None

    def slot(self, name: str) -> slice:
        """The slice of entry ``name`` in the vector."""
        i = self.index(name)
        return slice(i, i + self.signal(name).size)

    def span(self, first: str, last: str) -> slice:
        """The slice from entry ``first`` to entry ``last``, both included."""
        return slice(self.index(first), self.slot(last).stop)

    def signal(self, name: str) -> Signal:
        return self.signals[tuple.index(self, name)]

    def offsets(self) -> dict:
        """``{name: offset}`` and ``size``: the layout as a plain mapping (for a gains file)."""
        return {**self._offsets, "size": self.size}

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(s.unit for s in self.signals)

    # ---------------------------------------------------------------- vectors
    def _get(self, vec, s: Signal):
        i = self._offsets[s.name]
        return vec[i] if s.size == 1 else vec[i:i + s.size]

    def unpack(self, vec) -> SimpleNamespace:
        """The entries of ``vec`` as attributes (rows of an ``(n, N)`` array, casadi elements; a block
        as its slice). A shorter vector may leave off trailing optional entries: those read as None."""
        return SimpleNamespace(**self.as_dict(vec))

    def as_dict(self, vec) -> dict:
        """As :meth:`unpack`, a dict in layout order."""
        n = _length(vec)
        out, k = {}, 0
        for s in self.signals:
            if k + s.size > n:
                break
            out[s.name] = self._get(vec, s)
            k += s.size
        if k != n or not all(s.optional for s in self.signals[len(out):]):
            raise ModelError(f"layout '{self.title}': expected a vector of {self.size} numbers "
                             f"({', '.join(self)}), got length {n}")
        for s in self.signals[len(out):]:
            out[s.name] = None
        return out

    def pack(self, values: dict | None = None, o=None, like=None, fill=None, **kw):
        """The vector of ``values`` (a mapping and/or keywords) in layout order, numpy or casadi.

        Trailing optional entries not given are left off (a shorter vector: the reader sees them as
        None); any other entry not given takes its :attr:`Signal.default`, or ``fill`` when that is
        set. A scalar default becomes ``like * 0 + value`` so that it broadcasts with batched numpy
        values. Anything else missing, or a name the layout does not have, is an error.
        """
        from .backend import NUMPY
        o = NUMPY if o is None else o
        vals = dict(values or {}, **kw)
        unknown = [k for k in vals if k not in self._offsets]
        if unknown:
            raise ModelError(f"layout '{self.title}' has no entries {', '.join(unknown)}; entries: {', '.join(self)}")
        last = max((tuple.index(self, k) for k in vals), default=-1)
        items = []
        for j, s in enumerate(self.signals):
            if j > last and all(r.optional for r in self.signals[j:]):
                break
            if s.size == 0:
                continue
            if s.name in vals:
                v = vals[s.name]
            else:
                const = s.default if s.default is not None else fill
                if const is None:
                    raise ModelError(f"layout '{self.title}': entry '{s.name}' not given")
                v = const if like is None else like * 0.0 + const
                if s.size > 1:
                    v = o.stack([v] * s.size)
            items.append(v)
        if all(s.size == 1 for s in self.signals[:len(items)]):
            return o.stack(items)
        return o.concat(items)

    def zeros(self, rows: int | None = None) -> np.ndarray:
        """A zero vector, or a ``(rows, size)`` table of zeros."""
        return np.zeros(self.size) if rows is None else np.zeros((rows, self.size))

    def columns(self, table) -> dict:
        """The columns of an ``(N, size)`` table by entry name (numpy views: writing them fills the
        table; a block is its ``(N, k)`` slice)."""
        if table.ndim != 2 or table.shape[1] != self.size:
            raise ModelError(f"layout '{self.title}': expected a table of {self.size} columns "
                             f"({', '.join(self)}), got shape {table.shape}")
        return {s.name: (table[:, self._offsets[s.name]] if s.size == 1 else table[:, self.slot(s.name)])
                for s in self.signals}


def join(title: str, *parts: tuple[str, Layout]) -> Layout:
    """One layout of several after one another, each entry named ``prefix.name``."""
    sigs = []
    for prefix, lay in parts:
        sigs += [_renamed(s, f"{prefix}.{s.name}") for s in lay.signals]
    return Layout(title, sigs)


def _renamed(s: Signal, name: str) -> Signal:
    from dataclasses import replace
    return replace(s, name=name)
