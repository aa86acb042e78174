"""The ECU as an FMI 2.0 co-simulation FMU (toolkit.firmware.fmu): FMPy's validation of the model
description, and an FMPy-driven run over a closed-loop sensor log that issues the exported C's commands
bit for bit (float64)."""

from __future__ import annotations

import subprocess
import zipfile

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import make_maneuver
from evstab.toolkit.cli import main
from evstab.toolkit.kernels.compiled import compiler
from evstab.toolkit.firmware.csource import write_inputs_csv
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS
from evstab.toolkit.firmware.export import ecu_from_design
from evstab.toolkit.firmware.fmu import VR_CALIBRATION, VR_OUTPUT
from evstab.toolkit.firmware.replay import ecu_inputs
from evstab.toolkit.loop.simulator import simulate

fmpy = pytest.importorskip("fmpy", reason="FMPy (test extra) is not installed")
from fmpy import read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

CC = compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")


@pytest.fixture(scope="module")
def design_dir(default_design_dir):
    return default_design_dir


@pytest.fixture(scope="module")
def exported(design_dir, tmp_path_factory):
    if CC is None:
        pytest.skip("no C compiler on this machine")
    out = tmp_path_factory.mktemp("fmu")
    assert main(["export", str(design_dir), "--format", "c", "--fmu", "--out", str(out)]) == 0
    return out


@needs_cc
def test_the_fmu_passes_fmpy_validation(exported, design_dir):
    """FMPy's checks of the model description (schema, unique names, ModelStructure, start values,
    causality/variability, units) find nothing; every ECU input, output and calibration scalar is there
    once, with its unit, and the parameters carry the A2L's limits."""
    fmu = exported / "evstab_ecu.fmu"
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu), validate=True)
    by_name = {v.name: v for v in md.modelVariables}
    d, _ = ecu_from_design(design_dir)
    assert [by_name[f"in.{n}"].valueReference for n in INPUTS] == list(range(len(INPUTS)))
    assert [by_name[f"out.{n}"].valueReference for n in OUTPUTS] == [VR_OUTPUT + k for k in range(len(OUTPUTS))]
    assert by_name["in.yaw_rate"].unit == "rad/s" and by_name["out.yaw_moment_cmd"].unit == "N m"
    for k, c in enumerate(d.calibration()):
        v = by_name[f"cal.{c.name}"]
        assert (v.valueReference, v.causality, v.variability) == (VR_CALIBRATION + k, "parameter", "tunable")
        assert (float(v.start), float(v.min), float(v.max)) == (c.value, c.lower, c.upper)
    assert md.coSimulation.canBeInstantiatedOnlyOncePerProcess
    assert float(md.defaultExperiment.stepSize) == d.filter.dt_nominal
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
    assert {"binaries/linux64/evstab_ecu.so", "sources/evstab_fmu.c", "sources/evstab_firmware.c",
            "sources/evstab_firmware.h", "sources/evstab_fmu_vars.h"} <= names


def _slave(fmu, tmp_path):
    md = read_model_description(str(fmu))
    unzipped = fmpy.extract(str(fmu), str(tmp_path / "unzipped"))
    s = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="ecu")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    return s


@needs_cc
def test_the_fmu_issues_the_exported_c_commands_bit_for_bit(exported, design_dir, tmp_path):
    """A closed-loop lane change's sensor log (two-track, compact-ev, ISO 3888-1 at 100 km/h on mu 0.5, where the
    law acts): the FMU driven by
    FMPy, one fmi2DoStep of one period per log sample with the sample's inputs, against the exported C's
    replay harness over the same inputs: every output equal to the last bit (float64; both print and read
    17 significant digits)."""
    p = load_vehicle("compact-ev")
    d, _ = ecu_from_design(design_dir)
    res = simulate(p, "two-track", make_maneuver("iso3888-1", p, 100 / 3.6), seed=3, controller="two-dof",
                   design=d, disturbances=Disturbances(friction=Friction(mu=0.5)))
    U = ecu_inputs(res.log_columns(), d.controller.params.mu, d.filter.dt_nominal, d.wheel_radius)
    U[:, INPUTS.index("dt")] = d.filter.dt_nominal  # the FMU steps by whole periods
    inputs = tmp_path / "inputs.csv"
    with open(inputs, "w", newline="") as fh:
        write_inputs_csv(fh, U)
    binary = tmp_path / "replay"
    subprocess.run([CC, "-std=c99", "-O2", "-o", str(binary), str(exported / "evstab_firmware.c"),
                    str(exported / "evstab_replay.c"), "-lm"], check=True)
    lines = subprocess.run([str(binary), str(inputs)], capture_output=True, text=True, check=True).stdout.splitlines()
    Y_c = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    s = _slave(exported / "evstab_ecu.fmu", tmp_path)
    vr_in, vr_out = list(range(len(INPUTS))), [VR_OUTPUT + k for k in range(len(OUTPUTS))]
    Y = np.empty((len(U), len(OUTPUTS)))
    for k, u in enumerate(U):
        s.setReal(vr_in, list(u))
        s.doStep(currentCommunicationPoint=k * d.filter.dt_nominal, communicationStepSize=d.filter.dt_nominal)
        Y[k] = s.getReal(vr_out)
    s.terminate()
    s.freeInstance()
    np.testing.assert_array_equal(np.array([float(f"{y:.17g}") for y in Y.ravel()]).reshape(Y.shape), Y_c)
    assert np.abs(Y[:, OUTPUTS.index("yaw_moment_cmd")]).max() > 100.0  # the law acts in this run


@needs_cc
def test_the_fmu_refuses_a_calibration_outside_its_limits_and_a_partial_period(exported, design_dir, tmp_path):
    """``cal.k_beta`` just above its A2L upper limit, or NaN, is refused (fmi2Error) and the value stays; one
    just inside is taken. A communication step of 1.5 periods is refused; 3 periods run three steps."""
    from fmpy.fmi1 import FMICallException
    d, _ = ecu_from_design(design_dir)
    k = [c.name for c in d.calibration()].index("k_beta")
    cal = d.calibration()[k]
    s = _slave(exported / "evstab_ecu.fmu", tmp_path)
    vr = [VR_CALIBRATION + k]
    for bad in (cal.upper * (1 + 1e-12), float("nan")):
        with pytest.raises(FMICallException):
            s.setReal(vr, [bad])
        assert s.getReal(vr) == [cal.value]
    s.setReal(vr, [cal.upper])
    assert s.getReal(vr) == [cal.upper]
    with pytest.raises(FMICallException):
        s.doStep(0.0, 1.5 * d.filter.dt_nominal)
    s.doStep(0.0, 3 * d.filter.dt_nominal)
    s.terminate()
    s.freeInstance()


def test_without_a_compiler_the_fmu_export_says_so_and_writes_nothing(design_dir, tmp_path, monkeypatch, capsys):
    """``--fmu`` needs the host's C compiler for the binary: without one the export stops with a message naming
    what is missing, before any file of the export is written."""
    from evstab.toolkit.firmware import fmu
    monkeypatch.setattr(fmu, "compiler", lambda: None)
    out = tmp_path / "out"
    assert main(["export", str(design_dir), "--fmu", "--out", str(out)]) == 2
    assert "C compiler" in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
