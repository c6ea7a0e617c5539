"""The control socket's server: one event loop, every client bounded in bytes, time and number.

What a client can cost the server, whoever it is:
- another uid: one accept, one SO_PEERCRED read and a one-line refusal; nothing it sent is read;
- bytes: a request is one line of at most MAX_REQUEST bytes, read incrementally; a longer one is
  refused after MAX_REQUEST + 1 bytes, the rest never read;
- time: REQUEST_DEADLINE_S from accept to a whole request, REPLY_DEADLINE_S to take the reply;
  a client that sends one byte a second is cut off like an idle one;
- number: at most MAX_CONNECTIONS open; a new owner connection evicts the oldest still waiting
  for its request, so idle connections never lock the owner out (the listen backlog never fills).

`handler(request)` returns the reply (a dict, or a whole pre-encoded line as bytes), or a
`Deferred` from `defer()` that is answered later with `complete()` (a command another process
handles). The loop runs in `serve()`, in a thread with `start()`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import selectors
import socket
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable

from .control_socket import (MAX_REQUEST, bind_listener, encode_reply, parse_request, peer_credentials,
                             peer_allowed, refusal_for)

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 32          # a person runs a handful of commands at once; this many is far more
REQUEST_DEADLINE_S = 2.0      # the client library sends its request at once after connecting
REPLY_DEADLINE_S = 2.0        # a status reply is a few kB: a client that will not take it is gone
FORWARD_DEADLINE_S = 60.0     # a reload may load and warm up a new model in the main process
ACCEPT_BATCH = 64             # accepts per wake-up, so replies and deadlines are never starved
LOG_EVERY_S = 10.0            # refusals and cut-offs are summed up in one log line this often
IDLE_WAKE_S = 0.5             # the loop's longest sleep (stop requests are seen this fast)

READING, WAITING, WRITING = "reading", "waiting", "writing"

Reply = dict | bytes
Handler = Callable[[dict[str, Any]], "Reply | Deferred"]


class Deferred:
    """A reply promised by the handler; answer it with `ControlServer.complete`."""

    __slots__ = ("conn",)

    def __init__(self, conn: "_Conn") -> None:
        self.conn = conn


class _Conn:
    __slots__ = ("sock", "buf", "deadline", "out", "state")

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock = sock
        self.buf = bytearray()
        self.deadline = deadline
        self.out = memoryview(b"")
        self.state = READING


class ControlServer:
    """Serves one-request connections on a listening Unix socket (bound here from `path`, or given)."""

    def __init__(self, path: Path | None, handler: Handler, owner_uid: int | None = None, *,
                 listener: socket.socket | None = None, max_connections: int = MAX_CONNECTIONS,
                 request_deadline_s: float = REQUEST_DEADLINE_S) -> None:
        if listener is None:
            if path is None:
                raise ValueError("ControlServer needs a path or a listening socket")
            listener = bind_listener(Path(path))
        listener.setblocking(False)
        self.path = Path(path) if path is not None else None
        self.handler = handler
        self.owner_uid = os.geteuid() if owner_uid is None else owner_uid
        self.max_connections = max_connections
        self.request_deadline_s = request_deadline_s
        self.counters = {"served": 0, "refused_uid": 0, "bad": 0, "too_long": 0, "timed_out": 0, "evicted": 0}
        self._listener = listener
        self._sel = selectors.DefaultSelector()
        self._sel.register(listener, selectors.EVENT_READ, None)
        self._conns: OrderedDict[int, _Conn] = OrderedDict()     # oldest first
        self._watched: dict[int, Callable[[], None]] = {}
        self._current: _Conn | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._logged = dict(self.counters)
        self._next_log = time.monotonic() + LOG_EVERY_S
        self._refused_uids: set[int] = set()

    # ---- running ------------------------------------------------------------------------------
    def start(self) -> "ControlServer":
        """Serve in a background thread (tests, and processes with nothing else to do)."""
        self._thread = threading.Thread(target=self.serve, name="gma-ffc-control", daemon=True)
        self._thread.start()
        return self

    def serve(self) -> None:
        """Run until `close()` (or `stop()`) is called."""
        while not self._stop.is_set():
            ready = self._sel.select(self._timeout())
            ready.sort(key=lambda item: not callable(item[0].data))   # watched sockets (news) first
            for key, events in ready:
                self._dispatch(key, events)
            self._expire(time.monotonic())
            self._log_summary()

    def stop(self) -> None:
        self._stop.set()

    def watch(self, sock: socket.socket, on_readable: Callable[[], None]) -> None:
        """Call `on_readable()` from the loop whenever `sock` has something to read."""
        self._watched[sock.fileno()] = on_readable
        self._sel.register(sock, selectors.EVENT_READ, on_readable)

    def defer(self) -> Deferred:
        """From inside the handler: the reply comes later, through `complete`."""
        if self._current is None:
            raise RuntimeError("defer() is only valid inside the handler")
        return Deferred(self._current)

    def complete(self, deferred: Deferred, reply: Reply) -> None:
        """Answer a deferred request (ignored if its client is gone meanwhile)."""
        conn = deferred.conn
        if conn.state == WAITING and id(conn) in self._conns:
            self._respond(conn, reply)

    def close(self) -> None:
        """Stop serving, close every connection, remove the socket file if this server bound it."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        for conn in list(self._conns.values()):
            self._drop(conn)
        self._sel.close()
        self._listener.close()
        if self.path is not None:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()

    # ---- the loop's steps ---------------------------------------------------------------------
    def _timeout(self) -> float:
        if not self._conns:
            return IDLE_WAKE_S
        soonest = min(conn.deadline for conn in self._conns.values())
        return min(IDLE_WAKE_S, max(0.0, soonest - time.monotonic()))

    def _dispatch(self, key: selectors.SelectorKey, events: int) -> None:
        if key.data is None:
            self._accept_batch()
        elif callable(key.data):
            key.data()
        else:
            conn: _Conn = key.data
            if events & selectors.EVENT_READ and conn.state == READING:
                self._read(conn)
            if events & selectors.EVENT_WRITE and conn.state == WRITING:
                self._write(conn)

    def _accept_batch(self) -> None:
        for _ in range(ACCEPT_BATCH):
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:          # e.g. EMFILE: the next wake-up tries again
                log.warning("control socket: accept failed: %s", exc.strerror)
                return
            self._admit(sock)

    def _admit(self, sock: socket.socket) -> None:
        """Peer uid first, before a byte is read; then make room and read what is already there."""
        sock.setblocking(False)
        try:
            _pid, uid, _gid = peer_credentials(sock)
        except OSError:
            sock.close()
            return
        if not peer_allowed(uid, self.owner_uid):
            self._refuse_uid(sock, uid)
            return
        if len(self._conns) >= self.max_connections:
            self._evict_oldest()
        conn = _Conn(sock, time.monotonic() + self.request_deadline_s)
        self._conns[id(conn)] = conn
        self._sel.register(sock, selectors.EVENT_READ, conn)
        self._read(conn)

    def _refuse_uid(self, sock: socket.socket, uid: int) -> None:
        self.counters["refused_uid"] += 1
        if uid not in self._refused_uids and len(self._refused_uids) < 100:
            self._refused_uids.add(uid)
            log.warning("control socket: refused uid %d (owner is uid %d)", uid, self.owner_uid)
        with contextlib.suppress(OSError):
            sock.send(encode_reply(refusal_for(uid, self.owner_uid)))   # one try: it fits or is lost
        sock.close()

    def _evict_oldest(self) -> None:
        """Close the oldest connection that is not waiting on the main process."""
        for conn in self._conns.values():
            if conn.state != WAITING:
                self.counters["evicted"] += 1
                self._drop(conn)
                return

    def _read(self, conn: _Conn) -> None:
        try:
            chunk = conn.sock.recv(MAX_REQUEST + 1 - len(conn.buf))
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(conn)
            return
        conn.buf += chunk
        newline = conn.buf.find(b"\n")
        if newline >= 0:
            self._handle(conn, bytes(conn.buf[:newline]))
        elif len(conn.buf) > MAX_REQUEST:
            self.counters["too_long"] += 1
            self._respond(conn, {"ok": False, "error": f"bad request: longer than {MAX_REQUEST} bytes "
                                                       "(a request is one short JSON line)"})
        elif not chunk:                     # the client closed its side: what it sent is the request
            if conn.buf:
                self._handle(conn, bytes(conn.buf))
            else:
                self._drop(conn)

    def _handle(self, conn: _Conn, line: bytes) -> None:
        request, error = parse_request(line)
        if request is None:
            self.counters["bad"] += 1
            self._respond(conn, {"ok": False, "error": error})
            return
        self._current = conn
        try:
            reply = self.handler(request)
        except Exception as exc:            # one bad request must not take the server down
            log.exception("control socket: handler failed for %r", request.get("cmd"))
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        finally:
            self._current = None
        self.counters["served"] += 1
        if isinstance(reply, Deferred):
            conn.state = WAITING            # nothing more is read from it (unregistered until the reply)
            conn.deadline = time.monotonic() + FORWARD_DEADLINE_S
            self._sel.unregister(conn.sock)
        else:
            self._respond(conn, reply)

    def _respond(self, conn: _Conn, reply: Reply) -> None:
        waiting = conn.state == WAITING
        conn.out = memoryview(reply if isinstance(reply, bytes) else encode_reply(reply))
        conn.state = WRITING
        conn.deadline = time.monotonic() + REPLY_DEADLINE_S
        if waiting:
            self._sel.register(conn.sock, selectors.EVENT_WRITE, conn)
        else:
            self._sel.modify(conn.sock, selectors.EVENT_WRITE, conn)
        self._write(conn)

    def _write(self, conn: _Conn) -> None:
        try:
            sent = conn.sock.send(conn.out)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(conn)
            return
        conn.out = conn.out[sent:]
        if not conn.out:
            self._drop(conn)

    def _expire(self, now: float) -> None:
        for conn in [c for c in self._conns.values() if c.deadline <= now]:
            self.counters["timed_out"] += 1
            if conn.state == READING:
                self._respond(conn, {"ok": False, "error": f"bad request: no whole request within "
                                                           f"{self.request_deadline_s:g} s"})
                if conn.state == WRITING:    # it did not take the reply at once: give up on it
                    self._drop(conn)
            elif conn.state == WAITING:
                self._respond(conn, {"ok": False, "error": f"the controller did not answer within "
                                                           f"{FORWARD_DEADLINE_S:g} s"})
            else:
                self._drop(conn)

    def _drop(self, conn: _Conn) -> None:
        self._conns.pop(id(conn), None)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(conn.sock)
        conn.sock.close()
        conn.state = "closed"

    def _log_summary(self) -> None:
        """Hostile or broken clients are summed up every LOG_EVERY_S, never logged one by one."""
        now = time.monotonic()
        if now < self._next_log:
            return
        self._next_log = now + LOG_EVERY_S
        new = {k: v - self._logged[k] for k, v in self.counters.items() if k != "served" and v != self._logged[k]}
        self._logged = dict(self.counters)
        if new:
            log.warning("control socket, last %g s: %s", LOG_EVERY_S,
                        ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in new.items()))

