"""Fleet scale (issue 21): one unit out of a multi-unit file, batch calibration of every unit
and state on Dask, the fleet summary (table, outliers, tolerances, HTML) and the calibration
history per serial number (SQLite). docs/fleet.md."""

from .select import pair_mask, pairs, select_unit_state

__all__ = ["pair_mask", "pairs", "select_unit_state"]
