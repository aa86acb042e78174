"""evstab: closed-loop stability-control design for electric vehicles with in-wheel motors.

The package's parts are ``evstab.plants`` (vehicle parameters and models), ``evstab.controllers``
(the 2-DOF law and its supervision), ``evstab.toolkit`` (estimation, the loop, analysis, the
design job, firmware export, the command line) and ``evstab.studies`` (the papers' studies).
The names below are what a script needs most (imported on first use)::

    import evstab
    p = evstab.load_vehicle("compact-ev")
    run = evstab.simulate(p, "two-track", evstab.make_maneuver("step-steer", p, 60 / 3.6))
    evstab.run_design("compact-ev", "out/design", quick=True)
    evstab.export_design("out/design", "out/firmware")
"""

from __future__ import annotations

import os as _os

try:
    from importlib.metadata import PackageNotFoundError as _NotFound, version as _version
    try:
        __version__ = _version("evstab")
    except _NotFound:  # a source tree that is not installed
        __version__ = "0.0.0+unknown"
finally:
    del _version, _NotFound

# In a source tree (or an editable install) the parts live beside this folder: plants/,
# controllers/, toolkit/, studies/ at the repository's top level, installed as evstab.<part>.
_here = _os.path.dirname(_os.path.abspath(__file__))
_top = _os.path.dirname(_here)
if all(_os.path.isdir(_os.path.join(_top, part)) for part in ("plants", "controllers", "toolkit")) \
        and not _os.path.isdir(_os.path.join(_here, "plants")):
    __path__.append(_top)  # noqa: F821 (the package's own __path__)

_API = {
    "VehicleParams": ("evstab.plants", "VehicleParams"),
    "load_vehicle": ("evstab.plants", "load_vehicle"),
    "bundled_vehicles": ("evstab.plants", "bundled_vehicles"),
    "make_maneuver": ("evstab.plants.maneuvers", "make_maneuver"),
    "simulate": ("evstab.toolkit.loop.simulator", "simulate"),
    "run_design": ("evstab.toolkit.design.design_job", "run_design"),
    "load_design": ("evstab.toolkit.design.design_job", "load_design"),
    "export_design": ("evstab.toolkit.firmware.export", "export_design"),
    "run_series": ("evstab.toolkit.verdicts.fmvss126", "run_series"),
    "EvstabError": ("evstab.plants.errors", "EvstabError"),
}
__all__ = ["__version__", *_API]


def __getattr__(name: str):
    if name in _API:
        import importlib
        module, attr = _API[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'evstab' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
