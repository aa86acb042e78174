"""ASAM MDF4 (``.mf4``) logs to the drive-log schema, through asammdf and a channel map.

The channel map and the alignment of channels onto rows are :mod:`toolkit.logs.channels`'s (which reads
MATLAB and CSV files through the same map); an MDF file carries each channel's time stamps and unit,
and a unit in the map that differs from the file's is refused. Example map::

    [options]
    time_base = "yaw_rate"          # the column whose channel's timestamps are the rows (the IMU)

    [speed]
    channel = "VehSpd"              # channel name in the MDF file
    unit = "km/h"                   # its unit as logged (checked against the file's; converted to m/s)

    [gps_course]
    channel = "GNSS_COG"
    unit = "deg"
    angle = "cw-from-north-deg"     # receiver convention: converted to the yaw sense in rad, continuous
"""

from __future__ import annotations

from .channels import ANGLE_CONVENTIONS, COLUMNS, GPS_COLUMNS, load_channel_map, read_mapped
from .drivelog import DriveLog

__all__ = ["ANGLE_CONVENTIONS", "COLUMNS", "GPS_COLUMNS", "load_channel_map", "read_mdf"]


def read_mdf(path, channel_map) -> DriveLog:
    """A drive log from an MDF4 file and a channel map (a path or :func:`load_channel_map`'s result)."""
    return read_mapped(path, channel_map)
