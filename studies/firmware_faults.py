"""Single faults on every ECU input in the closed loop: what the ECU commands when an input goes wrong.

The ECU (compact-ev, evstab's default filter and law, with its input guard: :mod:`toolkit.ecu.guard`)
closes the loop on the two-track plant; :func:`toolkit.loop.ecu_faults.single_faults` injects, between the
sensors and the ECU, one fault at a time on each input: one NaN sample, NaN for 0.5 s, one +Inf sample, one
spike inside the physical range, stuck for 1 s, an offset for 1 s (:data:`toolkit.loop.ecu_faults.OFFSETS`).

* **Straight road** at 60 and 120 km/h (6 s, the fault at 3 s, seed 1): every command finite; the largest
  steer the ECU adds to the driver's and yaw moment it commands, and for how long it intervenes (steer
  beyond 0.01 deg or yaw moment beyond 10 N m); whether the fault word names the signal (faults of
  50 ms and more: the guard's latch time). The issue's bound: at most 0.5 deg and 300 N m, for at most
  100 ms (:data:`STEER_MAX_DEG`, :data:`YAW_MOMENT_MAX`, :data:`INTERVENTION_MAX_S`).
* **ISO 3888-1 lane change** at 80 km/h on mu 1.0 and 100 km/h on mu 0.5 (seeds 0-2), the fault from the
  driver's first steer: the peak sideslip against the car alone's, by the envelope's no-harm rule
  (:func:`toolkit.verdicts.envelope.judge`: at most 1.1 x the car alone's or 0.3 deg more), and by the same rule
  against the controlled car without the fault (where the law alone already breaks the rule, a row reads
  "as without the fault" when the fault adds nothing beyond it).

* **ECU reset at 100 km/h** (:func:`reset_runs`; seeds 0-2): the ECU resets and boots for 50 ms
  (the driver's steer passed on, no yaw moment), then starts from ``evstab_init``'s state, in steady left
  turns of 4 and 7 m/s^2 on mu 1 (at 5 s) and in the ISO 3888-1 lane change on mu 0.5 (0.5 s after the
  driver's first steer, between its two lane changes). Against an ECU that never reset, replayed over
  the same run's sensor log (:func:`shadow_commands`: the same car on the same path): how long after the
  boot the commands differ by more than 0.05 deg or 50 N m ("the law is back"; at most 1 s in the turns), the
  largest difference, the commands' largest change per period after the boot against the never-reset
  ECU's over the run (a spike: above it; :func:`command_steps`), and the peak sideslip by the no-harm rule
  against the car alone (:func:`reset_verdict`).

Outputs: ``firmware_faults.csv`` (every run), ``firmware_faults_table.md`` (per input and fault, the worst
over the straight roads and over the lane changes), ``firmware_faults_summary.md`` (counts),
``firmware_faults_baseline.md`` (each lane change's peak sideslip, car alone and controlled without a fault),
``firmware_faults_reset.md`` (the resets), ``firmware_faults_recovery.md`` (:func:`recovery_runs`: the guard's
recovery settings at the limit).

Run: ``python -m evstab.studies.firmware_faults OUT_DIR [--quick]`` (quick: 60 km/h straight road and the
80 km/h lane change, seed 0, the NaN and spike faults only).
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import constant_radius, make_maneuver
from evstab.studies._common import out_dir, write_markdown, write_table
from evstab.toolkit.loop.ecu_faults import EcuFault, single_faults
from evstab.toolkit.verdicts.envelope import HARM_FACTOR, HARM_MARGIN_DEG
from evstab.toolkit.ecu.guard import FAULT_BITS, GuardSettings
from evstab.toolkit.loop.loop_ecu import loop_ecu
from evstab.toolkit.loop.simulator import simulate

STEER_MAX_DEG = 0.5
YAW_MOMENT_MAX = 300.0
INTERVENTION_MAX_S = 0.1
ACTING_STEER_DEG = 0.01
ACTING_YAW_MOMENT = 10.0
FAULT_AT = 3.0
LATCH_S = GuardSettings().latch_time
STRAIGHT = (60.0, 120.0)
LANE_CHANGES = ((80.0, 1.0), (100.0, 0.5))
SEEDS = (0, 1, 2)
RESET_KMH = 100.0
RESET_BOOT_S = 0.05
RESET_TURNS_AY = (4.0, 7.0)
RESET_AT = 5.0
BACK_STEER_DEG = 0.05
BACK_YAW_MOMENT = 50.0
BACK_WITHIN_S = 1.0


def peak_beta_deg(r) -> float:
    """A run's peak sideslip [deg] (NaN samples, after a run stopped being finite, left out)."""
    return float(np.degrees(np.nanmax(np.abs(r.truth["beta"]))))


def first_steer_s(r) -> float:
    """[s] The first instant a run's road-wheel angle passes 0.5 deg: where a manoeuvre's faults are placed."""
    return float(r.t[np.argmax(np.abs(r.commands["steer"]) > np.radians(0.5))])


def straight_metrics(r, fault) -> dict:
    c = r.commands
    added = np.degrees(np.abs(c["steer"] - c["steer_driver"]))  # at the wheels, beyond the driver's angle
    nz = np.abs(c["yaw_moment_cmd"])
    finite = bool(np.all(np.isfinite(c["steer_cmd"])) and np.all(np.isfinite(c["yaw_moment_cmd"])))
    acting = (added > ACTING_STEER_DEG) | (nz > ACTING_YAW_MOMENT)
    bit = FAULT_BITS["gps" if fault.signal.startswith("gps_") else fault.signal]
    word = np.asarray(c["fault_word"], float)
    # only what lasts the guard's latch time is latched (a single bad sample is replaced and counted)
    named = bool(np.any((word.astype(np.int64) >> bit) & 1)) if fault.end - fault.start >= LATCH_S else None
    return {"finite": finite, "added_steer_deg": float(np.nanmax(added)), "yaw_moment_nm": float(np.nanmax(nz)),
            "intervention_s": float(acting.sum() * r.meta["dt"]), "named": named}


def within_bound(row: dict) -> bool:
    """The straight road's bound: finite commands, added steer and yaw moment within their bounds, intervening
    no longer than :data:`INTERVENTION_MAX_S`."""
    return bool(row["finite"] and row["added_steer_deg"] <= STEER_MAX_DEG and row["yaw_moment_nm"] <= YAW_MOMENT_MAX
                and row["intervention_s"] <= INTERVENTION_MAX_S)


def no_harm(peak_deg: float, alone_deg: float) -> bool:
    """The envelope's no-harm rule on the peak sideslip: at most ``HARM_FACTOR`` x the car alone's or
    ``HARM_MARGIN_DEG`` more."""
    return bool(np.isfinite(peak_deg) and peak_deg <= max(HARM_FACTOR * alone_deg, alone_deg + HARM_MARGIN_DEG))


def back_after(t, steer, steer_ref, nz, nz_ref, from_t: float) -> tuple[float, float, float]:
    """(seconds after ``from_t`` until the commands stay within :data:`BACK_STEER_DEG` and
    :data:`BACK_YAW_MOMENT` of the reference's, the largest steer [deg] and yaw-moment [N m] difference
    after ``from_t``). 0 when they never leave; inf when a command is not finite."""
    k = t >= from_t - 1e-9
    ds = np.degrees(np.abs(np.asarray(steer) - steer_ref))[k]
    dn = np.abs(np.asarray(nz) - nz_ref)[k]
    if not (np.all(np.isfinite(ds)) and np.all(np.isfinite(dn))):
        return np.inf, np.inf, np.inf
    out = np.flatnonzero((ds > BACK_STEER_DEG) | (dn > BACK_YAW_MOMENT))
    back = float(t[k][out[-1]] + (t[1] - t[0]) - from_t) if len(out) else 0.0
    return back, float(ds.max()), float(dn.max())


def command_steps(t, steer, steer_driver, nz, from_t: float = -np.inf) -> np.ndarray:
    """From ``from_t`` on: the largest change from one period to the next of the steer correction ``steer -
    steer_driver`` [deg] and of the yaw moment [N m]."""
    k = np.flatnonzero(np.asarray(t) >= from_t - 1e-9)
    corr = np.degrees(np.asarray(steer, float) - np.asarray(steer_driver, float))[k]
    m = np.asarray(nz, float)[k]
    return np.array([np.abs(np.diff(x)).max() if len(x) > 1 else 0.0 for x in (corr, m)])


def no_spike(reset_steps, never_steps) -> bool:
    """A reset's commands spike where one of their :func:`command_steps` after the boot exceeds what the ECU that
    never reset made over the whole run on the same inputs (by more than 1e-9 of it and 1e-9 deg or N m: rounding):
    a start from a state that does not fit the car steps its commands as the law itself never does."""
    r, n = np.asarray(reset_steps, float), np.asarray(never_steps, float)
    return bool(np.all(np.isfinite(r)) and np.all(r <= n * (1.0 + 1e-9) + 1e-9))


def shadow_commands(ecu, r) -> tuple[np.ndarray, np.ndarray]:
    """The steer and yaw-moment commands an ECU that never reset would have issued on run ``r``'s inputs:
    the ECU step replayed (:func:`toolkit.firmware.replay.ecu_program`) over the run's own sensor log, so
    that the comparison is with the same car on the same path (two closed-loop runs part ways)."""
    from evstab.toolkit.ecu.step import OUTPUTS
    from evstab.toolkit.firmware.replay import ecu_inputs, ecu_program
    U = ecu_inputs(r.log_columns(), ecu.controller.mu_max, wheel_radius=ecu.wheel_radius)
    y = OUTPUTS.columns(ecu_program(ecu).run(U))
    return y["steer_cmd"], y["yaw_moment_cmd"]


def reset_runs(p, quick: bool = False) -> list[dict]:
    """The ECU resets at 100 km/h (see the module): one row per case and seed."""
    ecu = loop_ecu("two-dof", p).ecu
    v = RESET_KMH / 3.6
    cases: list[tuple] = [(f"left turn {ay:g} m/s^2, mu 1", constant_radius(v, v * v / ay, laps=0.25, lead_in=60.0), Disturbances(),
              RESET_AT) for ay in RESET_TURNS_AY]
    cases.append(("ISO 3888-1, mu 0.5", make_maneuver("iso3888-1", p, v), Disturbances(friction=Friction(mu=0.5)),
                  None))
    rows = []
    for name, man, road, at in cases[:1] if quick else cases:
        for seed in SEEDS[:1] if quick else SEEDS:
            alone = simulate(p, "two-track", man, disturbances=road, seed=seed)
            clean = simulate(p, "two-track", man, disturbances=road, seed=seed, controller="two-dof", design=ecu)
            start = at if at is not None else first_steer_s(alone) + 0.5
            f = EcuFault("ecu", "reset", start, start + RESET_BOOT_S)
            r = simulate(p, "two-track", man, disturbances=road, seed=seed, controller="two-dof", design=ecu,
                         ecu_fault=f)
            c = r.commands
            steer0, nz0 = shadow_commands(ecu, r)
            back, ds, dn = back_after(r.t, c["steer_cmd"], steer0, c["yaw_moment_cmd"], nz0, f.end)
            steps = command_steps(r.t, c["steer_cmd"], c["steer_driver"], c["yaw_moment_cmd"], f.end)
            never = command_steps(r.t, steer0, c["steer_driver"], nz0)
            peak = peak_beta_deg(r)
            peak_alone = peak_beta_deg(alone)
            row = {"case": f"reset at {RESET_KMH:.0f} km/h: {name}", "seed": seed, "reset_at_s": start,
                   "finite": bool(np.isfinite(back)), "back_after_s": back, "steer_diff_deg": ds,
                   "yaw_moment_diff_nm": dn, "peak_beta_deg": peak,
                   "no_reset_peak_beta_deg": peak_beta_deg(clean),
                   "alone_peak_beta_deg": peak_alone, "no_harm": no_harm(peak, peak_alone),
                   "back_in_time": bool(back <= BACK_WITHIN_S), "no_spike": no_spike(steps, never),
                   "steady": at is not None,
                   **{f"reset_{k}": float(a) for k, a in zip(STEPS, steps)},
                   **{f"never_{k}": float(a) for k, a in zip(STEPS, never)}}
            rows.append(row)
            print(row, flush=True)
    return rows


STEPS = ("steer_step_deg", "yaw_moment_step_nm")
"""The entries of :func:`command_steps`."""


def reset_verdict(r: dict) -> str:
    """A reset row's verdict: finite, no harm (the peak sideslip against the car alone's) and no spike; in a steady
    turn also the law back within :data:`BACK_WITHIN_S` (the commands those of the ECU that never reset). At the
    limit the two ECUs' supervisors may part for as long as the car stays at the limit (a law active from the restart
    releases only once the friction use falls below ``release_use``), so there the time is reported, not judged."""
    if not r["finite"]:
        return "FAIL: not finite"
    if not r["no_harm"]:
        return "FAIL: harm"
    if not r["no_spike"]:
        return "FAIL: spike"
    if r["steady"] and not r["back_in_time"]:
        return "FAIL: late"
    return "pass" if r["steady"] else "pass (at the limit: no harm, no spike)"


RECOVERY_VARIANTS: tuple[tuple[str, dict], ...] = (("recovery 0.2 s (the default)", {}), ("recovery 1 s", {"recover_time": 1.0}),
                     ("recovery 0.2 s, authority held 2.5 s after the restart", {"restart_hold": 2.5}))
RECOVERY_SIGNALS = ("yaw_rate", "speed", "steer_cmd_driver")


def recovery_runs(p, quick: bool = False) -> list[list]:
    """The guard's recovery settings at the limit: NaN for 0.5 s on the yaw rate, the speed and the driver's
    steer from the first steer of ISO 3888-1 at 100 km/h on mu 0.5 (seeds 0 and 1), with the default
    recovery (0.2 s), a 1 s one, and the authority held for 2.5 s after the restart; the peak sideslip's
    range over the six runs of each. One table row per variant."""
    ecu = loop_ecu("two-dof", p).ecu
    man = make_maneuver("iso3888-1", p, 100 / 3.6)
    road = Disturbances(friction=Friction(mu=0.5))
    rows = []
    for label, settings in RECOVERY_VARIANTS[:1] if quick else RECOVERY_VARIANTS:
        d = dataclasses.replace(ecu, guard=dataclasses.replace(ecu.guard, **settings))
        peaks, alone_peaks = [], []
        for seed in SEEDS[:1] if quick else SEEDS[:2]:
            alone = simulate(p, "two-track", man, disturbances=road, seed=seed)
            alone_peaks.append(peak_beta_deg(alone))
            start = first_steer_s(alone)
            for signal in RECOVERY_SIGNALS:
                r = simulate(p, "two-track", man, disturbances=road, seed=seed, controller="two-dof", design=d,
                             ecu_fault=EcuFault(signal, "nan", start, start + 0.5))
                peaks.append(peak_beta_deg(r))
        rows.append([label, f"{min(peaks):.2f}-{max(peaks):.2f}", f"{min(alone_peaks):.2f}-{max(alone_peaks):.2f}"])
        print(rows[-1], flush=True)
    return rows


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    rows = []
    kinds = ("nan", "value") if quick else None
    for kmh in STRAIGHT[:1] if quick else STRAIGHT:
        man = make_maneuver("step-steer", p, kmh / 3.6, 0.0)
        for f in single_faults(FAULT_AT):
            if kinds and f.kind not in kinds:
                continue
            r = simulate(p, "two-track", man, seed=1, controller="two-dof", ecu_fault=f)
            row = {"case": f"straight {kmh:.0f} km/h", "signal": f.signal, "fault": f.label, **straight_metrics(r, f)}
            row["within_bound"] = within_bound(row)
            rows.append(row)
            print(row, flush=True)
    for kmh, mu in LANE_CHANGES[:1] if quick else LANE_CHANGES:
        man = make_maneuver("iso3888-1", p, kmh / 3.6)
        road = Disturbances(friction=Friction(mu=mu))
        for seed in SEEDS[:1] if quick else SEEDS:
            alone = simulate(p, "two-track", man, disturbances=road, seed=seed)
            peak_alone = peak_beta_deg(alone)
            clean = simulate(p, "two-track", man, disturbances=road, seed=seed, controller="two-dof")
            peak_clean = peak_beta_deg(clean)
            start = first_steer_s(alone)
            for f in single_faults(start):
                if kinds and f.kind not in kinds:
                    continue
                r = simulate(p, "two-track", man, disturbances=road, seed=seed, controller="two-dof", ecu_fault=f)
                peak = peak_beta_deg(r)
                finite = bool(np.all(np.isfinite(r.commands["steer_cmd"])) and
                              np.all(np.isfinite(r.commands["yaw_moment_cmd"])))
                row = {"case": f"ISO 3888-1 {kmh:.0f} km/h mu {mu:g}, seed {seed}", "signal": f.signal, "fault": f.label,
                       "finite": finite, "peak_beta_deg": peak, "alone_peak_beta_deg": peak_alone,
                       "no_fault_peak_beta_deg": peak_clean, "no_harm": no_harm(peak, peak_alone),
                       "as_without_fault": no_harm(peak, peak_clean)}
                rows.append(row)
                print(row, flush=True)
    write_markdown(out / "firmware_faults_recovery.md",
                   ["guard setting", "peak sideslip [deg]", "the car alone [deg]"], recovery_runs(p, quick))
    resets = reset_runs(p, quick)
    write_markdown(out / "firmware_faults_reset.md",
                   ["case", "seed", "reset at [s]", "law back after the boot [s]", "largest steer difference [deg]",
                    "largest yaw-moment difference [N m]",
                    "largest change per period after the boot, steer / yaw moment: reset / never reset [deg, N m]",
                    "peak sideslip: reset / no reset / car alone [deg]", "verdict"],
                   [[r["case"], r["seed"], f"{r['reset_at_s']:.2f}", f"{r['back_after_s']:.3f}",
                     f"{r['steer_diff_deg']:.3f}", f"{r['yaw_moment_diff_nm']:.0f}",
                     f"{r['reset_steer_step_deg']:.3f} / {r['never_steer_step_deg']:.3f}, "
                     f"{r['reset_yaw_moment_step_nm']:.0f} / {r['never_yaw_moment_step_nm']:.0f}",
                     f"{r['peak_beta_deg']:.2f} / {r['no_reset_peak_beta_deg']:.2f} / {r['alone_peak_beta_deg']:.2f}",
                     reset_verdict(r)] for r in resets])
    keys = list(dict.fromkeys(k for r in rows for k in r))
    write_table([{k: r.get(k, "") for k in keys} for r in rows], out / "firmware_faults.csv")
    table = fault_table(rows)
    write_markdown(out / "firmware_faults_table.md",
                   ["input", "fault", "added steer [deg]", "yaw moment [N m]", "intervening [ms]", "fault word names it",
                    "lane change: peak sideslip less the car alone's [deg]",
                    "... less the controlled car's without the fault [deg]", "verdict"],
                   [[s, f.split(", ")[0].split(" ", 1)[1] + ", " + f.split(", ")[1], f"{t['steer']:.3f}", f"{t['nz']:.0f}",
                     f"{1000 * t['time']:.0f}", "-" if t["named"] is None else ("yes" if t["named"] else "no"),
                     f"{t['excess']:+.2f}" if np.isfinite(t["excess"]) else "-",
                     f"{t['by_fault']:+.2f}" if np.isfinite(t["by_fault"]) else "-",
                     t["verdict"]] for (s, f), t in table.items()])
    runs = len(rows)
    passed = sum(bool(r.get("within_bound", r.get("no_harm")) and r["finite"]) for r in rows)
    as_clean = sum(bool(r.get("within_bound", r.get("as_without_fault")) and r["finite"]) for r in rows)
    base = {}
    for r in rows:
        if "no_fault_peak_beta_deg" in r:
            base[r["case"]] = (r["alone_peak_beta_deg"], r["no_fault_peak_beta_deg"])
    write_markdown(out / "firmware_faults_summary.md", ["runs", "commands finite", "within the rules",
                                                        "within the rules against the run without the fault"],
                   [[runs, sum(r["finite"] for r in rows), passed, as_clean]])
    write_markdown(out / "firmware_faults_baseline.md", ["lane change", "car alone [deg]",
                                                         "controlled, no fault [deg]"],
                   [[c, f"{a:.2f}", f"{b:.2f}"] for c, (a, b) in base.items()])
    return rows


def fault_table(rows: list[dict]) -> dict:
    """Per ``(signal, fault)``, the worst over its runs: added steer, yaw moment and intervention time on the
    straight roads, whether the fault word named it, the lane changes' peak sideslip less the car alone's and
    less the controlled car's without the fault, and the verdict: ``pass`` where every run keeps its rule; ``as
    without the fault`` where a lane change breaks the rule against the car alone but not against the controlled
    run without the fault, and every straight-road run keeps its bound (the run without the fault makes no
    command there, so nothing excuses one); ``FAIL`` otherwise."""
    table: dict = {}
    for r in rows:
        t = table.setdefault((r["signal"], r["fault"]), {"steer": 0.0, "nz": 0.0, "time": 0.0, "named": None,
                                                          "excess": -np.inf, "by_fault": -np.inf, "ok": True,
                                                          "fault_ok": True})
        if "added_steer_deg" in r:
            t["steer"], t["nz"] = max(t["steer"], r["added_steer_deg"]), max(t["nz"], r["yaw_moment_nm"])
            t["time"] = max(t["time"], r["intervention_s"])
            if r["named"] is not None:
                t["named"] = r["named"] if t["named"] is None else (t["named"] and r["named"])
            kept = r["within_bound"] and r["finite"]
            t["ok"] &= kept
            t["fault_ok"] &= kept
        else:
            t["excess"] = max(t["excess"], r["peak_beta_deg"] - r["alone_peak_beta_deg"])
            t["by_fault"] = max(t["by_fault"], r["peak_beta_deg"] - r["no_fault_peak_beta_deg"])
            t["ok"] &= r["no_harm"] and r["finite"]
            t["fault_ok"] &= r["as_without_fault"] and r["finite"]
    for t in table.values():
        t["verdict"] = "pass" if t["ok"] else ("as without the fault" if t["fault_ok"] else "FAIL")
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--quick"]
    main(args[0] if args else "out/studies", quick="--quick" in sys.argv)
