"""What the ECU's actuators can reach in the envelope's friction drop (:mod:`toolkit.verdicts.reachable`):
the smallest peak sideslip a command sequence of the front steer correction and the rear motors gives on
the two-track compact-ev, free from a reaction time after the drop, against the default ECU (five noise
seeds) and the car alone.

The envelope's friction drop from 1.0 to 0.3 in a 0.5 g turn at 80 km/h is the one case where the default
ECU breaks the *stabilise* rule (:mod:`studies.control_envelope`). Commands are searched from 0.1 s before
the drop to the manoeuvre's end, free from 0.1-0.5 s after the drop, starting from the default ECU's run
(seed 0); each sequence found is replayed through the plant by scipy's ``solve_ivp`` and the replay's peak is
what the table gives.

Writes ``reachable.csv`` (one row per reaction time) and ``reachable_table.md``.
Run: ``python -m evstab.studies.control_reachable OUT_DIR [--quick]`` (29 min on 2 cores with four to six other jobs
running; quick, for the test suite: one reaction time, the window to 4 s, the ECU's seed 0 only).
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.toolkit.loop.simulator import simulate
from evstab.toolkit.verdicts import envelope as ev
from evstab.toolkit.verdicts import reachable as rc

CASE = ev.Case("friction-drop", 80, 1.0, 0.3)
DROP = 3.0
"""[s] When the friction drops (:func:`toolkit.verdicts.envelope.run_setup`)."""
REACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)
"""[s] After the drop, the times from which the commands are free."""
SEEDS = (0, 1, 2, 3, 4)


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    man, road, _ = ev.run_setup(CASE, p)
    end = 4.0 if quick else man.duration
    ecu = [simulate(p, "two-track", man, disturbances=road, controller="two-dof", seed=s)
           for s in (SEEDS[:1] if quick else SEEDS)]
    win = [(r.t >= DROP - 0.1) & (r.t <= end + 1e-9) for r in ecu]
    ecu_peaks = [float(np.degrees(np.max(np.abs(r.truth["beta"][w])))) for r, w in zip(ecu, win)]
    rows, table, found = [], [], []
    # the latest reaction first: its commands are open to every earlier one, and start its search
    warm = None
    for react in sorted(REACTIONS[1:2] if quick else REACTIONS, reverse=True):
        r = rc.search(CASE, p, start=DROP - 0.1, react=DROP + react, end=end, guess=ecu[0], warm=warm)
        beta = rc.replay(r, CASE, p)
        found.append((float(np.degrees(np.max(np.abs(beta)))), react, r))
        warm = r
    for peak, react, r in sorted(found, key=lambda f: f[1]):
        # what a later reaction reached, an earlier one reaches too
        best_peak, best_react, best = min((f for f in found if f[1] >= react), key=lambda f: f[0])
        corr = np.degrees(best.correction)
        free = ~np.isnan(best.torques[0])
        row = {"case": CASE.label, "reaction_s": react, "status": r.status, "search_peak_beta_deg": peak,
               "reachable_peak_beta_deg": best_peak, "from_reaction_s": best_react,
               "largest_correction_deg": float(np.max(np.abs(corr))),
               "largest_torque_nm": float(np.max(np.abs(best.torques[:, free]))) if free.any() else 0.0,
               "ecu_median_deg": float(np.median(ecu_peaks)), "ecu_worst_deg": float(np.max(ecu_peaks)),
               "alone_peak_beta_deg": r.alone_peak_beta_deg}
        rows.append(row)
        note = "" if r.status == "Solve_Succeeded" else f"{r.status} ({peak:.2f})"
        if best_react != react:
            note = (note + "; " if note else "") + f"the commands free from {best_react:.1f} s"
        table.append([CASE.label, f"{react:.1f}", f"{best_peak:.2f}",
                      f"{row['largest_correction_deg']:.1f} / {row['largest_torque_nm']:.0f}",
                      f"{row['ecu_median_deg']:.2f} / {row['ecu_worst_deg']:.2f}", f"{row['alone_peak_beta_deg']:.2f}",
                      note or "-"])
    write_table(rows, out / "reachable.csv")
    write_markdown(out / "reachable_table.md", [
        "case", "commands free after the drop [s]", "reachable peak sideslip [deg]",
        "largest steer correction [deg] / rear torque [N m]", "default ECU: median / worst seed [deg]",
        "car alone [deg]", "search (where not converged: its peak)"], table)
    return rows


if __name__ == "__main__":
    cli(main)
