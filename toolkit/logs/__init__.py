"""Drive logs in and out: the drive-log CSV schema and its reader and writer (:mod:`.drivelog`), logs recorded
by other tools read through a channel map (:mod:`.channels`: MDF4 (:mod:`.mdf`), MATLAB, CSV tables, CAN traces
(:mod:`.cantrace`), ROS 2 bags (:mod:`.mcaplog`); :func:`.channels.read_log` reads any of them), NMEA 0183 GNSS
logs merged onto an IMU log (:mod:`.nmea`), the GNSS-to-IMU time offset (:mod:`.timesync`), and production
sensors emulated on a reference log (:mod:`.emulate`). Nothing here imports the rest of the toolkit.
"""
