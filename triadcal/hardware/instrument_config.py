"""Opening a capture's instruments from a file: the port config (``--config``, TOML ``[imu]``,
``[bench]``, ``[chamber]``) and the instruments file (``--instruments``, every driver and its
options, validated key by key), the drivers they name, and what the IMU driver says its frames
carry (:func:`imu_metadata`). Split from ``capture.py``, which walks the plan with what these open.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from ..errors import InputError


def load_port_config(path) -> dict:
    """A capture config file (TOML): tables ``[imu]`` (port, protocol, baudrate),
    ``[bench]`` (port, baudrate) and ``[chamber]`` (port, slave, baudrate)."""

    from ..io.atomic import read_toml

    cfg = read_toml(path, "a config file")
    for section in ("imu", "bench", "chamber"):
        if section in cfg and "port" not in cfg[section]:
            raise InputError(f"{path}: [{section}] needs a 'port'")
    return cfg


def open_instruments(cfg: Mapping) -> tuple:
    """(imu, bench, chamber) drivers from a config mapping: a ``--config`` ports file (see
    :func:`load_port_config`) or an instruments file (:func:`load_instruments`, already
    normalised). ``[imu]`` ``protocol`` (or ``driver``), ``baudrate``, ``rate_hz``; ``[bench]``
    ``driver`` ``scpi`` (default) or ``template`` with ``profile``; ``[chamber]`` ``driver`` as
    :func:`~triadcal.hardware.drivers.chamber.open_chamber` (default ``modbus``)."""
    from .drivers import SerialImu
    from .drivers.chamber import open_chamber

    missing = [s for s in ("imu", "bench", "chamber") if s not in cfg or not cfg[s].get("port")]
    if missing:
        raise InputError(f"no port given for: {', '.join(missing)} (use --config, --instruments or "
                         f"--{missing[0]}-port)")
    i, c = cfg["imu"], dict(cfg["chamber"])
    protocol = str(i.get("protocol", i.get("driver", "nmea")))
    imu_opts = {k: i[k] for k in IMU_OPTIONS if k in i}
    imu = SerialImu(i["port"], protocol=protocol, baudrate=int(i.get("baudrate", 921600)),
                    rate_hz=float(i["rate_hz"]) if i.get("rate_hz") else None, **imu_opts)
    bench = open_bench(cfg["bench"])
    try:
        if "driver" not in c:
            c.setdefault("baudrate", 19200)
        chamber = open_chamber(c)
    except BaseException:
        bench.close()
        raise
    return imu, bench, chamber


#: options of ``[imu]`` passed to the vendor protocol's configuration (drivers/imu.py)
IMU_OPTIONS = ("output", "temperature_hz", "timeout_s", "stall_timeout_s")
BENCH_DRIVERS = ("scpi", "template")


def open_bench(b: Mapping):
    """A bench driver from a ``[bench]`` mapping: ``driver = "scpi"`` (the SCPI-style bench, the
    default) or ``"template"`` with ``profile`` (a TOML path or a shipped profile's name, e.g.
    ``esp301``); ``port`` a device path or any pyserial URL; ``baudrate`` overrides the profile's."""
    from .drivers import ScpiBench
    from .drivers.bench import DEFAULT_TOLERANCE_DEG

    driver = str(b.get("driver", "scpi")).lower()
    if driver == "scpi":
        return ScpiBench(b["port"], baudrate=int(b.get("baudrate", 115200)),
                         tolerance_deg=float(b.get("tolerance_deg", DEFAULT_TOLERANCE_DEG)))
    if driver == "template":
        from .drivers.bench_template import TemplateBench

        if not b.get("profile"):
            raise InputError("[bench] driver = \"template\" needs 'profile' (a TOML file or a shipped name: esp301)")
        return TemplateBench(b["profile"], b["port"], baudrate=b.get("baudrate"))
    raise InputError(f"[bench] driver {driver!r}: expected one of {', '.join(BENCH_DRIVERS)}")


#: the sections of an instruments file and the keys each takes (docs/hardware.md)
INSTRUMENT_KEYS = {
    "imu": {"driver", "port", "baud", "rate_hz", *IMU_OPTIONS},
    "chamber": {"driver", "port", "baud", "address", "stopbits", "parity", "loop", "word_order", "timeout_s"},
    "bench": {"driver", "profile", "port", "baud", "tolerance_deg"},
    "dmm": {"driver", "resource", "resources", "channels", "model", "range_V", "nplc", "backend", "timeout_s",
            "mains_hz", "time_scale"},
}
IMU_DRIVERS = ("vectornav", "xsens", "mip", "nmea", "binary")


def load_instruments(path) -> dict:
    """An instruments file (TOML; ``triadcal capture --instruments``): sections ``[imu]``
    (``driver`` one of :data:`IMU_DRIVERS`, ``port``, ``baud``, ``rate_hz``), ``[chamber]``
    (``driver`` watlow-f4 | watlow-f4t | espec | modbus, ``port``, ``baud``, ``address``),
    ``[bench]`` (``driver`` template | scpi, ``profile``, ``port``, ``baud``, ``tolerance_deg`` for
    scpi: how close to its target an axis must read, degrees, default 0.01), ``[dmm]``
    (``driver = "scpi"``, ``resource`` ...). Unknown sections and keys are refused naming the
    file, the section and the key; the result uses the drivers' own names (``baudrate``,
    ``slave`` / ``address``, ``protocol``) as :func:`open_instruments` takes them. ``[dmm]`` is
    kept as written (``drivers.dmm.open_voltmeter``), plus ``time_scale`` (instrument seconds
    per wall second for :func:`capture_voltmeter`; 1 for real meters, the emulator writes its
    own)."""

    from .drivers.chamber import CHAMBER_DRIVERS

    from ..io.atomic import read_toml

    doc = read_toml(path, "an instruments file")
    out: dict = {}
    for section, table in doc.items():
        if section not in INSTRUMENT_KEYS:
            raise InputError(f"{path}: unknown section [{section}]; expected {', '.join(INSTRUMENT_KEYS)}")
        if not isinstance(table, dict):
            raise InputError(f"{path}: [{section}] must be a table")
        for key in table:
            if key not in INSTRUMENT_KEYS[section]:
                raise InputError(f"{path}: [{section}] unknown key {key!r}; expected one of "
                                 f"{', '.join(sorted(INSTRUMENT_KEYS[section]))}")
        if section != "dmm" and not table.get("port"):
            raise InputError(f"{path}: [{section}] needs 'port' (a device path or a pyserial URL)")
        t = dict(table)
        if "baud" in t:
            t["baudrate"] = int(t.pop("baud"))
        driver = str(t.get("driver", "")).lower()
        allowed = {"imu": IMU_DRIVERS, "chamber": CHAMBER_DRIVERS, "bench": BENCH_DRIVERS, "dmm": ("scpi",)}[section]
        if driver not in allowed:
            raise InputError(f"{path}: [{section}] driver {t.get('driver')!r}: expected one of {', '.join(allowed)}")
        t["driver"] = driver
        if section == "imu":
            t["protocol"] = driver
            if "rate_hz" in t and not float(t["rate_hz"]) > 0:
                raise InputError(f"{path}: [imu] rate_hz must be positive")
        if section == "chamber" and "address" in t and driver != "espec":
            t["slave"] = int(t.pop("address"))
        if section == "bench" and "tolerance_deg" in t:
            tol = t["tolerance_deg"]
            if driver == "template":
                raise InputError(f"{path}: [bench] tolerance_deg is for the scpi driver; a template bench takes it "
                                 "from its profile's [settle] tolerance_deg")
            if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0.0 < float(tol) <= 1.0:
                raise InputError(f"{path}: [bench] tolerance_deg = {tol!r}: must be a number of degrees in (0, 1] "
                                 "(how close to its target an axis must read to count as in position)")
        if section == "bench" and driver == "template" and not t.get("profile"):
            raise InputError(f"{path}: [bench] driver = \"template\" needs 'profile'")
        if section == "bench" and t.get("profile"):
            prof = Path(str(t["profile"]))
            if not prof.is_absolute() and (Path(path).parent / prof).exists():
                t["profile"] = str(Path(path).parent / prof)      # relative to the instruments file
        out[section] = t
    return out


def imu_metadata(imu) -> dict:
    """What the IMU driver says its frames carry, for the CSV header: ``output_unit``,
    ``imu_protocol`` and ``imu_temperature`` (per-axis sensors, one sensor copied to t_x, t_y,
    t_z, or none)."""
    from .protocols import TEMPERATURE_NONE, TEMPERATURE_SINGLE

    out = {}
    unit = getattr(imu, "output_unit", None)
    if unit:
        out["output_unit"] = unit
    if getattr(imu, "protocol", None):
        out["imu_protocol"] = imu.protocol
    temp = getattr(imu, "temperature", None)
    if temp == TEMPERATURE_SINGLE:
        out["imu_temperature"] = "single: the IMU's one temperature sensor, copied to t_x, t_y and t_z"
    elif temp == TEMPERATURE_NONE:
        out["imu_temperature"] = "none: the IMU gives no temperature; t_x, t_y, t_z are NaN"
    elif temp:
        out["imu_temperature"] = "per-axis: one sensor per accelerometer"
    return out
