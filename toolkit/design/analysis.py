"""Design analysis across a speed grid, as a tidy table (one row per speed).

For a vehicle, an estimator design and a controller design: observability of the
estimator (rank, smallest singular-value ratio, unobservable directions by name),
the estimator's periodic poles (eigenvalues of its error monodromy over one GPS
period, as per-second rates), the controller's and the nominal loop's poles,
internal stability, loop-at-a-time margins at the plant inputs, and the stability
of the sampled multi-rate loop with the estimator in it. Data only; reports draw it.
"""

from __future__ import annotations

import numpy as np

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import VehicleParams

from ..estimation.analysis import measurement_rows, observability, periodic_gains
from ..estimation.kalman import transition_matrix
from ..estimation.spec import FilterDesign
from .stability import channel_margins, estimator_loop, nominal_loop

SPEEDS_KMH = (10.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 140.0)


def estimator_periodic_poles(d: FilterDesign, v: float, gps_rate: float, dt: float) -> np.ndarray:
    """Eigenvalues of the estimation-error monodromy over one GPS period, as continuous rates [1/s].

    The a-priori error of a Kalman filter evolves as ``e+ = F (I - K C) e`` per sample; the
    product over the period with the periodic gains, ``ln(lambda) / T_gps``.
    """
    F = transition_matrix(d, v, dt)
    C = measurement_rows(d, v)
    gains, _ = periodic_gains(d, v, gps_rate, dt)
    M = np.eye(d.n)
    for k, K in enumerate(gains):
        Ck = C if k == 0 else C[:1]
        M = F @ (np.eye(d.n) - K @ Ck) @ M
    lam = np.linalg.eigvals(M).astype(complex)
    return np.log(lam) * gps_rate


def speed_grid(params: VehicleParams, est: FilterDesign, ctl: TwoDofDesign, speeds_kmh=SPEEDS_KMH,
               gps_rate: float = 5.0, dt: float = 1e-3) -> list[dict]:
    rows = []
    for kmh in speeds_kmh:
        v = kmh / 3.6
        obs = observability(est, v)
        loop, st = nominal_loop(ctl, v, params)
        margins = {m.channel: m for m in channel_margins(loop)}
        try:
            slowest = float(np.max(estimator_periodic_poles(est, v, gps_rate, dt).real))
            _, mr = estimator_loop(ctl, est, v, true_params=params, gps_rate=gps_rate, dt=dt)
            mr_stable, mr_rho, riccati = mr.stable, 1.0 - mr.margin, "ok"
        except np.linalg.LinAlgError:  # no stabilising Riccati solution: the design is not detectable
            slowest, mr_stable, mr_rho, riccati = float("nan"), False, float("nan"), "no stabilising solution"
        rows.append({
            "speed_kmh": kmh,
            "observable": obs.observable, "observability_rank": obs.rank,
            "observability_sv_ratio": obs.smallest_singular_value,
            "unobservable": "; ".join(" ".join(f"{k}={val:.3g}" for k, val in dd.items())
                                      for dd in obs.unobservable) or "-",
            "riccati": riccati, "estimator_slowest_rate_1_s": slowest,
            "loop_poles": " ".join(f"{z.real:.3g}{z.imag:+.3g}j" for z in st.poles),
            "internally_stable": st.stable, "loop_margin_1_s": st.margin,
            "gm_delta_db": margins["delta"].gm_db, "pm_delta_deg": margins["delta"].pm_deg,
            "gm_nz_db": margins["Nz"].gm_db, "pm_nz_deg": margins["Nz"].pm_deg,
            "disk_margin_min": min(m.disk_margin for m in margins.values()),
            "sensitivity_peak_max": max(m.sensitivity_peak for m in margins.values()),
            "multirate_stable": mr_stable, "multirate_spectral_radius": mr_rho,
        })
    return rows
