"""Physical units of a log's columns.

The model keeps one position unit and a torque unit scaled with it (the log
schema's symbols ``pos``, ``trq``; ``sensaug-log``), named by
``rig.position_unit``. On the rig and in the Hi5 presets it is deg or rad
and the drive's N m is ``trq * rad_per_unit``, so a ``trq`` is (pi/180) N m
when positions are in degrees and a gain ``trq/pos`` is exactly N m/rad
either way. The simulation-section presets model a linear handle: ``m``,
the "torque" a force in N, gains in N/m and N s/m (simulation only; the rig
refuses ``m``). docs/logs.md, docs/model.md "Units". Everywhere a person
reads a number (plots, CLI tables, ``Log.units``, the MCAP export) the
symbols are replaced by these.
"""

from __future__ import annotations

from typing import Any, Mapping

__all__ = ["POSITION_UNITS", "physical", "position_unit"]

#: rig.position_unit -> the physical unit of each symbol of the log schema.
POSITION_UNITS: dict[str, dict[str, str]] = {
    "deg": {"pos": "deg", "trq": "(pi/180) N m", "trq/pos": "N m/rad", "trq s/pos": "N m s/rad"},
    "rad": {"pos": "rad", "trq": "N m", "trq/pos": "N m/rad", "trq s/pos": "N m s/rad"},
    "m": {"pos": "m", "trq": "N", "trq/pos": "N/m", "trq s/pos": "N s/m"},
}


def position_unit(config: Mapping[str, Any] | None) -> str | None:
    """The configuration's position unit (``rig.position_unit``), None if it names none."""
    unit = ((config or {}).get("rig") or {}).get("position_unit")
    return unit if unit in POSITION_UNITS else None


def physical(symbol: str, unit: str | None) -> str:
    """``symbol`` of the log schema (``pos/s``, ``(trq/pos)^2``, ``pos^2``...)
    in physical units for positions in ``unit``; unchanged for None."""
    if unit is None:
        return symbol
    table = POSITION_UNITS[unit]
    for base in ("trq s/pos", "trq/pos"):  # gains before their parts
        if base in symbol:
            return symbol.replace(base, table[base])
    if symbol.startswith("pos"):
        return table["pos"] + symbol[3:]
    if symbol.startswith("trq"):
        return table["trq"] + symbol[3:]
    return symbol
