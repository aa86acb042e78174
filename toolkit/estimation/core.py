"""The Kalman predict and update, written once for numpy and casadi; every estimator uses them.

* :func:`predict`: ``x <- F x + w``, ``P <- F P F^T + Q`` (``w`` the input's contribution), or, with
  :func:`predict_delta`, the same with ``F = I + E`` carried as ``E`` (the 1 kHz filters, whose
  ``F`` is the identity to within ``1e-3``: ``x + E x`` and ``P + E P + P E^T + E P E^T`` keep the
  small part's low digits that ``F`` itself would round away).
* :func:`scalar_update`: one scalar measurement in Joseph form,
  ``(I - K h) P (I - K h)^T + K r K^T``, with an optional 0/1 gate that makes a conditional
  update without a branch.
* :func:`posterior`: the same Joseph form for a vector measurement, on numbers (the design-time
  analyses: steady-state and periodic covariances).

Covariances are kept exactly symmetric: the upper triangle is computed and mirrored (which also
halves the work in generated code). ``o`` is :data:`plants.backend.NUMPY` or ``CASADI``; ``n``
the state dimension.
"""

from __future__ import annotations

import numpy as np

from evstab.plants.backend import CASADI, NUMPY


def column(v, o=NUMPY):
    """A column of numbers (or, for casadi, of numbers and symbols: tuned noise intensities)."""
    if o is CASADI:
        import casadi as ca
        return ca.vertcat(*[ca.SX(e) if isinstance(e, ca.SX) else float(e) for e in v])
    return np.asarray(v, float)


def unit(n: int, i: int, o=NUMPY):
    """The ``i``-th unit vector of length ``n`` (a measurement row that reads state ``i``)."""
    return column(np.eye(n)[i], o)


def dot(a, b, o=NUMPY):
    """``a^T b`` of two columns."""
    return (a.T @ b) if o is CASADI else a @ b


def diag(q, o=NUMPY):
    if o is CASADI:
        import casadi as ca
        return ca.diag(q)
    return np.diag(q)


def _mirror(entry, P, n, o):
    """The symmetric matrix whose upper triangle is ``entry(i, j)`` (numpy: ``entry`` is the
    whole matrix, its upper triangle kept)."""
    if o is not CASADI:
        D = np.triu(entry)
        return D + np.triu(D, 1).T
    import casadi as ca
    out = ca.SX.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            e = entry(i, j)
            out[i, j] = e
            out[j, i] = e
    return out


def predict(x, P, F, Q, o=NUMPY, n=None, w=None):
    """``(F x + w, F P F^T + Q)`` (``w`` None: no input term)."""
    n = P.shape[0] if n is None else n
    x = F @ x if w is None else F @ x + w
    if o is CASADI:
        M = F @ P
        return x, _mirror(lambda i, j: _dot_rows(M, F, i, j) + Q[i, j], P, n, o)
    return x, _mirror(F @ P @ F.T + Q, P, n, o)


def _dot_rows(M, F, i, j):
    import casadi as ca
    return ca.dot(M[i, :].T, F[j, :].T)


def predict_delta(x, P, E, Q, o=NUMPY, n=None, w=None):
    """:func:`predict` with ``F = I + E``: ``(x + E x + w, P + (M + M^T + M E^T) + Q)``, ``M = E P``."""
    n = P.shape[0] if n is None else n
    x = x + (E @ x if w is None else E @ x + w)
    M = E @ P
    if o is CASADI:
        import casadi as ca
        return x, _mirror(lambda i, j: P[i, j] + (M[i, j] + M[j, i] + ca.dot(M[i, :].T, E[j, :].T)) + Q[i, j],
                          P, n, o)
    return x, _mirror(P + (M + M.T + M @ E.T) + Q, P, n, o)


def scalar_update(x, P, h, innov, r, o=NUMPY, n=None, gate=None, scale=None):
    """Scalar measurement update in Joseph form; returns ``(x, P, S, K)``.

    ``(I - K h) P (I - K h)^T + K r K^T`` is evaluated in its expanded, O(n^2) form
    ``P - K m^T - m K^T + (h m + r) K K^T`` with ``m = P h^T``: the same expression for
    any gain ``K`` (so it keeps the Joseph form's validity and exact symmetry) without
    the two n x n x n products. ``gate`` (0 or 1, number or symbol) multiplies the gain:
    with 0 the update leaves ``x`` and ``P`` exactly as they were, with 1 it is the
    plain update, so a conditional update needs no selection of every element.
    ``scale`` (a column, None: all 1) multiplies the gain entry by entry: 0 for a state makes it a
    consider state (Schmidt): the update leaves its estimate as it is while its covariance and its
    correlations with the rest stay right for the gain used (the Joseph form holds for any gain).
    The returned ``K`` is the ungated gain.
    """
    n = P.shape[0] if n is None else n
    m = P @ h
    S = dot(h, m, o) + r
    K = m * (1.0 / S)
    Kg = K if gate is None else K * gate
    if scale is not None:
        Kg = Kg * scale
    if o is CASADI:
        Pn = _mirror(lambda i, j: P[i, j] - Kg[i] * m[j] - m[i] * Kg[j] + Kg[i] * Kg[j] * S, P, n, o)
    else:
        Pn = _mirror(P - np.outer(Kg, m) - np.outer(m, Kg) + np.outer(Kg, Kg) * S, P, n, o)
    return x + Kg * innov, Pn, S, K


def posterior(P, H, R):
    """The a-posteriori covariance of a vector measurement ``H`` with noise ``R`` (numbers), Joseph
    form ``(I - K H) P (I - K H)^T + K R K^T`` with the optimal ``K = P H^T (H P H^T + R)^-1``;
    returns ``(P_post, K)``."""
    P, H, R = (np.atleast_2d(np.asarray(a, float)) for a in (P, H, R))
    S = H @ P @ H.T + R
    K = np.linalg.solve(S.T, (P @ H.T).T).T
    IKH = np.eye(P.shape[0]) - K @ H
    Pn = IKH @ P @ IKH.T + K @ R @ K.T
    return 0.5 * (Pn + Pn.T), K
