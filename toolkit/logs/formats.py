"""Reference tables of ``docs/formats.md`` drawn from the code's own definitions (the drive-log
schema, the vehicle file's fields with units and ranges), so the page cannot drift from the
reader and the validator: ``python -m evstab.toolkit.logs.formats`` prints them, and a test checks
that the page carries every row."""

from __future__ import annotations

from dataclasses import MISSING, fields


def drive_log_table() -> str:
    from .drivelog import PLAUSIBLE, SCHEMA
    rows = ["| column | unit | required | possible range |", "| --- | --- | --- | --- |"]
    for name, unit, req in SCHEMA:
        lo, hi = PLAUSIBLE.get(name, (None, None))
        rng = f"{lo:g} to {hi:g}" if lo is not None else "-"
        rows.append(f"| `{name}` | {unit} | {'yes' if req else 'no'} | {rng} |")
    return "\n".join(rows)


def vehicle_table() -> str:
    from evstab.plants.params import _REQUIRED, VehicleParams
    rows = ["| key | meaning [unit] | required | range |", "| --- | --- | --- | --- |"]
    for f in fields(VehicleParams):
        if f.name in ("name", "source"):
            continue
        lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
        br = "(" if f.metadata.get("strict_lo", True) else "["
        rng = f"{br}{lo:g}, {hi:g}]" if lo is not None and hi is not None else "-"
        default = "" if f.default is MISSING or f.default is None else f" (default {f.default:g})"
        rows.append(f"| `{f.name}` | {f.metadata.get('doc', '')}{default} | "
                    f"{'yes' if f.name in _REQUIRED else 'no'} | {rng} |")
    return "\n".join(rows)


if __name__ == "__main__":
    print(drive_log_table())
    print()
    print(vehicle_table())
