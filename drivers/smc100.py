"""Newport SMC100 axis over RS-232 ASCII (pyserial): the protocol hooks of ``Axis``.

Every set command is followed by ``TE``, so a silently rejected command raises ``ExceptionReply``;
a stage error in ``TS`` raises ``DeviceFault``. Positions are controller units / ``units_per_deg``.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Mapping

from .axis import Axis, AxisConfig
from .errors import DeviceError, DeviceFault, DeviceTimeout, ExceptionReply, NotHomedError, ProtocolError
from .smc100_protocol import (
    DEFAULT_BAUD, DISABLE_STATES, MM_DISABLE, MM_ENABLE, MOTION_STATES, NOT_REFERENCED_STATES, QUERY,
    READY_STATES, TERMINATOR, Cmd, ErrorLetter, State, TellState, build_command, decode_ts,
    parse_reply, te_meaning,
)

from .transport import PORT_ERRORS

log = logging.getLogger(__name__)
REPLY_TIMEOUT_S = 0.2  # the manual gives about 10 ms for TP; leave room for a busy host
IDENTITY_QUERIES = {"version": Cmd.VERSION, "stage": Cmd.STAGE_ID}  # VE, ID: read-only


class SMC100Axis(Axis):
    """One stage on a Newport SMC100 controller.

    ``port``: serial device path (for messages: the rig layer opens it, 57600 8N1 XON/XOFF);
    ``address``: controller address 1-31; ``units_per_deg``: controller units (deg for a rotation
    stage) per degree; ``reply_timeout_s``: how long to wait for one reply line (real seconds; the
    transport's read timeout is set to it at connect).
    """

    def __init__(self, config: AxisConfig, port: str = "", address: int = 1,
                 units_per_deg: float = 1.0, reply_timeout_s: float = REPLY_TIMEOUT_S) -> None:
        super().__init__(config)
        self.port, self.address = str(port), int(address)
        self.units_per_deg = float(units_per_deg)
        self.reply_timeout_s = float(reply_timeout_s)
        self._serial = None  # the ByteTransport handed in by connect()
        self._latched_causes: list[str] = []  # TS error bits clear when read: keep them for _read_fault
        self._last_ts: TellState | None = None
        self.soft_limits_units: tuple[float, float] | None = None
        self._te_owed = False  # a TE went unanswered: its reply may still come (``_tell_error``)

    @classmethod
    def from_section(cls, config: AxisConfig, section: Mapping) -> "SMC100Axis":
        """Build from a validated ``smc100`` driver section of the rig file."""
        return cls(config, port=section["port"], address=section.get("address", 1),
                   units_per_deg=section.get("units_per_deg", 1.0),
                   reply_timeout_s=section.get("reply_timeout_ms", REPLY_TIMEOUT_S * 1000.0) / 1000.0)

    # ----- transport ---------------------------------------------------------------------------
    def _send(self, cmd: Cmd, value=None) -> str:
        """Write one command line; return its text for error messages."""
        line = build_command(self.address, cmd, value)
        if self._serial is None:
            raise DeviceTimeout(self.name, line.decode().strip(), None, "port closed")
        try:
            self._serial.reset_input_buffer()  # a late or partial reply must not answer this command
            self._serial.write(line)
        except PORT_ERRORS as exc:
            raise DeviceTimeout(self.name, line.decode().strip(), None, f"connection lost: {exc}") from exc
        return line.decode().strip()

    def _query(self, cmd: Cmd, value=None) -> str:
        """Send a query and return the value text of its reply (prefix checked)."""
        text = self._send(cmd, value)
        try:
            raw = self._serial.read_until(TERMINATOR)
        except PORT_ERRORS as exc:
            raise DeviceTimeout(self.name, text, None, f"connection lost: {exc}") from exc
        if not raw.endswith(TERMINATOR):
            raise DeviceTimeout(self.name, text, raw or None,
                                f"no complete reply within {self.reply_timeout_s:g} s")
        try:
            value = parse_reply(raw, self.address, cmd)
        except ValueError as exc:
            raise ProtocolError(self.name, text, raw, str(exc)) from exc
        if cmd is not Cmd.TELL_ERROR:
            self._te_owed = False  # replies come in order: a late TE reply came before this one
        return value

    def _command(self, cmd: Cmd, value=None) -> None:
        """Send a set command, then read TE: any letter but '@' raises ExceptionReply."""
        text = self._send(cmd, value)
        letter = self._tell_error()
        if len(letter) != 1:
            raise ProtocolError(self.name, f"{text}; TE", letter, "expected one error letter")
        if letter != ErrorLetter.NONE:
            error = NotHomedError if letter == ErrorLetter.IN_NOT_REFERENCED else ExceptionReply
            raise error(self.name, text, f"{self.address}TE{letter}", f"refused: {letter} = {te_meaning(letter)}",
                        code=letter)

    def _tell_error(self) -> str:
        """Read TE once.

        TE clears the letter it reports, so a TE whose reply was lost is not asked again: the timeout goes
        up, where a move is read back with TH and a repeatable set command sent again. Every TE reply looks
        alike, so after such a TE the next one is preceded by a TP whose reply is awaited with late lines
        skipped (``_resync``).
        """
        if self._te_owed:
            self._resync()
        try:
            letter = self._query(Cmd.TELL_ERROR)
        except DeviceError:
            self._te_owed = True
            raise
        return letter

    def _resync(self) -> None:
        """Send TP and read lines until its reply, skipping the late ones before it; then no
        earlier reply is still on its way. No TP reply: DeviceTimeout (the caller may retry)."""
        text = self._send(Cmd.TELL_POSITION)
        while True:
            try:
                raw = self._serial.read_until(TERMINATOR)
            except PORT_ERRORS as exc:
                raise DeviceTimeout(self.name, text, None, f"connection lost: {exc}") from exc
            if not raw.endswith(TERMINATOR):
                raise DeviceTimeout(self.name, f"{text} (resync after a lost TE reply)", raw or None,
                                    f"no complete reply within {self.reply_timeout_s:g} s")
            try:
                parse_reply(raw, self.address, Cmd.TELL_POSITION)
            except ValueError:
                log.info("%s: skipped a late reply %r before the TE", self.name, raw)
                continue
            self._te_owed = False
            return

    def _tell_state(self) -> TellState:
        """Read and decode TS; latch its error bits (reading TS clears them on the controller)."""
        value = self._query(Cmd.TELL_STATE)
        try:
            ts = decode_ts(value)
        except ValueError as exc:
            raise ProtocolError(self.name, f"{self.address}TS", value, str(exc)) from exc
        for cause in ts.causes:
            if cause not in self._latched_causes:
                self._latched_causes.append(cause)
        self._last_ts = ts
        return ts

    def _fault_causes(self, ts: TellState) -> list[str]:
        causes = list(self._latched_causes)
        if ts.state == State.STAGE_ERROR:
            causes.append("stage error state (TS state 10)")
        return causes

    def set_soft_limits(self, lo_deg: float, hi_deg: float) -> None:
        """Set the controller's own limits SL/SR (degrees); PA outside them is refused with G."""
        self._require_connected("set soft limits")
        self._call(self._command, Cmd.LIMIT_NEGATIVE, lo_deg * self.units_per_deg)
        self._call(self._command, Cmd.LIMIT_POSITIVE, hi_deg * self.units_per_deg)
        self.soft_limits_units = (lo_deg * self.units_per_deg, hi_deg * self.units_per_deg)

    # ----- protocol hooks ----------------------------------------------------------------------
    def _attach(self, transport) -> None:
        transport.timeout = self.reply_timeout_s
        self._serial = transport

    def _connect(self) -> None:
        self._tell_state()  # proves a controller answers at this address
        lo, hi = self._query(Cmd.LIMIT_NEGATIVE, QUERY), self._query(Cmd.LIMIT_POSITIVE, QUERY)
        try:
            self.soft_limits_units = (float(lo), float(hi))
        except ValueError as exc:
            raise ProtocolError(self.name, f"{self.address}SL?; {self.address}SR?", f"{lo}; {hi}",
                                "expected two numbers") from exc

    def _read_identity(self) -> dict:
        """VE (controller firmware) and ID (stage identifier): read-only queries of the manual."""
        return {"protocol": "smc100", "address": self.address,
                **{key: self._query(cmd, QUERY if cmd is Cmd.STAGE_ID else None).strip()
                   for key, cmd in IDENTITY_QUERIES.items()}}

    def error_text(self, letter: str) -> str:
        """TB: the controller's own text for a TE error letter (read-only)."""
        self._require_connected("read error text")
        return self._call(self._query, Cmd.TELL_ERROR_STRING, letter)

    def _move_taken(self, target: float) -> bool:
        """TH, the set-point: equal to the target once the controller took the PA."""
        value = self._query(Cmd.TELL_SETPOINT)
        try:
            return abs(float(value) / self.units_per_deg - target) <= self.config.tolerance_deg
        except ValueError as exc:
            raise ProtocolError(self.name, f"{self.address}TH", value, "expected a number") from exc

    def _close(self) -> None:
        if self._serial is not None:
            self._serial.close()
            self._serial = None

    def _command_move(self, deg: float) -> None:
        self._command(Cmd.MOVE_ABSOLUTE, deg * self.units_per_deg)

    def _read_position(self) -> float:
        value = self._query(Cmd.TELL_POSITION)
        try:
            return float(value) / self.units_per_deg
        except ValueError as exc:
            raise ProtocolError(self.name, f"{self.address}TP", value, "expected a number") from exc

    def _read_moving(self) -> bool:
        ts = self._tell_state()
        if ts.is_fault:
            causes = self._fault_causes(ts)
            self._latched_causes.clear()  # delivered with this error
            raise DeviceFault(self.name, f"{self.address}TS", f"{self.address}TS{ts.error_bits:04X}"
                              f"{int(ts.state):02X}", causes)
        return ts.state in MOTION_STATES

    def _read_at_rest(self) -> tuple[bool, float]:
        """A TS state outside the motion states is at rest (a stage error state included)."""
        return self._tell_state().state not in MOTION_STATES, self._read_position()

    def _read_referenced(self) -> bool:
        """TS: a stage in a NOT REFERENCED state refuses PA with TE 'H' until OR has run."""
        return self._tell_state().state not in NOT_REFERENCED_STATES

    def _command_home(self) -> None:
        """Reference the stage (OR, ends at 0 units) if needed, then go to ``home_deg``. Reads are
        retried; a lost reply to OR is read back with TS (HOMING or READY: the search started),
        one to the PA with TH, as any move."""
        ts = self._call(self._tell_state)
        if ts.state in NOT_REFERENCED_STATES:
            try:
                self._command(Cmd.HOME)
            except (DeviceTimeout, ProtocolError) as exc:
                state = self._call(self._tell_state).state
                if state != State.HOMING and state not in READY_STATES:
                    raise
                log.info("%s: reply to OR lost (%s); read back: TS state %s, the search started",
                         self.name, exc, state.name)
            if self.config.home_deg == 0.0:
                return
            self._wait_homed()
        self._send_move(self.config.home_deg)

    def _wait_homed(self) -> None:
        """Block until the home search ends (bounded by the longest possible search)."""
        lo, hi = self.config.limits_deg
        t_end = time.monotonic() + self.move_timeout_s(hi - lo)
        while time.monotonic() < t_end:
            ts = self._call(self._tell_state)
            if ts.is_fault:
                raise DeviceFault(self.name, f"{self.address}OR", None, self._fault_causes(ts))
            if ts.state in READY_STATES:
                return
            time.sleep(self.poll_s)
        raise DeviceTimeout(self.name, f"{self.address}OR", None, "home search did not end")

    def _command_stop(self) -> None:
        self._send(Cmd.STOP)

    def _set_enabled(self, enabled: bool) -> None:
        """MM1 / MM0 where the state allows it; NOT REFERENCED stages are enabled by homing."""
        state = self._tell_state().state
        if enabled and state in DISABLE_STATES:
            self._command(Cmd.ENABLE_STATE, MM_ENABLE)
        elif not enabled and state in READY_STATES:
            self._command(Cmd.ENABLE_STATE, MM_DISABLE)

    def _read_fault(self) -> str | None:
        ts = self._tell_state()
        causes = self._fault_causes(ts)
        self._latched_causes.clear()
        return ", ".join(causes) or None

    def _apply_motion_profile(self, speed_deg_s: float, accel_deg_s2: float) -> None:
        self._command(Cmd.VELOCITY, speed_deg_s * self.units_per_deg)
        self._command(Cmd.ACCELERATION, accel_deg_s2 * self.units_per_deg)

    def _status_details(self) -> dict:
        ts = self._last_ts
        return {"protocol": "smc100", "port": self.port, "address": self.address,
                "state": ts.state.name if ts else None,
                "soft_limits_units": self.soft_limits_units}
