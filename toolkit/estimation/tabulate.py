"""The ECU filter's transition table built from its design: the lateral model
(:func:`toolkit.estimation.spec.continuous_model`) discretised exactly at each grid point of the speed schedule
for the control period (:func:`toolkit.estimation.transition.exact_discretisation`), as
:class:`toolkit.estimation.transition.Transition` holds and propagates it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from evstab.controllers.schedule import SpeedTable
from evstab.plants.backend import NUMPY

from .spec import continuous_model
from .transition import Transition, exact_discretisation


def build_transition(d, schedule, dt: float) -> Transition:
    """The transition table of filter design ``d`` on ``schedule``'s grid (its coefficient rows at
    each grid point) for the control period ``dt`` (cached by what it depends on)."""
    key = (d.states, d.disturbance, float(d.noise.disturbance_tau), schedule, float(dt), bool(d.kinematic))
    hit = _CACHE.get(key)
    if hit is None:
        if len(_CACHE) > 32:
            _CACHE.clear()
        hit = _CACHE[key] = _build(dataclasses.replace(d, schedule=schedule, transition=None), schedule, float(dt))
    return hit


_CACHE: dict = {}


def _build(d, schedule, dt: float) -> Transition:
    As, Bs = (np.array(m) for m in zip(*(continuous_model(d, 1.0 / x, NUMPY, dynamic=True)
                                         for x in schedule.inv_speed)))
    Es, Gs = (np.array(m) for m in zip(*(exact_discretisation(A, B, dt) for A, B in zip(As, Bs))))
    e_idx = tuple((int(i), int(j)) for i, j in zip(*np.nonzero(np.any(Es != 0.0, axis=0))))
    g_idx = tuple((int(i), int(k)) for i, k in zip(*np.nonzero(np.any(Gs != 0.0, axis=0))))
    rows = [tuple(float(v) for v in Es[:, i, j]) for i, j in e_idx] + \
        [tuple(float(v) for v in Gs[:, i, k]) for i, k in g_idx]
    a_idx: tuple[tuple[int, int], ...] = ()
    b_idx: tuple[tuple[int, int], ...] = ()
    if d.kinematic:  # the sideslip row of the continuous model, which the kinematic path compares with a_y
        ib = d.index("beta")
        a_idx = tuple((ib, int(j)) for j in np.nonzero(np.any(As[:, ib] != 0.0, axis=0))[0])
        b_idx = tuple((ib, int(k)) for k in np.nonzero(np.any(Bs[:, ib] != 0.0, axis=0))[0])
        rows += [tuple(float(v) for v in As[:, i, j]) for i, j in a_idx] + \
            [tuple(float(v) for v in Bs[:, i, k]) for i, k in b_idx]
    A0, B0 = continuous_model(d, 1.0, NUMPY, dynamic=False)
    E0, _ = exact_discretisation(A0, B0, dt)
    held = tuple((int(i), int(j), float(E0[i, j])) for i, j in zip(*np.nonzero(E0)))
    return Transition(float(dt), d.n, e_idx, g_idx, SpeedTable(schedule.inv_speed, tuple(rows)), held, a_idx, b_idx)
