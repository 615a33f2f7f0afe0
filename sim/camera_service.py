"""The simulated camera served on loopback, for the rig file of ``goniofrost sim --write-rig``.

One text line each way on 127.0.0.1: ``target NAME`` (``sample``, ``white``, ``flat``),
``expose SECONDS`` (one DNG into the hot folder), ``material SPEC:NAME``; answered ``ok [...]`` or
``error TEXT``. ``python -m sim.camera_service --port P ...`` is the client the rig file's commands
run (exit 0 on ``ok``, else 1).
"""
from __future__ import annotations

import argparse
import select
import socket
import sys
import threading
from pathlib import Path

LOOPBACK = "127.0.0.1"
CLIENT_TIMEOUT_S = 60.0  # the longest exposure of a ladder (16 s) at speed-up 1, with margin
STOP_WAIT_S = 5.0  # how long stop() lets a request under way finish


class CameraService:
    """Serve ``camera`` (a connected ``sim.camera.SimCamera``) on a loopback port; frames go to
    ``folder`` as ``frame_NNNNNN.dng``. ``start()`` returns the port; ``stop()`` ends it.
    ``materials(SPEC:NAME) -> (name, brdf)`` resolves a ``material`` request (None: refused)."""

    def __init__(self, camera, folder: Path, materials=None) -> None:
        self.camera, self.folder, self.materials = camera, Path(folder), materials
        self._default = None  # the material the camera started with, kept at the first change
        self._server = socket.create_server((LOOPBACK, 0))
        self.port = self._server.getsockname()[1]
        # stop() writes a byte here to wake the serving thread: closing a listening socket does not
        # wake a thread blocked in its accept() (Linux), which then kept the port open and stop()
        # waited out its join timeout, 5 s of every `goniofrost sim --write-rig` stopping
        self._wake_read, self._wake_write = socket.socketpair()
        self._count = 0
        self._lock = threading.Lock()  # one frame at a time, as one camera gives
        self._thread = threading.Thread(target=self._serve, name="sim-camera-service", daemon=True)

    def start(self) -> int:
        self.folder.mkdir(parents=True, exist_ok=True)
        self._thread.start()
        return self.port

    def stop(self) -> None:
        """Stop serving and release the port (idempotent). A request under way is given up to
        STOP_WAIT_S to finish (a frame being rendered)."""
        if self._wake_write.fileno() == -1:  # stopped before
            return
        self._wake_write.send(b"\0")
        if self._thread.is_alive():
            self._thread.join(timeout=STOP_WAIT_S)
        for sock in (self._server, self._wake_read, self._wake_write):
            sock.close()

    def _serve(self) -> None:
        while True:
            try:
                ready, _, _ = select.select([self._server, self._wake_read], [], [])
            except (OSError, ValueError):  # closed by a stop() that did not wait for the last request
                return
            if self._wake_read in ready:  # stop()
                return
            try:
                conn, _ = self._server.accept()
                with conn:
                    line = conn.makefile("rb").readline().decode("ascii", "replace").strip()
                    conn.sendall((self.handle(line) + "\n").encode())
            except OSError:  # the client went away (reset before accept, or before the answer)
                continue

    def handle(self, line: str) -> str:
        """One request line -> its answer line."""
        verb, _, arg = line.partition(" ")
        try:
            with self._lock:
                if verb == "target":
                    self.camera.set_target(arg)
                    return "ok"
                if verb == "expose":
                    self._count += 1
                    path = self.folder / f"frame_{self._count:06d}.dng"
                    self.camera.capture(float(arg), path)
                    return f"ok {path}"
                if verb == "material":
                    return f"ok {self._set_material(arg)}"
        except Exception as exc:  # noqa: BLE001 - the client reports it; the service goes on
            return f"error {exc}"
        return (f"error unknown request {line!r} (expected 'target NAME', 'expose SECONDS' or "
                f"'material SPEC:NAME')")

    def _set_material(self, spec: str) -> str:
        """Put material ``spec`` (or ``default``) on the sample card; its name."""
        if self._default is None:
            self._default = (self.camera.material, self.camera.brdf)
        if spec == "default":
            name, brdf = self._default
        elif self.materials is None:
            raise ValueError("this service renders one material only")
        else:
            name, brdf = self.materials(spec)
        self.camera.material, self.camera.brdf = name, brdf
        return name


def request(port: int, line: str, timeout_s: float = CLIENT_TIMEOUT_S) -> str:
    """Send one request line to the service on ``port``; return its answer line."""
    with socket.create_connection((LOOPBACK, int(port)), timeout=timeout_s) as sock:
        sock.sendall((line + "\n").encode())
        return sock.makefile("rb").readline().decode("ascii", "replace").strip()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.camera_service",
                                     description="ask a running `goniofrost sim` for a target or a frame")
    parser.add_argument("--port", type=int, required=True, help="the service's loopback port")
    parser.add_argument("verb", choices=("target", "expose", "material"))
    parser.add_argument("value", help="a target name, an exposure in seconds, or a material SPEC:NAME")
    args = parser.parse_args(argv)
    try:
        answer = request(args.port, f"{args.verb} {args.value}")
    except OSError as exc:
        answer = f"error no simulated camera on 127.0.0.1:{args.port}: {exc}"
    if answer == "ok" or answer.startswith("ok "):
        return 0
    print(f"sim camera: {answer.removeprefix('error ')}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
