"""Cornering-stiffness identification from a sideslip estimate and the yaw rate (seed 001 sec. VI).

With the sideslip known (from the kinematic filter: course minus integrated heading),
each sample gives the axle slip angles of the bicycle model (ISO 8855 signs, docs/models.md)

    alpha_f = delta - beta - l_f r / v,        alpha_r = -beta + l_r r / v,

and the axle forces from the lateral and yaw balances

    F_f + F_r = m a_y,        l_f F_f - l_r F_r = I_z r' - N_z,

so ``F_f = (l_r m a_y + I_z r' - N_z) / L`` and ``F_r = (l_f m a_y - I_z r' + N_z) / L``.
The per-tire stiffness is the least-squares slope through the origin of ``F = 2 C alpha``
over the samples with enough slip. ``a_y`` is ``v (r + beta')`` (what the plane motion
needs, unaffected by body roll and road bank, which tilt an accelerometer; its
``beta'`` term is dropped: the sideslip estimate changes only at fixes) or the
accelerometer (``accel=True``); on a banked road ``bank`` [rad, left side up] adds the
gravity the tires hold, ``g sin(bank)``. ``r'`` is the derivative of the gyro smoothed over
``smooth`` s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.params import G
from evstab.plants.errors import DataError


@dataclass(frozen=True)
class Stiffness:
    front: float
    """[N/rad] per tire."""
    rear: float
    samples_front: int
    samples_rear: int
    fit_front: float
    """R^2 of the front fit (through the origin)."""
    fit_rear: float


def _smooth(x, n):
    if n <= 1:
        return np.asarray(x, float)
    k = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")


def _slope(alpha, force):
    c2 = float(np.dot(alpha, force) / np.dot(alpha, alpha))
    res = force - c2 * alpha
    r2 = 1.0 - float(np.dot(res, res) / np.dot(force, force))
    return c2 / 2.0, r2


def _samples(p, t, speed, steer, yaw_rate, beta, ay, yaw_moment, rows, accel, bank, min_slip, min_speed, smooth):
    """Slip angles, axle forces and the usable samples of each axle (see the module docstring)."""
    t, v, d, r, b = (np.asarray(a, float) for a in (t, speed, steer, yaw_rate, beta))
    dt = float(np.median(np.diff(t)))
    rs = _smooth(r, max(1, int(round(smooth / dt))))
    rdot = np.gradient(rs, t)
    if accel:
        if ay is None:
            raise DataError("cornering_stiffness: accel=True needs the lateral acceleration")
        a_y = np.asarray(ay, float)
    else:
        a_y = v * r
    if bank is not None:  # on a side slope the tires also hold the car against gravity (bank > 0: left up)
        a_y = a_y + G * np.sin(np.asarray(bank, float))
    nz = np.zeros_like(t) if yaw_moment is None else np.nan_to_num(np.asarray(yaw_moment, float))
    m, iz, lf, lr = p.mass, p.yaw_inertia, p.lf, p.lr
    L = lf + lr
    vv = np.maximum(v, min_speed)
    f_f = (lr * m * a_y + iz * rdot - nz) / L
    f_r = (lf * m * a_y - iz * rdot + nz) / L
    al_f = d - b - lf * r / vv
    al_r = -b + lr * r / vv
    sel = np.isfinite(b) & (v >= min_speed)
    if rows is not None:
        mask = np.zeros(len(t), bool)
        mask[np.asarray(rows)] = True
        sel &= mask
    return (al_f, f_f, sel & (np.abs(al_f) >= min_slip)), (al_r, f_r, sel & (np.abs(al_r) >= min_slip))


def cornering_stiffness(p: VehicleParams, t, speed, steer, yaw_rate, beta, *, ay=None, yaw_moment=None,
                        rows=None, accel: bool = False, bank=None, min_slip: float = np.radians(0.3),
                        min_speed: float = 5.0, smooth: float = 0.1) -> Stiffness:
    """Per-tire cornering stiffness of both axles from one run (mass, inertia and axle positions
    from ``p``; ``rows`` selects samples, e.g. the fixes at which a kinematic sideslip is fresh)."""
    (al_f, f_f, sf), (al_r, f_r, sr) = _samples(p, t, speed, steer, yaw_rate, beta, ay, yaw_moment, rows, accel,
                                                bank, min_slip, min_speed, smooth)
    if sf.sum() < 10 or sr.sum() < 10:
        raise DataError(f"cornering_stiffness: too few samples with slip above {np.degrees(min_slip):.2f} deg "
                         f"(front {int(sf.sum())}, rear {int(sr.sum())}; at least 10 each): the run must turn")
    cf, r2f = _slope(al_f[sf], f_f[sf])
    cr, r2r = _slope(al_r[sr], f_r[sr])
    return Stiffness(cf, cr, int(sf.sum()), int(sr.sum()), r2f, r2r)


def cornering_stiffness_online(p: VehicleParams, t, speed, steer, yaw_rate, beta, *, forgetting: float = 1.0,
                               **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """The same estimate as it evolves, sample by sample (recursive least squares through the origin:
    ``C = sum(lambda^j alpha F) / (2 sum(lambda^j alpha^2))`` over the usable samples so far, each
    older usable sample weighted by ``forgetting`` once more). Per-tire front and rear arrays over
    ``t``, NaN until an axle has 10 usable samples; with ``forgetting`` 1 the last value is
    :func:`cornering_stiffness`'s."""
    import scipy.signal

    if not 0 < forgetting <= 1:
        raise DataError(f"cornering_stiffness_online: forgetting must be in (0, 1], got {forgetting!r}")
    out = []
    for al, f, s in _samples(p, t, speed, steer, yaw_rate, beta, kwargs.get("ay"), kwargs.get("yaw_moment"),
                             kwargs.get("rows"), kwargs.get("accel", False), kwargs.get("bank"),
                             kwargs.get("min_slip", np.radians(0.3)), kwargs.get("min_speed", 5.0),
                             kwargs.get("smooth", 0.1)):
        idx = np.flatnonzero(s)
        c = np.full(len(al), np.nan)
        if len(idx):
            num = scipy.signal.lfilter([1.0], [1.0, -forgetting], al[idx] * f[idx])
            den = scipy.signal.lfilter([1.0], [1.0, -forgetting], al[idx] ** 2)
            est = num / (2.0 * den)
            est[:9] = np.nan
            pos = np.searchsorted(idx, np.arange(len(al)), side="right") - 1  # last usable sample so far
            c = np.where(pos >= 0, est[np.maximum(pos, 0)], np.nan)
        out.append(c)
    return out[0], out[1]
