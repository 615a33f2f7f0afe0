"""A simulated Modbus motor drive (Oriental AZ-style register map) that also hosts the lamp.

A real pymodbus server, TCP on loopback or RTU on a pseudo-terminal. A direct-data write with
trigger = 1 starts a trapezoidal move; coil ``coil`` switches the lamp, input register
``photodiode_register`` reads its photodiode. Addresses follow PROTOCOLS.md section 3.
"""
from __future__ import annotations

import asyncio
import select
import threading
from collections import deque

from pymodbus import ModbusDeviceIdentification
from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

from drivers.modbus_map import (
    INTERLOCK_CLOSED, TRIGGER_ALL_DATA, DirectData, InputBit, OperationType, OutputBit, from_registers, resolve_map, to_registers,
)
from drivers.modbus_protocol import corrupt_checksum, drop_last_byte
from sim.clock import SimClock
from sim.faults import ArmedFaults, check_kind
from sim.lamp_model import LampModel
from sim.motion import TrapezoidMotion
from sim.pty_port import PtyPort

ALARM_OVERLOAD = 0x30  # the alarm an injected "alarm" raises
LOOPBACK = "127.0.0.1"


class _Block(ModbusSequentialDataBlock):
    """A register/coil block starting at block address 1 (= PDU address 0) with hooks.

    ``before_read(pdu_address, count)`` refreshes computed values; ``on_write(pdu_address,
    values)`` reacts to a write and may return an ExcCodes member to refuse it (nothing stored).
    """

    def __init__(self, count: int, before_read=None, on_write=None) -> None:
        super().__init__(1, [0] * count)
        self._before_read, self._on_write = before_read, on_write

    def getValues(self, address, count=1):
        if self._before_read is not None:
            self._before_read(address - 1, count)
        return super().getValues(address, count)

    def setValues(self, address, values):
        values = values if isinstance(values, list) else [values]
        if self._on_write is not None:
            refused = self._on_write(address - 1, values)
            if refused is not None:
                return refused
        return super().setValues(address, values)

    def word(self, pdu_address: int) -> int:
        return int(self.values[pdu_address])

    def put(self, pdu_address: int, words: list[int]) -> None:
        self.values[pdu_address:pdu_address + len(words)] = [int(w) for w in words]


class SimulatedModbusDrive(ArmedFaults):
    """One Modbus drive with one motor (in steps) plus the lamp coil and photodiode register.

    Parameters: ``clock``; ``transport`` "tcp" (``host`` 127.0.0.1, ``port`` 0 = a free port) or
    "rtu" (a pty; ``baud``; ``parity`` must stay "N": Linux ptys refuse parity with EINVAL); ``device_id``; ``steps_per_deg``; ``word_order``;
    ``register_map`` (name, mapping or RegisterMap); ``position_deg`` at power-up; ``lamp``
    (a shared LampModel, else an own one); ``coil``; ``photodiode_register``; ``interlock_input``:
    the discrete input of an interlock (reads ``INTERLOCK_CLOSED`` but while an ``interlock_open``
    drill lasts, ``open_interlock``).
    """

    def __init__(self, clock: SimClock, transport: str = "tcp", host: str = LOOPBACK, port: int = 0,
                 device_id: int = 1, steps_per_deg: float = 100.0, word_order: str = "big",
                 register_map="oriental-az", position_deg: float = 90.0, baud: int = 115200,
                 parity: str = "N", lamp: LampModel | None = None, coil: int = 0,
                 photodiode_register: int = 0x0200, interlock_input: int = 0) -> None:
        if transport not in ("tcp", "rtu"):
            raise ValueError(f"transport must be 'tcp' or 'rtu', got {transport!r}")
        if host != LOOPBACK:
            raise ValueError(f"the simulated drive serves on {LOOPBACK} only, got {host!r}")
        self.clock, self.transport, self.host, self.port = clock, transport, host, int(port)
        self.device_id, self.steps_per_deg = int(device_id), float(steps_per_deg)
        self.word_order, self.map = word_order, resolve_map(register_map)
        self.baud, self.parity = int(baud), parity
        self.lamp = lamp if lamp is not None else LampModel(clock)
        self.coil, self.photodiode_register = int(coil), int(photodiode_register)
        self.motion = TrapezoidMotion(clock, position_deg * self.steps_per_deg, 1000.0, 1000.0)
        self.alarm_code = 0
        self.free = False  # FREE input on: motor de-energised
        self.faults: set[str] = set()
        self.missing_replies = 0  # miss_reply: this many replies are lost, then it answers
        self._init_armed()
        self.writes: deque = deque(maxlen=10_000)  # recent holding-register writes (PDU address, values)
        self.requests: deque = deque(maxlen=10_000)  # recent raw requests, for byte-exact tests
        self._lock = threading.RLock()
        self._holding = _Block(self.map.highest_holding_register() + 1, self._refresh, self._on_write)
        self._coils = _Block(max(self.coil + 1, 16), self._refresh_coils, self._on_coil_write)
        self._inputs = _Block(self.photodiode_register + 1, self._refresh_inputs)
        self.interlock_input, self._interlock_open = int(interlock_input), (0.0, 0.0)  # nominal s [start, end)
        self._silent = (0.0, 0.0)  # nominal s [start, end) of a silent drill
        self._discrete = _Block(self.interlock_input + 1, self._refresh_discrete)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server = None
        self._bridge: _PtyBridge | None = None
        self.endpoint: dict | None = None

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> dict:
        """Start the server in a background thread; return the endpoint entry ``goniofrost sim`` prints."""
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="sim-modbus", daemon=True)
        self._thread.start()
        if self.transport == "rtu":
            self._bridge = _PtyBridge(self)
        asyncio.run_coroutine_threadsafe(self._serve(), self._loop).result(timeout=5)
        if self.transport == "rtu":
            self._bridge.start()
            self.endpoint = {"protocol": "modbus-rtu", "endpoint": self._bridge.client_path,
                             "id": self.device_id, "baud": self.baud}
        else:
            self.endpoint = {"protocol": "modbus-tcp", "endpoint": f"{self.host}:{self.port}",
                             "id": self.device_id, "baud": None}
        return dict(self.endpoint)

    def lamp_entry(self) -> dict:
        """The lamp's endpoint entry: this drive's endpoint plus the coil and photodiode register."""
        return {**self.endpoint, "coil": self.coil, "photodiode_register": self.photodiode_register}

    def stop(self) -> None:
        """Shut the server down and release the port (idempotent)."""
        if self._loop is None:
            return
        if self._server is not None:
            asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(timeout=5)
            self._server = None
        if self._bridge is not None:
            self._bridge.stop()
            self._bridge = None
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        self._loop.close()
        self._loop = None

    def place(self, position: float) -> None:
        """Put the axis at rest at ``position`` (device units), as journaled by an earlier run of the
        session (``sim.rig.SimulatedRig.restore``): nothing moves, no fault strikes."""
        with self._lock:
            self.motion.set_position(float(position))

    def true_position_deg(self) -> float:
        """Ground truth: where the motor really is, in degrees."""
        return self.motion.position() / self.steps_per_deg

    def inject_fault(self, kind: str) -> None:
        """Inject a fault (see sim.faults.FAULT_KINDS); all but disconnect last until ``inject_fault('clear')``.

        miss_reply: the next reply is lost (the request is acted on), then it answers as before.
        no_reply: requests are acted on but no reply goes out. bad_checksum: RTU replies carry a
        wrong CRC; TCP has no checksum, so the MBAP protocol id is corrupted instead. drop_byte:
        each reply loses its last byte. alarm: alarm code 0x30 (overload), ALM-A on, motor
        stopped; moves are ignored until ALM-RST (which works once the fault is cleared). stall: the motor freezes while MOVE stays on.
        disconnect: the drive goes off line (server closed, motor stopped).
        """
        check_kind(kind)
        with self._lock:
            if kind == "miss_reply":  # one lost reply, not a lasting fault
                self.missing_replies += 1
                return
            if kind == "clear":  # removes the causes; an alarm stays latched until ALM-RST
                self.faults.clear()
                return
            self.faults.add(kind)
            if kind == "alarm":
                self.alarm_code = ALARM_OVERLOAD
                self.motion.stop()
            elif kind == "stall":
                self.motion.stall()
            elif kind == "disconnect":
                self.motion.stop()
        if kind == "disconnect":
            self._go_offline()

    def _strike(self, kind: str) -> None:
        """An armed fault strikes while the server's event loop handles a request: going off line
        waits on that loop, so it happens in another thread (the reply is already suppressed)."""
        if kind != "disconnect":
            self.inject_fault(kind)
            return
        self.faults.add(kind)
        self.motion.stop()
        threading.Thread(target=self._go_offline, name="sim-modbus-offline", daemon=True).start()

    # --- server ----------------------------------------------------------------------------
    IDENTITY = {"VendorName": "ORIENTAL MOTOR", "ProductCode": "AZD-KD", "MajorMinorRevision": "4.00",
                "ProductName": "AZ series driver (simulated)"}  # Read Device Identification (43/14)

    def _context(self) -> ModbusServerContext:
        device = ModbusDeviceContext(hr=self._holding, co=self._coils, ir=self._inputs, di=self._discrete)
        return ModbusServerContext(devices={self.device_id: device}, single=False)

    async def _serve(self) -> None:
        """Create and start the pymodbus server (it needs the running loop of its thread)."""
        if self.transport == "tcp":
            self._server = ModbusTcpServer(self._context(), address=(self.host, self.port),
                                           identity=ModbusDeviceIdentification(info_name=self.IDENTITY),
                                           trace_packet=self._trace_packet)
        else:
            self._server = ModbusSerialServer(self._context(), framer=FramerType.RTU,
                                              port=self._bridge.server_path, baudrate=self.baud,
                                              parity=self.parity, trace_packet=self._trace_packet,
                                              identity=ModbusDeviceIdentification(info_name=self.IDENTITY))
        await self._server.serve_forever(background=True)
        if self.transport == "tcp":
            self.port = self._server.transport.sockets[0].getsockname()[1]

    def _go_offline(self) -> None:
        if self._bridge is not None:
            self._bridge.stop()
        elif self._server is not None and self._loop is not None:
            server, self._server = self._server, None
            asyncio.run_coroutine_threadsafe(server.shutdown(), self._loop).result(timeout=5)

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """Apply the wire faults to outgoing frames (pymodbus calls this for every packet)."""
        if not sending:
            self.requests.append(bytes(data))
            return data
        if not data:
            return data
        faults = self.faults
        if self.missing_replies:
            with self._lock:
                self.missing_replies -= 1
            return b""
        if "no_reply" in faults or "disconnect" in faults or self._silent_now():
            return b""
        if "bad_checksum" in faults:
            data = corrupt_checksum(data, rtu=self.transport == "rtu")
        if "drop_byte" in faults:
            data = drop_last_byte(data)
        return data

    # --- register behaviour ----------------------------------------------------------------
    def _status_word(self) -> int:
        bits = self.map.output_bits
        moving = self.motion.is_moving()
        word = 0
        if self.alarm_code:
            word |= 1 << bits[OutputBit.ALM_A]
        if moving:
            word |= 1 << bits[OutputBit.MOVE]
        if not moving and not self.alarm_code and not self.free:
            word |= 1 << bits[OutputBit.READY]
        if not moving and abs(self.motion.position() - self.motion.target) < 1.0:
            word |= 1 << bits[OutputBit.IN_POS]
        return word

    def _refresh(self, pdu_address: int, count: int) -> None:
        """Compute status, alarm and positions into the holding registers before a read."""
        with self._lock:
            m, order = self.map, self.word_order
            self._holding.put(m.output_status, to_registers(self._status_word(), order))
            self._holding.put(m.alarm_code, to_registers(self.alarm_code, order))
            self._holding.put(m.feedback_position, to_registers(round(self.motion.position()), order))
            self._holding.put(m.command_position, to_registers(round(self.motion.target), order))

    def _on_write(self, pdu_address: int, values: list[int]):
        """React to a holding-register write; return an ExcCodes member to refuse it."""
        with self._lock:
            self.writes.append((pdu_address, list(values)))
            end = pdu_address + len(values)
            trigger = self.map.direct_data + 2 * DirectData.TRIGGER
            if pdu_address <= trigger and end >= trigger + 2:
                refused = self._direct_data(pdu_address, values)
                if refused is not None:
                    return refused
            command = self.map.input_command
            if pdu_address <= command and end >= command + 2:
                self._input_command(values[command - pdu_address:command - pdu_address + 2])
            return None

    def _direct_data(self, pdu_address: int, values: list[int]):
        """A write reaching the trigger: start the move it describes (after storing it)."""
        block = list(self._holding.values)
        block[pdu_address:pdu_address + len(values)] = values
        base = self.map.direct_data

        def value(index: int) -> int:
            return from_registers(block[base + 2 * index: base + 2 * index + 2], self.word_order)

        kind, speed, rate = value(DirectData.OPERATION_TYPE), value(DirectData.SPEED), value(DirectData.RATE)
        if value(DirectData.TRIGGER) != TRIGGER_ALL_DATA:
            return None
        if kind not in tuple(OperationType) or speed <= 0 or rate <= 0:
            return ExcCodes.ILLEGAL_VALUE
        if self.alarm_code or self.free:
            return None  # an alarmed or de-energised drive ignores the trigger
        target = value(DirectData.POSITION) + (self.motion.target if kind == OperationType.INCREMENTAL else 0)
        self.motion.set_profile(speed, rate)
        if self.motion.start_move(target) > 0:
            self._move_started()
        return None

    def _input_command(self, words: list[int]) -> None:
        bits, word = self.map.input_bits, from_registers(words, self.word_order, signed=False)

        def on(bit: InputBit) -> bool:
            return bool(word >> bits[bit] & 1)

        if on(InputBit.STOP) or on(InputBit.FREE):
            self.motion.stop()
        self.free = on(InputBit.FREE)
        if on(InputBit.ALM_RST) and "alarm" not in self.faults:
            self.alarm_code = 0  # a reset clears the alarm only once its cause has gone
        if on(InputBit.ZHOME) and not self.alarm_code and not self.free:
            if self.motion.start_move(0.0) > 0:
                self._move_started()

    def _refresh_coils(self, pdu_address: int, count: int) -> None:
        self._coils.put(self.coil, [bool(self.lamp.is_on)])

    def _on_coil_write(self, pdu_address: int, values: list[int]):
        if pdu_address <= self.coil < pdu_address + len(values):
            self.lamp.is_on = bool(values[self.coil - pdu_address])
        return None

    def _refresh_inputs(self, pdu_address: int, count: int) -> None:
        self._inputs.put(self.photodiode_register, [self.lamp.photodiode_counts()])

    def open_interlock(self, duration_s: float) -> None:
        """Open the interlock for ``duration_s`` nominal seconds from now (the ``interlock_open`` drill)."""
        t0 = self.clock.nominal_time()
        with self._lock:
            self._interlock_open = (t0, t0 + float(duration_s))

    def go_silent(self, duration_s: float) -> None:
        """Answer nothing for ``duration_s`` nominal seconds from now (the ``silent`` drill)."""
        t0 = self.clock.nominal_time()
        with self._lock:
            self._silent = (t0, t0 + float(duration_s))

    def _silent_now(self) -> bool:
        start, end = self._silent
        return start <= self.clock.nominal_time() < end

    def _refresh_discrete(self, pdu_address: int, count: int) -> None:
        start, end = self._interlock_open
        closed = not start <= self.clock.nominal_time() < end
        self._discrete.put(self.interlock_input, [INTERLOCK_CLOSED if closed else 1 - INTERLOCK_CLOSED])


class _PtyBridge:
    """Two ptys joined by a thread: the server opens one, the client the other (a pty master has no
    path a serial server could open)."""

    def __init__(self, drive: SimulatedModbusDrive) -> None:
        self._server_side, self._client_side = PtyPort(), PtyPort()
        self.server_path, self.client_path = self._server_side.path, self._client_side.path
        self._running = False
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._running = True
        self._thread = threading.Thread(target=self._run, name="sim-modbus-rtu-bridge", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        a, b = self._server_side, self._client_side
        try:
            while self._running:
                ready, _, _ = select.select([a.master_fd, b.master_fd], [], [], 0.05)
                for src, dst in ((a, b), (b, a)):
                    if src.master_fd in ready:
                        dst.write(src.read(0))
        finally:
            b.close()

    def stop(self) -> None:
        """Stop copying and close the client's pty (the cable is pulled)."""
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)
            self._thread = None
            self._server_side.close()
