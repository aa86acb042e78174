"""``evstab export``: a design folder to firmware files (C99, JSON, A2L, CDFX).

Every file is generated in memory first; only when all of them are ready is each
written to a temporary name and renamed, so a failure leaves nothing half-written.
"""

from __future__ import annotations

from pathlib import Path

from evstab.plants.errors import EvstabError

from ..design.design_job import evstab_version, git_revision, load_design
from ..logs.drivelog import atomic_write
from . import asam, csource, gains
from .cgen import PRECISIONS, Precision
from ..ecu.step import EcuDesign

FORMATS = ("c", "json", "a2l", "cdfx")
FILES = {"c": ("evstab_firmware.h", "evstab_firmware.c", "evstab_replay.c"), "json": ("evstab_gains.json",),
         "a2l": ("evstab_firmware.a2l",), "cdfx": ("evstab_firmware.cdfx",)}


class ExportError(EvstabError, ValueError):
    """A design folder cannot be exported (what is wrong is named)."""


def ecu_from_design(path) -> tuple[EcuDesign, dict]:
    """The ECU design of an ``evstab design`` folder (or a ``design.json``) and its document."""
    from evstab.controllers.schedule import SpeedSchedule
    try:
        loaded = load_design(path)
    except ValueError as e:
        raise ExportError(str(e)) from None
    doc = loaded.document
    try:
        sched = SpeedSchedule.from_dict(doc["schedule"]) if "schedule" in doc else None
        d = EcuDesign.from_designs(loaded.filter, loaded.controller, sched)
    except (ValueError, EvstabError) as e:
        raise ExportError(f"{path}: {e}") from None
    return d, doc


def gain_set(design_dir, command: str | None = None) -> dict:
    """The gain-set document of a design folder."""
    d, doc = ecu_from_design(design_dir)
    prov = {"evstab_version": evstab_version(), "git_revision": git_revision(), "export_command": command,
            "design": doc.get("provenance", {}), "design_format": doc.get("format")}
    return gains.gains_document(d, prov, dict(doc.get("gps", {})))


def generator_info(doc: dict) -> dict:
    """What the C generator prints of a gain set: evstab's version, the design's digest, the vehicle."""
    return {"evstab_version": doc["evstab_version"], "params_digest": doc["vehicle"]["params_digest"],
            "vehicle": doc["vehicle"]["name"]}


def render(doc: dict, formats, precision: str) -> dict[str, bytes]:
    """File name -> content for the requested formats (nothing written)."""
    if precision not in PRECISIONS:
        raise ExportError(f"--precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    unknown = [f for f in formats if f not in FORMATS]
    if unknown:
        raise ExportError(f"unknown export format {unknown[0]!r}; known: {', '.join(FORMATS)}, all")
    d, _, _ = gains.load_gains(doc)
    p = Precision(precision)
    info = generator_info(doc)
    out: dict[str, bytes] = {}
    if "c" in formats:
        out["evstab_firmware.h"] = csource.header(d, p, info).encode()
        out["evstab_firmware.c"] = csource.source(d, p, info).encode()
        out["evstab_replay.c"] = csource.harness().encode()
    if "json" in formats:
        out["evstab_gains.json"] = gains.dumps(doc).encode()
    if "a2l" in formats:
        out["evstab_firmware.a2l"] = asam.a2l(doc, precision, d).encode()
    if "cdfx" in formats:
        out["evstab_firmware.cdfx"] = asam.cdfx(doc)
    return out


def export_design(design_dir, out_dir, formats=FORMATS, precision: str = "float64",
                  command: str | None = None, fmu: bool = False) -> list[Path]:
    """Export a design folder as firmware and calibration files.

    Parameters
    ----------
    design_dir : str or pathlib.Path
        An ``evstab design`` folder (or its ``design.json``).
    out_dir : str or pathlib.Path
        Folder to write into (created if needed); each file is written under a temporary name
        and renamed when complete.
    formats : sequence of str
        Any of ``c`` (``evstab_firmware.h``/``.c`` and the ``evstab_replay.c`` harness),
        ``json`` (``evstab_gains.json``), ``a2l``, ``cdfx``; default all.
    precision : str
        ``float64`` or ``float32``: the C type and the A2L record layouts.
    command : str, optional
        The command line recorded in the gain set's provenance.
    fmu : bool
        Also build ``evstab_ecu.fmu``, an FMI 2.0 co-simulation FMU of the step (:mod:`toolkit.firmware.fmu`;
        needs the host's C compiler). It is built before any file is written: a failed build writes nothing.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    doc = gain_set(design_dir, command)
    files = render(doc, formats, precision)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if fmu:
        from .fmu import FMU_NAME, build_fmu
        d, _, _ = gains.load_gains(doc)
        written.append(build_fmu(d, generator_info(doc), precision, out / FMU_NAME))
    for name, content in files.items():
        atomic_write(out / name, lambda fh, c=content: fh.write(c), mode="wb")
        written.append(out / name)
    return written
