"""Probes for what must not leak out of the server: a file of another user opened or read, a
request sent to the network.

- :class:`FileWatch`: Linux inotify (through ctypes). ``with FileWatch(path) as w: ...; assert
  w.events() == []``: the kernel reports every open and every read of a watched file by any
  process (the server's workers included), so no event means "0 bytes read".
- :class:`CountingListener`: a TCP listener on 127.0.0.1 that counts the connections it
  accepts and never answers (a URL that never answers is what once froze the API): "0 requests
  reach the listener".

The gate's tests show both have teeth (they see a read, they count a request).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import socket
import struct
import threading
import time
from pathlib import Path

IN_ACCESS = 0x001
IN_OPEN = 0x020
NAMES = {IN_ACCESS: "read", IN_OPEN: "open"}


class FileWatch:
    """inotify watches on ``paths`` for opens and reads (IN_OPEN, IN_ACCESS)."""

    def __init__(self, *paths: str | os.PathLike[str]):
        self._libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        self.fd = self._libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if self.fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1")
        self.paths = {}
        for p in paths:
            wd = self._libc.inotify_add_watch(self.fd, os.fsencode(str(p)), IN_ACCESS | IN_OPEN)
            if wd < 0:
                raise OSError(ctypes.get_errno(), f"inotify_add_watch {p}")
            self.paths[wd] = Path(p)
        self._seen: list[tuple[Path, str]] = []

    def events(self, settle_s: float = 0.2) -> list[tuple[Path, str]]:
        """Every (path, "open" | "read") seen so far (after ``settle_s`` for the queue to fill)."""
        time.sleep(settle_s)
        while True:
            try:
                data = os.read(self.fd, 65536)
            except BlockingIOError:
                return list(self._seen)
            i = 0
            while i < len(data):
                wd, mask, _cookie, length = struct.unpack_from("iIII", data, i)
                i += 16 + length
                for bit, name in NAMES.items():
                    if mask & bit:
                        self._seen.append((self.paths.get(wd, Path("?")), name))

    def close(self) -> None:
        os.close(self.fd)

    def __enter__(self) -> "FileWatch":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CountingListener:
    """A TCP listener on 127.0.0.1 (``port``, ``url``) counting the connections it accepts
    (``count``) and the first bytes of each (``requests``); it never answers and holds each
    connection until closed."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(128)
        self.port = self.sock.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.requests: list[bytes] = []
        self._held: list[socket.socket] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name="counting-listener", daemon=True)
        self._thread.start()

    @property
    def count(self) -> int:
        with self._lock:
            return len(self.requests)

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            conn.settimeout(0.5)
            try:
                first = conn.recv(4096)
            except OSError:
                first = b""
            with self._lock:
                self.requests.append(first)
                self._held.append(conn)

    def close(self) -> None:
        self.sock.close()
        with self._lock:
            for c in self._held:
                c.close()
            self._held = []

    def __enter__(self) -> "CountingListener":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
