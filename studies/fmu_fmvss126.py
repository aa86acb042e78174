"""The exported ECU as an FMU, in a closed loop with evstab's two-track plant: FMVSS 126's sine with dwell.

The loop is closed in Python, one ECU period at a time, the way a vehicle simulator closes it around an FMU:
FMPy (``fmpy``, a test extra) runs ``evstab_ecu.fmu`` (``evstab export --fmu``: the exported C step), evstab's
compiled two-track plant (:class:`toolkit.kernels.compiled.CompiledPlant`) the car. The sensors are the plant's
outputs of the previous period (one period of delay): speed ``vx``, yaw rate, lateral acceleration, the rear
wheel speeds, the road-wheel steer as last commanded, and a 5 Hz GPS course ``yaw + beta`` (HDOP 1, 10
satellites); no noise and no road-friction sensor. The actuators are ideal: the steer command is the road-wheel
angle, the yaw-moment command the rear motors' moment, and the ECU's ``drive_share`` scales the speed hold's drive
torque until the robot coasts. The car alone runs the same loop with the driver's
steer and no yaw moment. Runs: the two largest amplitudes of the standard's series at 80 km/h on mu 1
(``A`` from the standard's slowly increasing steer, :func:`toolkit.verdicts.fmvss126.find_a`), steered left.

Outputs: ``fmu_fmvss126.csv`` / ``fmu_fmvss126.md`` (per run: amplitude, controller, yaw-rate ratios at COS +
1.0 and 1.75 s, lateral displacement, peak sideslip, verdict).

Run: ``python -m evstab.studies.fmu_fmvss126 OUT_DIR`` (a C compiler and FMPy; about 10 s).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from evstab.plants import get_plant, load_vehicle
from evstab.plants.model import COMMANDS, DISTURBANCES, TRUTH
from evstab.studies._common import cli, out_dir, write_table
from evstab.toolkit.kernels.compiled import CompiledPlant
from evstab.toolkit.design.design_job import default_design_document
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS
from evstab.toolkit.firmware.export import export_design
from evstab.toolkit.firmware.fmu import FMU_NAME, MODEL_IDENTIFIER, VR_OUTPUT
from evstab.toolkit.verdicts.fmvss126 import amplitudes, find_a, score_swd, series_maneuver

MU = 1.0
GPS_EVERY = 200
"""Periods between course fixes (5 Hz at 1 kHz)."""


def default_fmu(folder: Path) -> Path:
    """The bundled compact-ev ECU (``dakf``, the 2-DOF law on the nominal model) exported as an FMU in ``folder``."""
    doc = default_design_document("python -m evstab.studies.fmu_fmvss126")
    (folder / "design").mkdir(parents=True, exist_ok=True)
    (folder / "design" / "design.json").write_text(json.dumps(doc))
    export_design(folder / "design", folder / "fmu", ("json",), fmu=True)
    return folder / "fmu" / FMU_NAME


def run_swd(p, fmu_path, amplitude_deg: float, mu: float = MU, control: bool = True, dt: float = 1e-3):
    """One sine with dwell (left, hand-wheel ``amplitude_deg``) with the FMU in the loop (``control``) or the
    car alone; returns ``(t, hand-wheel angle [rad], truth outputs (N, len(TRUTH)))``."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    man = series_maneuver(p, amplitude_deg)
    model = get_plant("two-track")
    plant = CompiledPlant(model, p, dt)
    x = model.initial_state(p, man.speed)
    w = np.zeros(len(DISTURBANCES))
    for c in ("fl", "fr", "rl", "rr"):
        w[DISTURBANCES.index(f"mu_{c}")] = mu
    md = read_model_description(str(fmu_path))
    ecu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu_path)), modelIdentifier=MODEL_IDENTIFIER,
                    instanceName="ecu")
    ecu.instantiate()
    ecu.setupExperiment(startTime=0.0)
    ecu.enterInitializationMode()
    ecu.exitInitializationMode()
    n = int(round(man.duration / dt))
    t = np.arange(n) * dt
    driver = man.steer(t)
    i = {k: INPUTS.index(k) for k in INPUTS}
    u = np.zeros(len(INPUTS))
    u[i["dt"]], u[i["gps_hdop"]], u[i["gps_sats"]], u[i["mu"]] = dt, 1.0, 10.0, 10.0
    cmd = np.zeros(len(COMMANDS))
    cmd[COMMANDS.index("speed_ref")], cmd[COMMANDS.index("drive_on")] = man.speed, 1.0
    out_vr = [VR_OUTPUT + OUTPUTS.index(k) for k in ("steer_cmd", "yaw_moment_cmd", "drive_share")]
    Y = np.empty((n, len(TRUTH)))
    _, y = plant.step(x, cmd, w)  # the outputs at the start (the state is not advanced)
    try:
        for k in range(n):
            g = dict(zip(TRUTH, y))
            u[i["speed"]], u[i["yaw_rate"]], u[i["ay"]] = g["vx"], g["yaw_rate"], g["ay"]
            u[i["steer"]], u[i["yaw_moment_applied"]] = cmd[COMMANDS.index("steer")], cmd[COMMANDS.index("yaw_moment")]
            u[i["steer_cmd_driver"]] = driver[k]
            u[i["wheel_speed_rl"]], u[i["wheel_speed_rr"]] = g["wheel_speed_rl"], g["wheel_speed_rr"]
            fix = k % GPS_EVERY == 0
            u[i["gps_valid"]], u[i["gps_course"]] = (1.0, g["yaw"] + g["beta"]) if fix else (0.0, 0.0)
            ecu.setReal(list(range(len(INPUTS))), list(u))
            ecu.doStep(currentCommunicationPoint=k * dt, communicationStepSize=dt)
            steer, nz, drive = ecu.getReal(out_vr) if control else (driver[k], 0.0, 1.0)
            cmd[COMMANDS.index("steer")], cmd[COMMANDS.index("yaw_moment")] = steer, nz
            # the speed hold's drive torque, less what the ECU takes away; none once the robot coasts
            coasting = man.coast_from is not None and t[k] >= man.coast_from
            cmd[COMMANDS.index("drive_on")] = 0.0 if coasting else drive
            x, y = plant.step(x, cmd, w)
            Y[k] = y
    finally:
        ecu.terminate()
        ecu.freeInstance()
    return t, driver * p.steering_ratio, Y


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    a_deg = find_a(p, "two-track", MU)
    rows = []
    with tempfile.TemporaryDirectory(prefix="evstab_fmu_study_") as tmp:
        fmu_path = default_fmu(Path(tmp))
        for amp in amplitudes(a_deg)[-1:] if quick else amplitudes(a_deg)[-2:]:
            for control in (True, False):
                t, hw, Y = run_swd(p, fmu_path, amp, MU, control)
                sc = score_swd(t, hw, Y[:, TRUTH.index("yaw_rate")], Y[:, TRUTH.index("ay")])
                ok, failed = sc.passes(amp, a_deg)
                rows.append({"amplitude_deg": amp, "controller": "the FMU" if control else "none (the car alone)",
                             "yaw_ratio_1_0_pct": sc.yaw_ratio_1_0, "yaw_ratio_1_75_pct": sc.yaw_ratio_1_75,
                             "lateral_displacement_m": sc.lateral_displacement_m,
                             "peak_beta_deg": float(np.degrees(np.abs(Y[:, TRUTH.index("beta")]).max())),
                             "verdict": "pass" if ok else "FAIL: " + ", ".join(failed)})
    write_table(rows, out / "fmu_fmvss126.csv", out / "fmu_fmvss126.md", floatfmt="{:.2f}")
    return rows


if __name__ == "__main__":
    cli(main)
