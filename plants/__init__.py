"""Vehicle parameter sets and plant models (ISO 8855, SI units).

Public surface: :func:`load_vehicle`, :class:`VehicleParams`, the plant models
(:data:`PLANTS`), the linear bicycle matrices and the typed errors.
"""

from . import bicycle, bicycle_roll, commonroad_mb, two_track
from .errors import EvstabError, ManeuverError, ModelError, ParameterError
from .lti import ContinuousLTI, DiscreteLTI
from .model import COMMANDS, DISTURBANCES, TRUTH, PlantModel, default_disturbance
from .params import G, VehicleParams, bundled_vehicles, load_vehicle

PLANTS: dict[str, PlantModel] = {
    bicycle.MODEL.name: bicycle.MODEL,
    bicycle_roll.MODEL.name: bicycle_roll.MODEL,
    two_track.MODEL.name: two_track.MODEL,
}


PLANT_SPECS = tuple(PLANTS) + tuple(f"commonroad-mb:{n}" for n in commonroad_mb.SETS)
"""Every plant name the command line offers (``commonroad-mb:N:RATE`` is accepted too)."""


def get_plant(name: str) -> PlantModel:
    """The plant model called ``name``: ``bicycle``, ``bicycle-roll``, ``two-track``, or
    ``commonroad-mb:N[:STEER_RATE]`` (CommonRoad's multi-body car, parameter set N)."""
    if isinstance(name, str) and name.startswith("commonroad-mb"):
        return commonroad_mb.plant(name)
    try:
        return PLANTS[name]
    except KeyError:
        raise ModelError(f"unknown plant '{name}'; known plants: {', '.join(PLANT_SPECS)}") from None


def truth_params(plant: str, params: VehicleParams) -> VehicleParams:
    """The parameters the sensors and actuators of ``plant`` see: the set's own geometry for a
    ``commonroad-mb`` car (its truth is the package's set, whatever a design believes), else ``params``."""
    if is_multibody(plant):
        return commonroad_mb.truth_params(commonroad_mb.set_of(plant))
    return params


def is_multibody(name: str) -> bool:
    """True for a ``commonroad-mb`` plant name (its truth parameters are the package's set)."""
    return isinstance(name, str) and name.startswith("commonroad-mb")


__all__ = [
    "COMMANDS", "DISTURBANCES", "G", "PLANTS", "TRUTH", "ContinuousLTI", "DiscreteLTI", "EvstabError",
    "ManeuverError", "ModelError", "PLANT_SPECS", "ParameterError", "PlantModel", "VehicleParams", "bicycle",
    "bicycle_roll", "bundled_vehicles", "commonroad_mb", "default_disturbance", "get_plant", "is_multibody", "truth_params", "load_vehicle", "two_track",
]
