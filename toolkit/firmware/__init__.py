"""Firmware: the ECU's step (estimator + controller) as evstab runs it, and its export (C99, JSON)."""
