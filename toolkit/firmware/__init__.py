"""Firmware: the ECU step (:mod:`toolkit.ecu`) of a design exported as C99 with its replay harness, the gain set
(JSON), A2L and CDFX, the FMI 2.0 FMU, and its build for a microcontroller."""
