"""The ECU filter's transition over one control period, tabulated on the speed schedule's grid.

A filter without tables re-discretises its lateral model at the current speed every period
(:func:`toolkit.estimation.kalman.discretize_delta`, a 4th-order Taylor series: about a
quarter of the ECU step's arithmetic). The ECU's filter runs at one period ``T`` and reads
its model from the speed schedule anyway, so the discretisation is done once, at export
time, for every grid point of the schedule: exactly (the matrix exponential's series summed
to rounding), from that grid point's coefficient rows. Per period the filter then
interpolates

* ``E = e^(A T) - I`` (its structurally non-zero entries: the sideslip, yaw-rate and heading
  rows; the disturbances' own decay is one constant row pair), and
* ``G = (int_0^T e^(A s) ds) B`` (the inputs' effect over the period),

linearly in ``1 / v`` by the schedule's rule (:data:`controllers.schedule.RULE`). Below the
filter's minimum speed the lateral model is held (``psi' = r`` only, as
:func:`toolkit.estimation.spec.continuous_model` holds it).

A period ``dt`` other than ``T`` scales both by ``dt / T`` (first order in the jitter:
the error in ``F`` is at most ``|dt / T - 1| |A T|^2 / 2`` per entry).

Accuracy (measured by ``tests/toolkit/test_transition.py``): at the grid points the table
equals scipy's ``expm`` to 1e-14 of the largest entry; between them the interpolated ``E`` differs from
the Taylor step at the interpolated coefficients by the interpolation error of the
coefficients themselves (the schedule's own ``max_error``), and a closed-loop log with the
tabulated step differs from the Taylor step's by the bounds that test asserts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.controllers.schedule import SpeedTable
from evstab.plants.backend import NUMPY
from evstab.plants.errors import ModelError

SERIES_TERMS = 30
"""Terms of the exponential's series at a grid point: ``|A T| < 1`` for every bundled vehicle at
1 kHz, so 30 terms leave a remainder far below double rounding (checked against ``expm``)."""


@dataclass(frozen=True)
class Transition:
    """``E`` and ``G`` entries of one filter on a speed grid, for the control period ``dt``."""

    dt: float
    """The control period ``T`` [s] the table is for."""
    n: int
    """The filter's state count."""
    e_entries: tuple[tuple[int, int], ...]
    """(row, column) of the tabulated entries of ``E``."""
    g_entries: tuple[tuple[int, int], ...]
    """(row, input) of the tabulated entries of ``G`` (inputs: steer, yaw moment)."""
    table: SpeedTable
    """A :class:`controllers.schedule.SpeedTable` with the ``E`` rows then the ``G`` rows (or, inside a
    traced ECU step, the rows already read at this period's speed)."""
    held: tuple[tuple[int, int, float], ...]
    """(row, column, value) of ``E`` with the lateral model held (below the minimum speed)."""
    a_entries: tuple[tuple[int, int], ...] = ()
    """(row, column) of continuous ``A`` entries tabulated after ``G`` (the sideslip row, for a filter
    with the kinematic path: it compares the model's lateral acceleration with the measured one)."""
    b_entries: tuple[tuple[int, int], ...] = ()
    """(row, input) of continuous ``B`` entries tabulated after those."""

    @property
    def names(self) -> tuple[str, ...]:
        """Row names: ``E_i_j`` and ``G_i_k`` (state and input indices)."""
        return tuple(f"E_{i}_{j}" for i, j in self.e_entries) + tuple(f"G_{i}_{k}" for i, k in self.g_entries) \
            + tuple(f"A_{i}_{j}" for i, j in self.a_entries) + tuple(f"B_{i}_{k}" for i, k in self.b_entries)

    def continuous(self, rows, dynamic, o=NUMPY):
        """The tabulated continuous entries from ``rows`` (this period's reads of :attr:`table`):
        ``{(i, j): A_ij}``, ``{(i, k): B_ik}``, gated by ``dynamic`` as the model is."""
        k = len(self.e_entries) + len(self.g_entries)
        a = {e: dynamic * rows[k + m] for m, e in enumerate(self.a_entries)}
        k += len(self.a_entries)
        return a, {e: dynamic * rows[k + m] for m, e in enumerate(self.b_entries)}

    def matrices(self, v, dt, dynamic, o=NUMPY, rows=None):
        """``(E, G)`` at speed ``v`` (the filter's, already at least its minimum speed) for the period
        ``dt``; ``dynamic`` 0/1 (number or symbol): the lateral model acts (1) or is held (0).
        ``rows``: the table already read at ``v``."""
        rows = self.table.values(v, o) if rows is None else rows
        r = dt * (1.0 / self.dt)  # 1 at the control period
        on = r * dynamic  # r or 0: one product per entry
        off = r * (1.0 - dynamic)
        held = {(i, j): h for i, j, h in self.held}
        E = o.zeros(self.n, self.n)
        for (i, j), val in zip(self.e_entries, rows):
            h = held.get((i, j), 0.0)
            E[i, j] = on * val if h == 0.0 else on * val + off * h
        G = o.zeros(self.n, 2)
        for (i, k), val in zip(self.g_entries, rows[len(self.e_entries):]):
            G[i, k] = on * val
        for i, j, h in self.held:  # held entries the moving model lacks
            if (i, j) not in self.e_entries:
                E[i, j] = off * h
        return E, G


def exact_discretisation(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^(A dt) - I, int_0^dt e^(A s) ds B)`` by the exponential's series to :data:`SERIES_TERMS` terms
    (``E`` without forming ``I + ...``, as the filter propagates it)."""
    M = np.asarray(A, float) * dt
    if np.abs(M).sum(axis=1).max() >= 1.0:
        raise ModelError(f"transition table: |A dt| = {np.abs(M).sum(axis=1).max():.3g} >= 1; the series would "
                         "converge slowly (a control period this long needs scaling and squaring)")
    n = M.shape[0]
    term = np.eye(n)
    E = np.zeros((n, n))
    gam = np.eye(n) * dt
    for k in range(1, SERIES_TERMS):
        term = term @ M / k  # M^k / k!
        E = E + term
        gam = gam + term * (dt / (k + 1))
    return E, gam @ np.asarray(B, float)
