"""evstab toolkit: the simulator, sensors-to-log I/O, compiled loops and the command line."""
