"""Hardware layer: wire protocols, instrument drivers, an emulator on pseudo-terminals,
and the campaign runner that captures a bench campaign (docs/hardware.md).

``protocols/`` frame and check the bytes (NMEA-style sentences with an XOR checksum,
binary frames with CRC-16), ``drivers/`` talk to the IMU readout, the two-axis bench
(SCPI-style text) and the thermal chamber (Modbus RTU through minimalmodbus), each
behind a small abstract class; ``emulator`` plays all three on pseudo-terminals with
the physics of :mod:`triadcal.models`; ``capture`` runs a campaign and ``storage``
keeps the raw samples append-only.
"""
