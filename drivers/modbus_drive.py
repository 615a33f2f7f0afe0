"""A Modbus motor drive axis (pymodbus, TCP or RTU) driven through a register map.

A move is one direct-data write ending with trigger = 1; positions are drive steps
(``steps_per_deg``), 32-bit values over two registers. Errors: ``ExceptionReply``,
``DeviceTimeout``, ``ChecksumError`` (RTU CRC), ``ProtocolError``, ``DeviceFault`` (ALM-A).
"""
from __future__ import annotations

from collections.abc import Mapping

from pymodbus.client.base import ModbusBaseSyncClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse
from pymodbus.transport import CommParams, CommType

from .axis import Axis, AxisConfig
from .errors import ChecksumError, DeviceError, DeviceFault, DeviceTimeout, ExceptionReply, ProtocolError
from .modbus_map import (
    InputBit, OutputBit, RegisterMap, direct_data_registers, from_registers, resolve_map, to_registers,
)
from .modbus_protocol import (EXCEPTION_BIT, MBAP_LENGTH, FrameError, check_rtu_frame,
                              check_tcp_frame, describe_exception, with_crc)
from .transport import PORT_ERRORS

REPLY_TIMEOUT_S = 0.3
DIAGNOSTICS = 0x08          # function 08, sub-function 0000 "return query data": the drive echoes it
RESYNC_MAX_BYTES = 4096     # a line that streams more than this before the echo is not in sync
# what each client method sends: its function code (a reply of another function answers another request)
FUNCTION_OF = {"read_coils": 1, "read_holding_registers": 3, "read_input_registers": 4, "write_coil": 5,
               "write_registers": 16, "read_device_information": 43}


class TransportClient(ModbusBaseSyncClient):
    """pymodbus's synchronous client on a byte transport it did not open.

    ``ModbusBaseSyncClient`` is pymodbus's own base of its serial and TCP clients: it owns the
    framer (RTU with its CRC, or the MBAP "socket" framer), the transaction ids, the PDUs and every
    request method (``read_holding_registers``, ``write_coil``, ...); a subclass supplies only
    ``send`` and ``recv``. Here they go to ``transport`` (a pyserial port, a ``SocketTransport``, or
    a test's in-memory transport): the rig layer opened it, and closing the client closes it.
    """

    def __init__(self, transport, framer: FramerType, timeout_s: float, trace_packet=None) -> None:
        params = CommParams(comm_type=CommType.SERIAL if framer == FramerType.RTU else CommType.TCP,
                            comm_name="goniofrost", timeout_connect=float(timeout_s))
        super().__init__(framer, 0, params, trace_packet, None, None)
        transport.timeout = float(timeout_s)
        self.transport = transport
        self._tcp = framer != FramerType.RTU
        self._pending = b""  # TCP: bytes after the first MBAP frame recv() handed over

    def connect(self) -> bool:
        return self.transport is not None

    @property
    def connected(self) -> bool:
        return self.transport is not None

    def close(self) -> None:
        if self.transport is not None:
            transport, self.transport = self.transport, None
            transport.close()

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        if self.transport is None:
            raise ConnectionException("transport closed")
        self._pending = b""
        self.transport.reset_input_buffer()  # drops a late reply already here; one still on its
        # way is told apart by pymodbus (TCP transaction id) or ModbusLink (RTU: resync, function, size)
        self.transport.write(request)
        return len(request)

    def recv(self, size: int | None) -> bytes:
        """What has arrived: waits up to the timeout for a first byte (b"" on silence: pymodbus
        then calls it a timeout), then takes what is waiting; the framer asks again for the rest.

        TCP: at most one MBAP frame at a time (the rest waits for the next call). pymodbus 3.12
        skips a frame of another transaction id (a late reply) but decodes its buffer from the
        start again for the next frame, so the awaited reply arriving behind a late one in the
        same read would be thrown away with it (a spurious timeout)."""
        if self.transport is None:
            raise ConnectionException("transport closed")
        data, self._pending = self._pending, b""
        if not data:
            data = self.transport.read(1 if size is None else size)
        if data and size is None and self.transport.in_waiting:
            data += self.transport.read(self.transport.in_waiting)
        if self._tcp and len(data) >= MBAP_LENGTH.stop:
            end = MBAP_LENGTH.stop + int.from_bytes(data[MBAP_LENGTH], "big")
            data, self._pending = data[:end], data[end:]
        return data


class ModbusLink:
    """One pymodbus client (TCP or RTU framing) on a transport, whose calls raise the typed driver
    errors. Shared by the motor axis and the lamp that sits on the same drive. ``name`` is used in
    error messages (the axis or device name); ``where`` (port path or host:port) too.
    """

    def __init__(self, name: str, device_id: int = 1, rtu: bool = False,
                 timeout_s: float = REPLY_TIMEOUT_S, where: str = "") -> None:
        self.name, self.device_id, self.rtu, self.where = name, int(device_id), bool(rtu), where
        self.timeout_s = float(timeout_s)
        self.client: TransportClient | None = None
        self._last_rx = b""
        self._in_doubt = False  # RTU: a request went unanswered, its reply may still be on the way
        self._echo_token = 0

    def open(self, transport) -> None:
        """Take the transport the rig layer opened (the link owns it from now on)."""
        self.close()
        self.client = TransportClient(transport, FramerType.RTU if self.rtu else FramerType.SOCKET,
                                      self.timeout_s, trace_packet=self._trace)

    @property
    def is_open(self) -> bool:
        return self.client is not None

    def close(self) -> None:
        if self.client is not None:
            client, self.client = self.client, None
            client.close()

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """Keep the raw bytes of the last reply, to tell a bad CRC or frame from silence."""
        if sending:
            self._last_rx = b""
        else:
            self._last_rx = bytes(data)
        return data

    def call(self, text: str, method: str, *args, **kwargs):
        """Run one client request; return the response or raise the matching DeviceError.

        A late reply must not answer a later request. Modbus TCP replies carry the request's
        transaction id (pymodbus skips others). An RTU reply carries only unit, function and data
        (a read's reply not even its address), so a late reply of the same shape is
        indistinguishable: after a request that went unanswered (or answered by a reply of
        another request) the link resyncs first (``_resync``). A reply of another function or
        size is a ProtocolError (retried like a damaged reply), never a value.
        """
        if self.client is None:
            raise DeviceTimeout(self.name, text, None, "not connected")
        if self.rtu and self._in_doubt:
            try:
                self._resync(text)
            except DeviceError as exc:  # the request still goes out (a stop must reach the drive),
                try:                    # but no reply can be trusted: the resync's error is raised
                    self._request(text, method, *args, **kwargs)
                except DeviceError:
                    pass
                raise exc
        response = self._request(text, method, *args, **kwargs)
        mismatch = self._mismatch(method, args, kwargs, response)
        if mismatch:
            self._in_doubt = True
            raise ProtocolError(self.name, text, self._last_rx or None,
                                f"a reply to another request (late?): {mismatch}")
        if isinstance(response, ExceptionResponse) or response.isError():
            code = getattr(response, "exception_code", None)
            raise ExceptionReply(self.name, text, self._last_rx or None, describe_exception(code), code=code)
        return response

    def _request(self, text: str, method: str, *args, **kwargs):
        """One pymodbus request: its response, or the driver error of a reply not accepted."""
        try:
            return getattr(self.client, method)(*args, device_id=self.device_id, **kwargs)
        except (ConnectionException, *PORT_ERRORS) as exc:  # OSError: the port vanished (EIO)
            self._in_doubt = True
            raise DeviceTimeout(self.name, text, None, f"connection lost: {exc}") from exc
        except ModbusException as exc:
            self._in_doubt = True
            raise self._classify_silence(text, exc) from exc

    @staticmethod
    def _mismatch(method: str, args: tuple, kwargs: dict, response) -> str | None:
        """Why ``response`` cannot be the reply to this request (None when it can): another
        function, another number of registers or bits, another written address or value."""
        function = FUNCTION_OF.get(method)
        got = getattr(response, "function_code", None)
        if function is None or got == function | EXCEPTION_BIT:
            return None
        if got != function:
            return f"function {got}, expected {function}"
        count = kwargs.get("count", 1)
        if function in (3, 4) and len(response.registers) != count:
            return f"{len(response.registers)} registers, expected {count}"
        if function == 1 and len(response.bits) != 8 * -(-count // 8):
            return f"{len(response.bits)} bits, expected {count}"
        if function == 16 and (response.address, response.count) != (args[0], len(args[1])):
            return f"write echo {response.count} at 0x{response.address:04X}, expected {len(args[1])} at 0x{args[0]:04X}"
        if function == 5 and (response.address, response.bits[:1]) != (args[0], [bool(args[1])]):
            return f"coil echo {response.bits[:1]} at {response.address}, expected {bool(args[1])} at {args[0]}"
        return None

    def _resync(self, text: str) -> None:
        """RTU only: send a diagnostics echo (08 / 0000) with a fresh token and skip every byte
        until its echo (or the drive's exception 0x88: it lacks function 08) comes back. The drive
        answers in order, so every late reply of an earlier request came before: the line is clean.
        No echo within the reply timeout raises like an unanswered request (the caller retries)."""
        transport = self.client.transport
        self._echo_token = self._echo_token % 0xFFFF + 1
        echo = with_crc(bytes([self.device_id, DIAGNOSTICS, 0, 0]) + self._echo_token.to_bytes(2, "big"))
        refusal = bytes([self.device_id, DIAGNOSTICS | EXCEPTION_BIT])
        what = f"{text}: resync (diagnostics echo)"
        buf = bytearray()
        try:
            transport.reset_input_buffer()
            transport.write(echo)
            while echo not in buf and not any(with_crc(buf[i:i + 3]) == buf[i:i + 5]
                                               for i in range(len(buf)) if buf[i:i + 2] == refusal):
                chunk = transport.read(1)
                if not chunk or len(buf) > RESYNC_MAX_BYTES:
                    self._last_rx = bytes(buf)
                    raise self._classify_silence(what, ModbusException("no echo before the line went quiet"))
                buf += chunk + (transport.read(transport.in_waiting) if transport.in_waiting else b"")
        except PORT_ERRORS as exc:
            raise DeviceTimeout(self.name, what, None, f"connection lost: {exc}") from exc
        self._in_doubt = False

    def _classify_silence(self, text: str, exc: Exception) -> DeviceError:
        """No accepted reply: was it silence, a bad CRC (RTU) or a malformed frame (TCP)?"""
        raw = self._last_rx
        if not raw:
            return DeviceTimeout(self.name, text, None, f"no reply within {self.timeout_s:g} s")
        try:
            check_rtu_frame(raw) if self.rtu else check_tcp_frame(raw)
        except FrameError as bad:
            return (ChecksumError if bad.kind == "crc" else ProtocolError)(self.name, text, raw, str(bad))
        return ProtocolError(self.name, text, raw, str(exc))

    def read_holding(self, address: int, count: int) -> list[int]:
        return self.call(f"read holding 0x{address:04X} x{count}", "read_holding_registers",
                         address, count=count).registers

    def write_holding(self, address: int, values: list[int]) -> None:
        self.call(f"write holding 0x{address:04X} x{len(values)}", "write_registers", address, values)

    def device_identification(self) -> dict[str, str]:
        """Read Device Identification (function 43 / MEI 14), basic objects: vendor name, product
        code, revision (object id -> text as the drive gives them)."""
        response = self.call("read device identification (43/14)", "read_device_information")
        names = {0: "vendor", 1: "product_code", 2: "revision", 3: "vendor_url", 4: "product_name",
                 5: "model_name"}
        return {names.get(k, f"object_{k}"): v.decode("ascii", "replace") if isinstance(v, bytes) else str(v)
                for k, v in sorted(response.information.items())}


class ModbusAxis(Axis):
    """One motor on a Modbus drive: RTU framing (``rtu=True``, a serial line) or Modbus TCP.

    ``steps_per_deg``: drive steps per degree; ``word_order``: "big" or "little";
    ``register_map``: a map name, an inline mapping or a RegisterMap; ``timeout_s``: reply
    timeout (real seconds); ``where``: the port path or host:port, for messages (the rig layer opens it).
    """

    def __init__(self, config: AxisConfig, *, rtu: bool = False, device_id: int = 1,
                 steps_per_deg: float = 100.0, word_order: str = "big", register_map="oriental-az",
                 timeout_s: float = REPLY_TIMEOUT_S, where: str = "") -> None:
        super().__init__(config)
        self.link = ModbusLink(config.name, device_id, rtu, timeout_s, where)
        self.steps_per_deg, self.word_order = float(steps_per_deg), word_order
        self.map: RegisterMap = resolve_map(register_map)
        self._speed_hz, self._rate = 1000, 1000

    @classmethod
    def from_section(cls, config: AxisConfig, section: Mapping) -> "ModbusAxis":
        """Build from a validated ``modbus-tcp`` or ``modbus-rtu`` driver section."""
        rtu = section["protocol"] == "modbus-rtu"
        return cls(config, rtu=rtu, device_id=section.get("device_id", 1),
                   steps_per_deg=section.get("steps_per_deg", 100.0),
                   word_order=section.get("word_order", "big"),
                   register_map=section.get("register_map", "oriental-az"),
                   timeout_s=section.get("reply_timeout_ms", REPLY_TIMEOUT_S * 1000.0) / 1000.0,
                   where=section["port"] if rtu else f"{section.get('host', '127.0.0.1')}:{section['port']}")

    # ----- registers -------------------------------------------------------------------------
    def _read32(self, address: int, signed: bool = True) -> int:
        return from_registers(self.link.read_holding(address, 2), self.word_order, signed)

    def _status_word(self) -> int:
        return self._read32(self.map.output_status, signed=False)

    def _bit(self, word: int, bit: OutputBit) -> bool:
        return bool(word >> self.map.output_bits[bit] & 1)

    def _write_inputs(self, *bits: InputBit) -> None:
        word = sum(1 << self.map.input_bits[b] for b in bits)
        self.link.write_holding(self.map.input_command, to_registers(word, self.word_order))

    def _alarm(self) -> str:
        return self.map.alarm_text(self._read32(self.map.alarm_code, signed=False))

    def reset_alarm(self) -> None:
        """Pulse ALM-RST (on, then off); the drive clears the alarm once its cause has gone."""
        self._write_inputs(InputBit.ALM_RST)
        self._write_inputs()

    # ----- protocol hooks --------------------------------------------------------------------
    def _attach(self, transport) -> None:
        self.link.open(transport)

    def _connect(self) -> None:
        self._status_word()  # proves the drive answers at this device id

    def _read_identity(self) -> dict:
        """The drive's Read Device Identification (43/14) when it answers it; a drive that refuses
        the function (exception 1) still gives its map's identity and device id."""
        out = {"protocol": "modbus-rtu" if self.link.rtu else "modbus-tcp", "device_id": self.link.device_id,
               "register_map": self.map.name}
        try:
            out.update(self.link.device_identification())
        except ExceptionReply as exc:
            out["identification"] = f"not supported ({exc.detail})"
        return out

    def _close(self) -> None:
        self.link.close()

    def _command_move(self, deg: float) -> None:
        steps = round(deg * self.steps_per_deg)
        regs = direct_data_registers(steps, self._speed_hz, self._rate, self._rate, self.word_order)
        self.link.write_holding(self.map.direct_data, regs)

    def _read_position(self) -> float:
        return self._read32(self.map.feedback_position) / self.steps_per_deg

    def _read_moving(self) -> bool:
        word = self._status_word()
        if self._bit(word, OutputBit.ALM_A):
            raise DeviceFault(self.name, f"read status 0x{self.map.output_status:04X}",
                              f"0x{word:04X}", [self._alarm()])
        return self._bit(word, OutputBit.MOVE)

    def _read_at_rest(self) -> tuple[bool, float]:
        """MOVE off is at rest, alarm or not (an alarm stops the motor)."""
        return not self._bit(self._status_word(), OutputBit.MOVE), self._read_position()

    def _command_stop(self) -> None:
        self._write_inputs(InputBit.STOP)
        self._write_inputs()

    def _set_enabled(self, enabled: bool) -> None:
        if enabled:
            self._write_inputs()
        else:
            self._write_inputs(InputBit.FREE)

    def _read_fault(self) -> str | None:
        return self._alarm() if self._bit(self._status_word(), OutputBit.ALM_A) else None

    def _apply_motion_profile(self, speed_deg_s: float, accel_deg_s2: float) -> None:
        """Kept for the next direct-data write (the AZ takes speed and rate with every move)."""
        self._speed_hz = max(1, round(speed_deg_s * self.steps_per_deg))
        self._rate = max(1, round(accel_deg_s2 * self.steps_per_deg))

    def _status_details(self) -> dict:
        return {"protocol": "modbus-rtu" if self.link.rtu else "modbus-tcp",
                "device_id": self.link.device_id, "register_map": self.map.name}
