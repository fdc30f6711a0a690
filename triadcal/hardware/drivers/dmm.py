"""An analog unit's voltmeter: SCPI digital multimeters over pyvisa (pyvisa-py by default).

An analog accelerometer (voltage output, e.g. AK-18, QA-3000, A-18) is read by a DMM: one
meter per axis (:class:`AxisVoltmeters` of :class:`ScpiDmm`), or one meter with a
multiplexer scanning the three outputs (:class:`ScpiScanner`). Either gives, per visit,
each axis's mean, standard deviation and sample count (:class:`VoltageAverage`), the
``w_*``, ``sd_*`` and ``n_samples`` of a bench CSV row.

Commands (Keysight Truevolt 34461A / 34465A operating manual; LF-terminated):

=======================  ================================================================
``*IDN?``                model check (``Keysight Technologies,34465A,...``)
``*CLS``                 clear the error queue
``CONF:VOLT:DC <range>`` DC volts, range in V (0.1, 1, 10, 100, 1000) or ``AUTO``
``VOLT:DC:NPLC <n>``     integration time in power-line cycles (checked against the model)
``SYST:ERR?``            ``+0,"No error"`` after configuring, else :class:`DmmError`
``SAMP:COUN <n>``        samples per trigger (sent when it changes)
``READ?``                ``INIT`` + ``FETC?``: ``+1.00520000E+01,+1.00510000E+01,...``
=======================  ================================================================

A scanner (34970A / DAQ970A style) takes the channel list on the same commands,
``CONF:VOLT:DC 10,(@101,102,103)``, ``VOLT:DC:NPLC 10,(@101,102,103)``, ``ROUT:SCAN (@...)``,
and ``TRIG:COUN <n>`` sweeps; ``READ?`` returns the readings sweep by sweep in scan-list
order. The meter's own gain and offset uncertainties are not this module's business: the
lab file declares them (``[voltmeter] gain_u_ppm, offset_u_V``) and the budget takes them
from there.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import numpy as np

from ...errors import InputError, TriadcalError

#: allowed integration times (PLC) per model; only 1, 10 and 100 PLC reject mains noise
NPLC_ALLOWED = {
    "34461A": (0.02, 0.2, 1.0, 10.0, 100.0),
    "34465A": (0.02, 0.06, 0.2, 1.0, 10.0, 100.0),
    # scanners: from their manuals, not verified against an instrument
    "34970A": (0.02, 0.2, 1.0, 2.0, 10.0, 20.0, 100.0, 200.0),
    "DAQ970A": (0.02, 0.2, 1.0, 2.0, 10.0, 20.0, 100.0, 200.0),
}
DCV_RANGES = (0.1, 1.0, 10.0, 100.0, 1000.0)
OVERLOAD = 9.9e37
AXES = ("x", "y", "z")


class DmmError(TriadcalError, OSError):
    """The voltmeter did not answer, reported an error or returned something unreadable."""


@dataclass(frozen=True)
class AxisStats:
    mean: float
    sd: float
    n: int


@dataclass(frozen=True)
class VoltageAverage:
    """Per-axis statistics of one averaging window."""

    axes: Mapping[str, AxisStats]

    @property
    def w(self) -> np.ndarray:
        return np.array([self.axes[a].mean for a in AXES])

    @property
    def sd(self) -> np.ndarray:
        return np.array([self.axes[a].sd for a in AXES])

    @property
    def n_samples(self) -> int:
        """The bench CSV's one count: the smallest of the axes' (they are equal when every
        axis got the same sample count)."""
        return min(self.axes[a].n for a in AXES)

    def row(self) -> dict:
        """``w_x, w_y, w_z, sd_x, sd_y, sd_z, n_samples`` for a bench CSV row."""
        out = {f"w_{a}": self.axes[a].mean for a in AXES}
        out.update({f"sd_{a}": self.axes[a].sd for a in AXES})
        out["n_samples"] = self.n_samples
        return out


def stats(values: Sequence[float]) -> AxisStats:
    v = np.asarray(values, dtype=float)
    if v.size < 2:
        raise DmmError(f"{v.size} reading(s): a mean and a standard deviation need at least 2")
    return AxisStats(float(v.mean()), float(v.std(ddof=1)), int(v.size))


def check_nplc(model: str, nplc: float) -> float:
    """``nplc`` as the model's float, or :class:`InputError` naming the allowed set."""
    allowed = NPLC_ALLOWED.get(model)
    if allowed is None:
        raise InputError(f"voltmeter model {model!r}: expected one of {', '.join(NPLC_ALLOWED)}")
    for a in allowed:
        if math.isclose(float(nplc), a, rel_tol=1e-9):
            return a
    raise InputError(f"NPLC {nplc:g} is not available on the {model}: choose one of "
                     f"{', '.join(f'{a:g}' for a in allowed)} (1, 10 or 100 reject mains noise)")


def check_range(range_V) -> str:
    """The range's SCPI text (``10``, ``AUTO``) or :class:`InputError`."""
    if isinstance(range_V, str) and range_V.upper() in ("AUTO", "DEF", "MIN", "MAX"):
        return range_V.upper()
    try:
        r = float(range_V)
    except (TypeError, ValueError):
        raise InputError(f"DC voltage range {range_V!r}: a number of volts or 'AUTO'") from None
    for a in DCV_RANGES:
        if math.isclose(r, a, rel_tol=1e-9):
            return f"{a:g}"
    raise InputError(f"DC voltage range {range_V!r} V: choose one of {', '.join(f'{a:g}' for a in DCV_RANGES)} "
                     "or 'AUTO'")


#: a DC volt range reads up to this factor of its full scale (the 34465A's and 34401A's 120 %)
OVERRANGE = 1.2


def parse_readings(text: str, expected: Optional[int] = None, what: str = "READ?",
                   full_scale_V: Optional[float] = None) -> np.ndarray:
    """``+1.00520000E+01,+1.00510000E+01,...`` as floats; overloads, a reading that is not a finite
    number (``NAN``), one beyond :data:`OVERRANGE` times ``full_scale_V`` (a fixed range: no meter
    reads 530 V on its 10 V range; an outside probe's meter answered in mV and the window was
    recorded) and a wrong count raise."""
    try:
        values = np.array([float(v) for v in text.strip().split(",") if v.strip()], dtype=float)
    except ValueError:
        raise DmmError(f"{what} answered {text[:80]!r}: not comma-separated numbers") from None
    if expected is not None and values.size != expected:
        raise DmmError(f"{what} answered {values.size} readings, {expected} expected")
    if np.any(np.abs(values) >= OVERLOAD):
        raise DmmError(f"{what}: overload (+9.9E+37) in the readings: the input exceeds the range")
    if not np.all(np.isfinite(values)):
        raise DmmError(f"{what}: a reading is not a finite number ({text[:80]!r})")
    if full_scale_V is not None and np.any(np.abs(values) > OVERRANGE * full_scale_V):
        worst = float(values[np.argmax(np.abs(values))])
        raise DmmError(f"{what}: a reading of {worst:g} V is beyond the {full_scale_V:g} V range (it reads up to "
                       f"{OVERRANGE * full_scale_V:g} V): not a reading of this range")
    return values


def _full_scale_V(range_text: str) -> Optional[float]:
    """The fixed range's full scale in volts, None for AUTO (the meter changes range itself)."""
    try:
        return float(range_text)
    except ValueError:
        return None


def _is_readings(text: str) -> bool:
    """True for a line of comma-separated numbers (a READ? answer), never for an ``*IDN?`` answer."""
    try:
        [float(p) for p in text.split(",")]
    except ValueError:
        return False
    return True


def _resource_manager(backend: str):
    import pyvisa

    return pyvisa.ResourceManager(backend)


class _ScpiMeter:
    """pyvisa transport, model check, configuration check, command log (:attr:`sent`)."""

    def __init__(self, resource: str, *, model: str, range_V, nplc: float, backend: str = "@py", rm=None,
                 timeout_s: float = 5.0, mains_hz: float = 50.0, check_idn: bool = True):
        # everything is checked before anything is opened or sent
        self.model = model
        self.nplc = check_nplc(model, nplc)
        self.range = check_range(range_V)
        self.resource_name = resource
        self.backend = backend
        self.timeout_s = float(timeout_s)
        self.mains_hz = float(mains_hz)
        self.check_idn = check_idn
        self._rm = rm
        self._res = None
        self.sent: list = []           # every command written, in order
        self.idn = ""
        self.stale_answers = 0         # answers of a previous client dropped at open
        self.late_answers = 0          # answers of a timed-out query dropped before the next one
        self._late: Optional[tuple] = None   # (command, timeout_s) of a query that timed out
        self._last: Optional[np.ndarray] = None   # the last window's readings (:meth:`_fresh`)

    def _fresh(self, values: np.ndarray, what: str) -> np.ndarray:
        """``values``, unless they equal the window before to the bit while varying (a meter that
        sends the previous window again: P02's 150 readings recorded as P03's, exit 0, an outside
        probe; a window of varying readings never repeats to the bit)."""
        last, self._last = self._last, values
        if last is not None and np.ptp(values) > 0 and np.array_equal(values, last):
            raise DmmError(f"{self.resource_name} READ?: the same {what} as the window before (a stale answer): "
                           "the window is read again")
        return values

    # -- transport ----------------------------------------------------------------------
    def open(self):
        if self._res is not None:
            return self
        try:
            rm = self._rm if self._rm is not None else _resource_manager(self.backend)
            self._rm = rm
            self._res = rm.open_resource(self.resource_name)
        except Exception as exc:   # noqa: BLE001 - pyvisa raises many kinds
            raise DmmError(f"cannot open voltmeter {self.resource_name}: {exc}") from None
        self._res.read_termination = "\n"
        self._res.write_termination = "\n"
        self._res.timeout = int(self.timeout_s * 1000)
        self.idn = self.query("*IDN?").strip()
        # a meter still answering a READ? of a client that died (a capture killed mid-window)
        # sends those readings before the answer to *IDN?: they are dropped, not taken for it
        for _ in range(3):
            if not _is_readings(self.idn):
                break
            self.stale_answers += 1
            self.idn = self._read_line("*IDN?").strip()
        if self.check_idn and self.model not in self.idn:
            raise DmmError(f"voltmeter {self.resource_name} is {self.idn!r}, not a {self.model}")
        self.configure()
        return self

    def write(self, command: str) -> None:
        self.sent.append(command)
        try:
            self._res.write(command)
        except Exception as exc:   # noqa: BLE001
            raise DmmError(f"voltmeter {self.resource_name}: {command!r} failed: {exc}") from None

    def query(self, command: str, timeout_s: Optional[float] = None) -> str:
        if self._late is not None:
            self._resync()
        self.sent.append(command)
        old = self._res.timeout
        try:
            if timeout_s is not None:
                self._res.timeout = int(timeout_s * 1000)
            return self._res.query(command)
        except Exception as exc:   # noqa: BLE001
            # the answer may still come (a READ? slower than its timeout): it must not be taken
            # for the answer to the next query, so the next query resynchronises first
            self._late = (command, self._res.timeout / 1000.0)
            raise DmmError(f"voltmeter {self.resource_name}: {command!r} got no answer: {exc}") from None
        finally:
            self._res.timeout = old

    def _resync(self) -> None:
        """After a query that timed out: ask ``*IDN?`` and drop every line before its answer (the
        late answer, or its remainder), waiting as long as that query could take. The meter
        works through its input in order, so what follows belongs to the next query."""
        command, wait_s = self._late
        self._late = None
        self.sent.append("*IDN?")
        old = self._res.timeout
        try:
            self._res.timeout = int(max(wait_s, self.timeout_s) * 1000)
            self._res.write("*IDN?")
            for dropped in range(4):
                if self._res.read().strip() == self.idn:
                    self.late_answers += dropped
                    return
        except Exception as exc:   # noqa: BLE001
            self._late = (command, wait_s)
            raise DmmError(f"voltmeter {self.resource_name}: lost step after {command!r} timed out, and "
                           f"*IDN? did not bring it back: {exc}") from None
        finally:
            self._res.timeout = old
        self._late = (command, wait_s)
        raise DmmError(f"voltmeter {self.resource_name}: lost step after {command!r} timed out: *IDN? was "
                       f"not answered with {self.idn!r}")

    def _read_line(self, after: str) -> str:
        try:
            return self._res.read()
        except Exception as exc:   # noqa: BLE001
            raise DmmError(f"voltmeter {self.resource_name}: no answer to {after!r} after dropping a "
                           f"previous client's readings: {exc}") from None

    def check_errors(self, after: str) -> None:
        text = self.query("SYST:ERR?").strip()
        code = text.split(",", 1)[0].strip()
        try:
            ok = int(code) == 0
        except ValueError:
            ok = False
        if not ok:
            raise DmmError(f"voltmeter {self.resource_name} reports {text!r} after {after}")

    def _read_timeout(self, n_readings: int) -> float:
        # one reading takes nplc / mains_hz s, twice that with auto-zero; plus margin
        return self.timeout_s + 2.5 * n_readings * self.nplc / self.mains_hz

    @abstractmethod
    def configure(self) -> None: ...

    def close(self) -> None:
        if self._res is not None:
            try:
                self._res.close()
            except Exception:   # noqa: BLE001
                pass
            self._res = None

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()


class ScpiDmm(_ScpiMeter):
    """One Truevolt meter (34461A / 34465A) on one axis."""

    def __init__(self, resource: str, *, model: str = "34465A", range_V=10.0, nplc: float = 10.0, **kw):
        super().__init__(resource, model=model, range_V=range_V, nplc=nplc, **kw)
        self._count: Optional[int] = None

    def configure(self) -> None:
        self.write("*CLS")
        self.write(f"CONF:VOLT:DC {self.range}")
        self.write(f"VOLT:DC:NPLC {self.nplc:g}")
        self._count = None
        self.check_errors("configuring")

    def read(self, n: int) -> np.ndarray:
        """``n`` readings (``SAMP:COUN n`` when it changed, then ``READ?``)."""
        n = int(n)
        if not 1 <= n <= 1_000_000:
            raise InputError(f"sample count {n}: expected 1..1000000")
        self.open()
        if n != self._count:
            self.write(f"SAMP:COUN {n}")
            self._count = n
        return self._fresh(parse_readings(self.query("READ?", timeout_s=self._read_timeout(n)), n,
                                          f"{self.resource_name} READ?", _full_scale_V(self.range)), f"{n} readings")


def samples_for_tau(tau_s: float, nplc: float, mains_hz: float, readings_per_sample: int = 1) -> int:
    """The sample count of an averaging window of ``tau_s`` seconds: each reading integrates
    ``nplc / mains_hz`` s, so ``n = round(tau_s * mains_hz / (nplc * readings_per_sample))``, at
    least 2 (``readings_per_sample`` 3 for a scanner's sweep of x, y, z). The count fixes the
    integration time; the meter's own overhead (auto-zero, up to about twice as long) makes
    the window last longer than ``tau_s`` in real time."""
    n = int(round(float(tau_s) * float(mains_hz) / (float(nplc) * readings_per_sample)))
    return max(2, n)


class VoltmeterReadout(ABC):
    """Per-axis voltage statistics of one averaging window."""

    @abstractmethod
    def measure(self, n: int) -> VoltageAverage: ...

    @abstractmethod
    def samples_for(self, tau_s: float) -> int:
        """``SAMP:COUN`` (or ``TRIG:COUN``) for an averaging window of ``tau_s`` (:func:`samples_for_tau`)."""

    def describe(self) -> str:
        return type(self).__name__

    def close(self) -> None:
        pass


class AxisVoltmeters(VoltmeterReadout):
    """One :class:`ScpiDmm` per axis (``{"x": meter, "y": ..., "z": ...}``); the meters are
    read one after the other (for simultaneous windows, trigger them externally)."""

    def __init__(self, meters: Mapping[str, ScpiDmm]):
        if sorted(meters) != sorted(AXES):
            raise InputError(f"one meter per axis: expected axes x, y, z, got {', '.join(meters)}")
        self.meters = dict(meters)

    def open(self):
        for a in AXES:
            self.meters[a].open()
        return self

    def measure(self, n: int) -> VoltageAverage:
        return VoltageAverage({a: stats(self.meters[a].read(n)) for a in AXES})

    def samples_for(self, tau_s: float) -> int:
        m = self.meters["x"]
        return samples_for_tau(tau_s, m.nplc, m.mains_hz)

    def describe(self) -> str:
        m = self.meters["x"]
        return (f"one {m.model} per axis ({', '.join(self.meters[a].resource_name for a in AXES)}), "
                f"range {m.range} V, NPLC {m.nplc:g} at {m.mains_hz:g} Hz mains, read one after the other")

    def close(self) -> None:
        for m in self.meters.values():
            m.close()


class ScpiScanner(_ScpiMeter, VoltmeterReadout):
    """One meter with a multiplexer: ``channels`` maps axes to channel numbers
    (``{"x": 101, "y": 102, "z": 103}``); ``n`` sweeps per window."""

    def __init__(self, resource: str, channels: Mapping[str, int], *, model: str = "DAQ970A", range_V=10.0,
                 nplc: float = 10.0, **kw):
        if sorted(channels) != sorted(AXES):
            raise InputError(f"scanner channels: expected axes x, y, z, got {', '.join(channels)}")
        chans = [int(channels[a]) for a in AXES]
        if len(set(chans)) != 3:
            raise InputError(f"scanner channels {chans}: three different channels needed")
        super().__init__(resource, model=model, range_V=range_V, nplc=nplc, **kw)
        self.channels = {a: int(channels[a]) for a in AXES}
        self.scan_order = sorted(AXES, key=lambda a: self.channels[a])   # a scanner sweeps in channel order
        self.channel_list = "(@" + ",".join(str(self.channels[a]) for a in self.scan_order) + ")"
        self._count: Optional[int] = None

    def configure(self) -> None:
        self.write("*CLS")
        self.write(f"CONF:VOLT:DC {self.range},{self.channel_list}")
        self.write(f"VOLT:DC:NPLC {self.nplc:g},{self.channel_list}")
        self.write(f"ROUT:SCAN {self.channel_list}")
        self._count = None
        self.check_errors("configuring")

    def measure(self, n: int) -> VoltageAverage:
        n = int(n)
        if not 2 <= n <= 50_000:
            raise InputError(f"sweep count {n}: expected 2..50000")
        self.open()
        if n != self._count:
            self.write(f"TRIG:COUN {n}")
            self._count = n
        v = self._fresh(parse_readings(self.query("READ?", timeout_s=self._read_timeout(3 * n)), 3 * n,
                                       f"{self.resource_name} READ?", _full_scale_V(self.range)).reshape(n, 3),
                        f"{n} sweeps")
        return VoltageAverage({a: stats(v[:, i]) for i, a in enumerate(self.scan_order)})

    def samples_for(self, tau_s: float) -> int:
        return samples_for_tau(tau_s, self.nplc, self.mains_hz, readings_per_sample=3)

    def describe(self) -> str:
        return (f"{self.model} scanning {self.channel_list} ({self.resource_name}), range {self.range} V, "
                f"NPLC {self.nplc:g} at {self.mains_hz:g} Hz mains")


def open_voltmeter(cfg: Mapping, rm=None) -> VoltmeterReadout:
    """A voltmeter readout from a ``[dmm]`` config section: ``driver = "scpi"``, then either
    ``resource`` + ``channels = {x = 101, y = 102, z = 103}`` (one meter with a scanner) or
    ``resources = {x = "...", y = "...", z = "..."}`` (one meter per axis); ``model``,
    ``range_V``, ``nplc``, ``backend`` (default ``@py``: pyvisa-py; ``path.yaml@sim``:
    pyvisa-sim), ``timeout_s``, ``mains_hz``. Opens and configures the meters."""
    driver = str(cfg.get("driver", "scpi")).lower()
    if driver != "scpi":
        raise InputError(f"[dmm] driver {driver!r}: expected 'scpi'")
    common = {k: cfg[k] for k in ("range_V", "nplc", "backend", "timeout_s", "mains_hz") if k in cfg}
    if rm is None:
        rm = _resource_manager(str(cfg.get("backend", "@py")))
    if "resources" in cfg:
        res = cfg["resources"]
        meters = {a: ScpiDmm(res[a], model=str(cfg.get("model", "34465A")), rm=rm, **common)
                  for a in AXES if a in res}
        return AxisVoltmeters(meters).open()
    if "resource" in cfg and "channels" in cfg:
        return ScpiScanner(cfg["resource"], cfg["channels"], model=str(cfg.get("model", "DAQ970A")), rm=rm,
                           **common).open()
    raise InputError("[dmm] needs 'resources' (x, y, z: one meter per axis) or 'resource' with 'channels'")
