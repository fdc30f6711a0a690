"""A two-axis bench driven by command templates read from a TOML profile.

A lab whose bench controller speaks a line-based ASCII protocol (one command per line, one
answer line per query) writes a profile instead of a driver: the transport (baud rate,
terminators), the controller's axis names, the command templates with placeholders, the
regular expressions that read the answers, each axis's scale and offset, the angle wrap, the
soft limits and the settle rule. :func:`load_profile` reads and checks it,
:class:`TemplateBench` implements :class:`~triadcal.hardware.drivers.bench.Bench` with it, and
the emulator (``Emulator(bench_profile=...)``) answers the same profile on a pty.
``profiles/esp301.toml`` is the Newport ESP301's. Keys: docs/hardware.md ("Bench by
command template").

Angles: the campaign speaks bench degrees; the controller speaks its own units::

    controller = scale * degrees + offset          degrees = (controller - offset) / scale

then the reading is wrapped (``wrap = "none" | "180" | "360"``: as read, [-180, 180),
[0, 360)). A requested angle is wrapped the same way before it is checked against the soft
limits (``min_deg``, ``max_deg``) and sent; a move outside them is refused before anything is
written to the line.
"""

from __future__ import annotations

import math
import re
import string
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

from ...errors import InputError
from .bench import DEFAULT_TOLERANCE_DEG, Bench, BenchError, angle_difference, within_tolerance  # noqa: F401

PROFILE_DIR = Path(__file__).resolve().parent.parent / "profiles"

#: placeholders each command template may use
PLACEHOLDERS = {"move": {"axis", "value"}, "position": {"axis"}, "done": {"axis"}, "stop": {"axis"},
                "home": {"axis"}, "error": {"axis"}}
REQUIRED_COMMANDS = ("move", "position", "done")
WRAPS = ("none", "180", "360")

_TOP = {"name", "description", "transport", "axes", "commands", "responses", "settle", "emulator"}
_TRANSPORT = {"baudrate", "bytesize", "parity", "stopbits", "rtscts", "xonxoff", "write_terminator",
              "read_terminator", "timeout_s", "retries", "delay_s"}
_AXIS = {"name", "id", "scale", "offset", "wrap", "min_deg", "max_deg"}
_COMMANDS = set(PLACEHOLDERS) | {"value_format"}
_RESPONSES = {"position", "done", "done_value", "error", "no_error"}
_SETTLE = {"tolerance_deg", "polls"}
_EMULATOR = {"position_reply", "done_reply", "moving_reply", "error_reply", "no_error_message",
             "unknown_command", "positive_limit", "negative_limit", "ticks_per_s"}


class BenchControllerError(BenchError):
    """The controller reported an error in its error buffer; ``code`` and ``message`` are its."""

    def __init__(self, text: str, code: str, message: str = ""):
        super().__init__(text)
        self.code, self.message = code, message


class BenchLimitError(BenchError, InputError):
    """A move outside the profile's soft limits (refused before anything is sent)."""


@dataclass(frozen=True)
class AxisSpec:
    name: str
    id: str
    scale: float = 1.0
    offset: float = 0.0
    wrap: str = "none"
    min_deg: float = -math.inf
    max_deg: float = math.inf

    def to_controller(self, deg: float) -> float:
        return self.scale * deg + self.offset

    def to_degrees(self, value: float) -> float:
        return wrap_angle((value - self.offset) / self.scale, self.wrap)


@dataclass(frozen=True)
class BenchProfile:
    """A parsed profile (see the module docstring and docs/hardware.md)."""

    name: str
    axes: tuple
    commands: dict
    responses: dict
    value_format: str = ".4f"
    baudrate: int = 9600
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    rtscts: bool = False
    xonxoff: bool = False
    write_terminator: str = "\r"
    read_terminator: str = "\r\n"
    timeout_s: float = 0.5
    retries: int = 3
    delay_s: float = 0.0
    tolerance_deg: float = DEFAULT_TOLERANCE_DEG
    settle_polls: int = 3
    emulator: dict = field(default_factory=dict)
    source: str = ""

    def with_axes(self, **changes) -> "BenchProfile":
        """The profile with every axis changed (e.g. ``min_deg=-1e9, max_deg=1e9``)."""
        return replace(self, axes=tuple(replace(a, **changes) for a in self.axes))


def wrap_angle(deg: float, wrap: str) -> float:
    if wrap == "180":
        return (deg + 180.0) % 360.0 - 180.0
    if wrap == "360":
        return deg % 360.0
    return deg


def template_fields(template: str) -> set:
    return {f.split(":")[0].split("!")[0] for _, f, _, _ in string.Formatter().parse(template) if f is not None}


def _check_keys(src: str, section: str, table, allowed: set) -> None:
    if not isinstance(table, dict):
        raise InputError(f"{src}: [{section}] must be a table")
    for key in table:
        if key not in allowed:
            raise InputError(f"{src}: [{section}] unknown key {key!r}; expected one of {', '.join(sorted(allowed))}")


def load_profile(path_or_name) -> BenchProfile:
    """A profile from a TOML file, or by name from the shipped ones (``"esp301"``).
    Unknown keys, missing commands, bad placeholders and bad regular expressions are refused,
    naming the file, the section and the key."""

    p = Path(str(path_or_name))
    if not p.suffix and not p.exists():
        p = PROFILE_DIR / f"{p.name}.toml"
    src = str(p)
    from ...io.atomic import read_toml

    if not p.is_file():
        shipped = ", ".join(sorted(q.stem for q in PROFILE_DIR.glob("*.toml")))
        raise InputError(f"bench profile {path_or_name}: no such file (shipped profiles: {shipped})")
    return parse_profile(read_toml(p, "a bench profile"), src)


def parse_profile(doc: dict, src: str = "<profile>") -> BenchProfile:
    for key in doc:
        if key not in _TOP:
            raise InputError(f"{src}: unknown key or section {key!r}; expected {', '.join(sorted(_TOP))}")
    tr = doc.get("transport", {})
    _check_keys(src, "transport", tr, _TRANSPORT)
    cmds = doc.get("commands", {})
    _check_keys(src, "commands", cmds, _COMMANDS)
    resp = doc.get("responses", {})
    _check_keys(src, "responses", resp, _RESPONSES)
    settle = doc.get("settle", {})
    _check_keys(src, "settle", settle, _SETTLE)
    emu = doc.get("emulator", {})
    _check_keys(src, "emulator", emu, _EMULATOR)
    axes_doc = doc.get("axes")
    if not isinstance(axes_doc, list) or len(axes_doc) != 2:
        raise InputError(f"{src}: needs exactly two [[axes]] tables (axis 1, then axis 2)")
    axes = []
    for i, a in enumerate(axes_doc, start=1):
        _check_keys(src, f"axes {i}", a, _AXIS)
        if "id" not in a:
            raise InputError(f"{src}: [axes {i}] needs 'id' (the controller's name for the axis, e.g. \"1\")")
        wrap = str(a.get("wrap", "none"))
        if wrap not in WRAPS:
            raise InputError(f"{src}: [axes {i}] wrap {wrap!r}: expected one of {', '.join(WRAPS)}")
        scale = float(a.get("scale", 1.0))
        if scale == 0 or not math.isfinite(scale):
            raise InputError(f"{src}: [axes {i}] scale must be finite and non-zero")
        lo, hi = float(a.get("min_deg", -math.inf)), float(a.get("max_deg", math.inf))
        if not lo < hi:
            raise InputError(f"{src}: [axes {i}] min_deg {lo:g} must be below max_deg {hi:g}")
        axes.append(AxisSpec(name=str(a.get("name", f"axis{i}")), id=str(a["id"]), scale=scale,
                             offset=float(a.get("offset", 0.0)), wrap=wrap, min_deg=lo, max_deg=hi))
    for name in REQUIRED_COMMANDS:
        if name not in cmds:
            raise InputError(f"{src}: [commands] needs {name!r}")
    commands = {}
    for name, tpl in cmds.items():
        if name == "value_format":
            continue
        bad = template_fields(str(tpl)) - PLACEHOLDERS[name]
        if bad:
            raise InputError(f"{src}: [commands] {name} = {tpl!r}: unknown placeholder "
                             f"{{{sorted(bad)[0]}}}; {name} may use {', '.join('{%s}' % p for p in sorted(PLACEHOLDERS[name]))}")
        commands[name] = str(tpl)
    if "value" not in template_fields(commands["move"]):
        raise InputError(f"{src}: [commands] move must contain {{value}} (the target in controller units)")
    value_format = str(cmds.get("value_format", ".4f"))
    try:
        format(1.0, value_format)
    except ValueError:
        raise InputError(f"{src}: [commands] value_format {value_format!r} is not a Python float format") from None
    responses = {}
    for name in ("position", "done", "error"):
        if name in resp:
            try:
                rx = re.compile(str(resp[name]))
            except re.error as exc:
                raise InputError(f"{src}: [responses] {name}: not a regular expression: {exc}") from None
            if rx.groups < 1:
                raise InputError(f"{src}: [responses] {name} needs a capturing group")
            responses[name] = rx
    if "position" not in responses:
        raise InputError(f"{src}: [responses] needs 'position' (a regex whose first group is the number)")
    responses["done_value"] = str(resp.get("done_value", "1"))
    responses["no_error"] = str(resp.get("no_error", "0"))
    if "done" not in responses:
        responses["done"] = re.compile(r"^\s*(\S+)\s*$")
    if "error" in commands and "error" not in responses:
        raise InputError(f"{src}: [responses] needs 'error' (a regex: group 1 the code, group 2 the message) "
                         "when [commands] has 'error'")
    parity = str(tr.get("parity", "N"))
    if parity not in ("N", "E", "O"):
        raise InputError(f"{src}: [transport] parity {parity!r}: expected N, E or O")
    polls = int(settle.get("polls", 3))
    if polls < 1:
        raise InputError(f"{src}: [settle] polls must be 1 or more")
    return BenchProfile(
        name=str(doc.get("name", Path(src).stem)), axes=tuple(axes), commands=commands, responses=responses,
        value_format=value_format, baudrate=int(tr.get("baudrate", 9600)), bytesize=int(tr.get("bytesize", 8)),
        parity=parity, stopbits=float(tr.get("stopbits", 1)), rtscts=bool(tr.get("rtscts", False)),
        xonxoff=bool(tr.get("xonxoff", False)), write_terminator=str(tr.get("write_terminator", "\r")),
        read_terminator=str(tr.get("read_terminator", "\r\n")), timeout_s=float(tr.get("timeout_s", 0.5)),
        retries=int(tr.get("retries", 3)), delay_s=float(tr.get("delay_s", 0.0)),
        tolerance_deg=float(settle.get("tolerance_deg", DEFAULT_TOLERANCE_DEG)), settle_polls=polls,
        emulator=dict(emu),
        source=src)


class TemplateBench(Bench):
    """:class:`Bench` over a serial port (device path or any pyserial URL) by a :class:`BenchProfile`.

    ``move_to`` checks the soft limits (refusing before anything is sent), sends the move
    template per axis and reads the error buffer (``error`` command) when the profile has one:
    a code other than ``no_error`` raises :class:`BenchControllerError` naming it.
    ``in_position`` is true once every axis reports done and reads within ``tolerance_deg`` of
    its target for ``polls`` consecutive calls; a done axis outside the tolerance makes it read
    the error buffer (a move stopped by a limit or a fault raises there).
    """

    def __init__(self, profile, port: str, *, baudrate: Optional[int] = None, ser=None):
        self.profile = profile if isinstance(profile, BenchProfile) else load_profile(profile)
        self.port = port
        pr = self.profile
        if ser is None:
            import serial

            try:
                ser = serial.serial_for_url(port, baudrate=int(baudrate or pr.baudrate), bytesize=pr.bytesize,
                                            parity=pr.parity, stopbits=pr.stopbits, rtscts=pr.rtscts,
                                            xonxoff=pr.xonxoff, timeout=pr.timeout_s)
            except (serial.SerialException, ValueError) as exc:
                raise BenchError(f"cannot open the bench's port {port}: {exc}") from None
        self._ser = ser
        self._rx = b""
        self.target: Optional[tuple] = None
        self._good_polls = 0
        self.sent: list[str] = []          # every command line written (for logs and tests)

    # -- line I/O ----------------------------------------------------------------------
    def _write(self, line: str) -> None:
        self.sent.append(line)
        self._ser.write((line + self.profile.write_terminator).encode("ascii"))
        self._ser.flush()
        if self.profile.delay_s:
            time.sleep(self.profile.delay_s)

    def _readline(self) -> Optional[str]:
        term = self.profile.read_terminator.encode("ascii")
        deadline = time.monotonic() + self.profile.timeout_s
        while term not in self._rx:
            if time.monotonic() > deadline:
                return None
            chunk = self._ser.read(max(1, self._ser.in_waiting))
            self._rx += chunk
        line, self._rx = self._rx.split(term, 1)
        return line.decode("ascii", "replace")

    def _query(self, command: str) -> str:
        for _ in range(max(1, self.profile.retries)):
            self._rx = b""
            self._ser.reset_input_buffer()
            self._write(command)
            line = self._readline()
            if line is not None:
                return line
        raise BenchError(f"bench {self.profile.name} on {self.port}: no answer to {command!r} after "
                         f"{self.profile.retries} tries of {self.profile.timeout_s:g} s")

    def _command(self, name: str, axis: AxisSpec, **values) -> str:
        return self.profile.commands[name].format(axis=axis.id, **values)

    def _match(self, name: str, command: str, reply: str) -> re.Match:
        m = self.profile.responses[name].search(reply)
        if m is None:
            raise BenchError(f"bench {self.profile.name} on {self.port}: answer {reply!r} to {command!r} does "
                             f"not match the profile's {name} pattern {self.profile.responses[name].pattern!r}")
        return m

    def _group(self, name: str, command: str, reply: str, group: int = 1) -> str:
        """Group ``group`` of the profile's ``name`` pattern in ``reply`` (stripped);
        :class:`BenchError` naming the answer when the pattern or the group does not match."""
        m = self._match(name, command, reply)
        value = m.group(group) if m.re.groups >= group else None
        if value is None:
            raise BenchError(f"bench {self.profile.name} on {self.port}: answer {reply!r} to {command!r} has "
                             f"no group {group} of the profile's {name} pattern {m.re.pattern!r}")
        return value.strip()

    # -- the controller's error buffer ---------------------------------------------------
    def check_error(self, axis: Optional[AxisSpec] = None) -> None:
        """Read the error buffer once (when the profile has an ``error`` command); raise
        :class:`BenchControllerError` naming the code unless it is ``no_error``."""
        if "error" not in self.profile.commands:
            return
        cmd = self._command("error", axis or self.profile.axes[0])
        reply = self._query(cmd)
        code = self._group("error", cmd, reply)
        m = self._match("error", cmd, reply)
        if code != self.profile.responses["no_error"]:
            message = m.group(2).strip() if m.re.groups >= 2 and m.group(2) else ""
            raise BenchControllerError(f"bench {self.profile.name} on {self.port}: controller error {code}"
                                       + (f" ({message})" if message else "") + f", read with {cmd!r}",
                                       code, message)

    # -- Bench ---------------------------------------------------------------------------
    def commanded(self, axis1_deg: float, axis2_deg: float) -> tuple:
        """The angles a move sends (wrapped), after the soft-limit check."""
        out = []
        for ax, deg in zip(self.profile.axes, (axis1_deg, axis2_deg)):
            d = wrap_angle(float(deg), ax.wrap)
            if not (ax.min_deg <= d <= ax.max_deg):
                raise BenchLimitError(f"bench {self.profile.name}: move of {ax.name} to {deg:g} deg refused: "
                                      f"outside the soft limits [{ax.min_deg:g}, {ax.max_deg:g}] deg of "
                                      f"{self.profile.source or 'the profile'}; nothing was sent")
            out.append(d)
        return tuple(out)

    def move_to(self, axis1_deg: float, axis2_deg: float) -> None:
        target = self.commanded(axis1_deg, axis2_deg)
        for ax, deg in zip(self.profile.axes, target):
            value = format(ax.to_controller(deg), self.profile.value_format)
            self._write(self._command("move", ax, value=value))
        self.target = target
        self._good_polls = 0
        self.check_error()

    def axis_position(self, ax: AxisSpec) -> float:
        cmd = self._command("position", ax)
        reply = self._query(cmd)
        text = self._group("position", cmd, reply)
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise BenchError(f"bench {self.profile.name} on {self.port}: {text!r} in the answer {reply!r} to "
                             f"{cmd!r} is not a finite number")
        return ax.to_degrees(value)

    def position(self) -> tuple[float, float]:
        a1, a2 = (self.axis_position(ax) for ax in self.profile.axes)
        return a1, a2

    def axis_done(self, ax: AxisSpec) -> bool:
        cmd = self._command("done", ax)
        reply = self._query(cmd)
        return self._group("done", cmd, reply) == self.profile.responses["done_value"]

    def in_position(self) -> bool:
        ok = all(self.axis_done(ax) for ax in self.profile.axes)
        if ok and self.target is not None:
            near = within_tolerance(self.position(), self.target, self.profile.tolerance_deg,
                                    [ax.wrap for ax in self.profile.axes])
            if not near:
                self.check_error()         # stopped short: a limit or a fault says why
            ok = near
        self._good_polls = self._good_polls + 1 if ok else 0
        return self._good_polls >= self.profile.settle_polls

    def stop(self) -> None:
        if "stop" in self.profile.commands:
            for ax in self.profile.axes:
                self._write(self._command("stop", ax))
            self.check_error()

    def home(self) -> None:
        if "home" not in self.profile.commands:
            raise BenchError(f"bench profile {self.profile.name} has no home command")
        for ax in self.profile.axes:
            self._write(self._command("home", ax))
        self.target = (wrap_angle((0.0 - self.profile.axes[0].offset) / self.profile.axes[0].scale,
                                  self.profile.axes[0].wrap),
                       wrap_angle((0.0 - self.profile.axes[1].offset) / self.profile.axes[1].scale,
                                  self.profile.axes[1].wrap))
        self._good_polls = 0
        self.check_error()

    def close(self) -> None:
        try:
            self._ser.close()
        except Exception:   # noqa: BLE001 - a port that went away
            pass
