"""Vehicle parameter sets and plant models (ISO 8855, SI units).

Public surface: :func:`load_vehicle`, :class:`VehicleParams`, the plant models
(:data:`PLANTS`), the linear bicycle matrices and the typed errors.
"""

from . import bicycle, bicycle_roll, two_track
from .errors import EvstabError, ManeuverError, ModelError, ParameterError
from .lti import ContinuousLTI, DiscreteLTI
from .model import COMMANDS, DISTURBANCES, TRUTH, PlantModel, default_disturbance
from .params import G, VehicleParams, bundled_vehicles, load_vehicle

PLANTS: dict[str, PlantModel] = {
    bicycle.MODEL.name: bicycle.MODEL,
    bicycle_roll.MODEL.name: bicycle_roll.MODEL,
    two_track.MODEL.name: two_track.MODEL,
}


def get_plant(name: str) -> PlantModel:
    """The plant model called ``name`` (``bicycle``, ``bicycle-roll``, ``two-track``)."""
    try:
        return PLANTS[name]
    except KeyError:
        raise ModelError(f"unknown plant '{name}'; known plants: {', '.join(PLANTS)}") from None


__all__ = [
    "COMMANDS", "DISTURBANCES", "G", "PLANTS", "TRUTH", "ContinuousLTI", "DiscreteLTI", "EvstabError",
    "ManeuverError", "ModelError", "ParameterError", "PlantModel", "VehicleParams", "bicycle",
    "bicycle_roll", "bundled_vehicles", "default_disturbance", "get_plant", "load_vehicle", "two_track",
]
