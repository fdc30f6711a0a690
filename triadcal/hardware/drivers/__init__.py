"""Instrument drivers, each behind a small abstract class.

A lab with another device writes one class: a subclass of
:class:`~triadcal.hardware.drivers.imu.ImuReadout`,
:class:`~triadcal.hardware.drivers.bench.Bench` or
:class:`~triadcal.hardware.drivers.chamber.Chamber` (docs/hardware.md, "Adding a device").
"""

from .bench import Bench, ScpiBench
from .chamber import Chamber, ModbusChamber
from .imu import ImuReadout, SerialImu, StreamThread

__all__ = ["Bench", "ScpiBench", "Chamber", "ModbusChamber", "ImuReadout", "SerialImu", "StreamThread"]
