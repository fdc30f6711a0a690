"""Watlow F4 and F4T chamber controllers over Modbus RTU (minimalmodbus, any pyserial port).

Public register maps (the F4 / F4T manuals; ChamberConnectLibrary ``watlowf4.py``,
``watlowf4t.py``): holding registers addressed by number, without the 40001 offset.

=============  =====================  ===============================================
controller     register (loop 1)      encoding
=============  =====================  ===============================================
F4             100 PV, 300 set point  signed int16, one implied decimal (x0.1 degC)
F4 loop 2      104 PV, 319 set point  same
F4T            2820 PV, 2782 SP       IEEE float32 over two registers, low word first
F4T loop n     + 160 (n - 1)          (word order configurable)
=============  =====================  ===============================================

The F4 set point is written with function 6 (write single register), as in the manual's
frames; the F4T float with function 16. Both drivers read the set point back after writing.

The module's encoders (:func:`read_holding_frame`, :func:`write_single_frame`,
:func:`f4_register`, :func:`float_to_words`) build the wire bytes independently of
minimalmodbus, for checking what goes out (tests) and for the docs.
"""

from __future__ import annotations

import math
import struct

import minimalmodbus

from ..protocols.binary import crc16_modbus
from .chamber import ChamberError, ModbusRtuChamber

F4_PV = {1: 100, 2: 104}
F4_SP = {1: 300, 2: 319}
F4T_SP = 2782
F4T_PV = 2820
F4T_LOOP_STRIDE = 160
WORD_ORDERS = {"low-first": minimalmodbus.BYTEORDER_LITTLE_SWAP,   # words CDAB, each big-endian
               "high-first": minimalmodbus.BYTEORDER_BIG}          # words ABCD


# -- encoders ---------------------------------------------------------------------------
def rtu_frame(slave: int, function: int, data: bytes) -> bytes:
    """A Modbus RTU frame: slave, function, data, CRC-16/MODBUS low byte first."""
    body = bytes([slave, function]) + data
    return body + crc16_modbus(body).to_bytes(2, "little")


def read_holding_frame(slave: int, register: int, count: int = 1) -> bytes:
    """Function 3, read ``count`` holding registers from ``register``."""
    return rtu_frame(slave, 3, struct.pack(">HH", register, count))


def write_single_frame(slave: int, register: int, value: int) -> bytes:
    """Function 6, write one register (``value`` as an unsigned 16-bit word)."""
    return rtu_frame(slave, 6, struct.pack(">HH", register, value & 0xFFFF))


def write_multiple_frame(slave: int, register: int, words) -> bytes:
    """Function 16, write consecutive registers."""
    words = list(words)
    return rtu_frame(slave, 16, struct.pack(">HHB", register, len(words), 2 * len(words))
                     + b"".join(struct.pack(">H", w & 0xFFFF) for w in words))


def f4_register(value_C: float) -> int:
    """The F4's word for a temperature: signed int16 of tenths of a degree (25.0 -> 0x00FA)."""
    tenths = int(round(value_C * 10))
    if not -32768 <= tenths <= 32767:
        raise ValueError(f"{value_C} degC does not fit the F4's signed 16-bit tenths")
    return tenths & 0xFFFF


def f4_value(word: int) -> float:
    """The temperature of an F4 word (inverse of :func:`f4_register`)."""
    return (word - 0x10000 if word & 0x8000 else word) / 10.0


def float_to_words(value: float, word_order: str = "low-first") -> tuple:
    """An IEEE float32 as two register words in the F4T's order (25.0 -> (0x0000, 0x41C8))."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", value))
    if word_order == "low-first":
        return lo, hi
    if word_order == "high-first":
        return hi, lo
    raise ValueError(f"word order {word_order!r}: expected one of {', '.join(WORD_ORDERS)}")


def words_to_float(words, word_order: str = "low-first") -> float:
    a, b = words
    hi, lo = (b, a) if word_order == "low-first" else (a, b)
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def plausible_C(value: float) -> bool:
    """A chamber temperature: finite, within -150..400 degC, and not a subnormal-small number
    (the swapped words of a round temperature: 23.0 degC reads 2.4e-41)."""
    return math.isfinite(value) and -150.0 <= value <= 400.0 and (value == 0.0 or abs(value) >= 1e-6)


# -- drivers ----------------------------------------------------------------------------
class _WatlowModbus(ModbusRtuChamber):
    """The Watlow controllers' transport (:class:`~.chamber.ModbusRtuChamber`; the F4's manual and
    implementations differ on the stop bits, so they are configurable)."""

    name = "Watlow"


class WatlowF4(_WatlowModbus):
    """Watlow F4: PV register 100 (loop 2: 104), set point 300 (loop 2: 319), signed int16
    tenths of a degree; 9600 baud 8N1 by default."""

    name = "Watlow F4"

    def __init__(self, port: str, **kw):
        super().__init__(port, **kw)
        if self.loop not in F4_PV:
            raise ValueError(f"Watlow F4 loop {self.loop}: expected 1 or 2")
        self.reg_pv = F4_PV[self.loop]
        self.reg_sp = F4_SP[self.loop]

    def set_setpoint_C(self, value: float) -> None:
        f4_register(value)                     # refuses what does not fit before sending
        target = round(float(value), 1)
        self._call("write set point", self._inst.write_register, self.reg_sp, target, 1,
                   functioncode=6, signed=True)
        back = self.setpoint_C()
        if abs(back - target) > 0.051:
            raise ChamberError(f"{self.name} on {self.port} reads back set point {back} degC after writing "
                               f"{target} (outside the controller's range, registers 602/603?)")

    def setpoint_C(self) -> float:
        return float(self._call("read set point", self._inst.read_register, self.reg_sp, 1,
                                functioncode=3, signed=True))

    def temperature_C(self) -> float:
        return float(self._call("read process value", self._inst.read_register, self.reg_pv, 1,
                                functioncode=3, signed=True))


class WatlowF4T(_WatlowModbus):
    """Watlow F4T: set point 2782, PV 2820 (+160 per loop), IEEE float32 over two registers,
    ``word_order`` ``low-first`` (the controller's default) or ``high-first``."""

    name = "Watlow F4T"

    def __init__(self, port: str, *, word_order: str = "low-first", **kw):
        if word_order not in WORD_ORDERS:
            raise ValueError(f"word order {word_order!r}: expected one of {', '.join(WORD_ORDERS)}")
        super().__init__(port, **kw)
        if self.loop < 1:
            raise ValueError(f"Watlow F4T loop {self.loop}: expected 1 or more")
        self.word_order = word_order
        self._byteorder = WORD_ORDERS[word_order]
        self.reg_sp = F4T_SP + F4T_LOOP_STRIDE * (self.loop - 1)
        self.reg_pv = F4T_PV + F4T_LOOP_STRIDE * (self.loop - 1)

    def _read_float(self, what: str, reg: int) -> float:
        return float(self._call(what, self._inst.read_float, reg, functioncode=3, number_of_registers=2,
                                byteorder=self._byteorder))

    def set_setpoint_C(self, value: float) -> None:
        value = float(value)
        self._call("write set point", self._inst.write_float, self.reg_sp, value, number_of_registers=2,
                   byteorder=self._byteorder)
        back = self.setpoint_C()
        if abs(back - value) > 1e-3 * max(1.0, abs(value)):
            raise ChamberError(f"{self.name} on {self.port} reads back set point {back} degC after writing {value}")

    def setpoint_C(self) -> float:
        return self._read_float("read set point", self.reg_sp)

    def temperature_C(self) -> float:
        """The PV, checked to be a temperature in the configured word order. The set point's read-back
        cannot catch a wrong order (it decodes the words it wrote the same wrong way); the PV can: a
        temperature's float read with its words swapped is a subnormal, a huge or a NaN number (23.0
        degC: 2.4e-41), and when the swapped reading is a temperature the order is named (an outside
        probe's ramp ran on a high-first controller read low-first: set points of -1e8 degC, exit 0)."""
        words = self._call("read process value", self._inst.read_registers, self.reg_pv, 2, functioncode=3)
        value = words_to_float(words, self.word_order)
        if plausible_C(value):
            return float(value)
        other = "high-first" if self.word_order == "low-first" else "low-first"
        swapped = words_to_float(words, other)
        if plausible_C(swapped):
            raise ChamberError(f"{self.name} on {self.port}: the process value reads {value!r} degC with word_order "
                               f"= {self.word_order!r} and {swapped:.4g} degC with {other!r}: set word_order = "
                               f"{other!r} in [chamber] (the controller's Modbus word order)")
        raise ChamberError(f"{self.name} on {self.port}: the process value reads {value!r} degC ({swapped!r} with the "
                           "words swapped): not a temperature (a sensor break, or another register map?)")
