"""The local control socket: newline-delimited JSON over a Unix stream socket, owner only.

Three layers keep other users out: the 0700 runtime directory, the 0600 socket file, and the
peer's uid read with SO_PEERCRED on every connection (so a socket file with loosened
permissions, or one passed to another process, still refuses strangers).

Request:  {"cmd": "status"} | {"cmd": "stop", "reason": "..."} | {"cmd": "reload"} | {"cmd": "ping"}
Response: {"ok": true, ...} or {"ok": false, "error": "one sentence"}
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import pwd
import socket
import stat
import struct
import threading
from pathlib import Path
from typing import Any, Callable

from ..errors import ConfigError, FaultError, NotRunningError

log = logging.getLogger(__name__)

MAX_MESSAGE = 1 << 20
_UCRED = struct.Struct("3i")  # struct ucred {pid_t pid; uid_t uid; gid_t gid;}

Handler = Callable[[dict[str, Any]], dict[str, Any]]


MAX_SOCKET_PATH = 107   # sun_path is 108 bytes with the terminating NUL


def check_socket_path(path: Path) -> None:
    """Unix socket paths are short; say so plainly instead of failing deep in bind/connect."""
    length = len(os.fsencode(str(path)))
    if length > MAX_SOCKET_PATH:
        raise ConfigError(f"socket path {path} is {length} bytes, over the {MAX_SOCKET_PATH}-byte "
                          "limit of Unix sockets; choose a shorter --runtime-dir")


def peer_credentials(conn: socket.socket) -> tuple[int, int, int]:
    """(pid, uid, gid) of the process at the other end of a connected Unix socket."""
    raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
    pid, uid, gid = _UCRED.unpack(raw)
    return pid, uid, gid


def peer_allowed(peer_uid: int, owner_uid: int) -> bool:
    """Only the uid that runs the controller may talk to it (root included: it is no exception)."""
    return peer_uid == owner_uid


class ControlServer:
    """Serves requests on `path` in a background thread until `close()`."""

    def __init__(self, path: Path, handler: Handler, owner_uid: int | None = None) -> None:
        self.path = Path(path)
        self.handler = handler
        self.owner_uid = os.geteuid() if owner_uid is None else owner_uid
        self._stop = threading.Event()
        self._sock = self._bind(self.path)
        self._thread = threading.Thread(target=self._serve, name="gma-ffc-control", daemon=True)

    @staticmethod
    def _bind(path: Path) -> socket.socket:
        """Bind with a 0177 umask so the socket is never, even briefly, reachable by others."""
        check_socket_path(path)
        with contextlib.suppress(FileNotFoundError):
            if stat.S_ISSOCK(path.lstat().st_mode):
                path.unlink()  # stale: the caller has made sure nobody answers on it
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        old = os.umask(0o177)
        try:
            sock.bind(str(path))
        except OSError as exc:
            sock.close()
            raise FaultError(f"cannot create control socket {path}: {exc.strerror}") from None
        finally:
            os.umask(old)
        os.chmod(path, 0o600)
        sock.listen(8)
        sock.settimeout(0.2)
        return sock

    def start(self) -> "ControlServer":
        self._thread.start()
        return self

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except (socket.timeout, BlockingIOError):
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            with conn:
                try:
                    self._handle(conn)
                except Exception:  # one bad client must not take the service down
                    log.exception("control socket: request failed")

    def _handle(self, conn: socket.socket) -> None:
        conn.settimeout(2.0)
        _pid, uid, _gid = peer_credentials(conn)
        if not peer_allowed(uid, self.owner_uid):
            log.warning("control socket: refused uid %d (owner is uid %d)", uid, self.owner_uid)
            owner = _user_name(self.owner_uid)
            _send(conn, {"ok": False, "denied": True,
                         "error": f"permission denied: uid {uid} is not the controller's owner "
                                  f"(uid {self.owner_uid}); run as that user, e.g. "
                                  f"'sudo -u {owner} gma-ffc ...'"})
            return
        try:
            request = _receive(conn)
        except (ValueError, socket.timeout) as exc:
            _send(conn, {"ok": False, "error": f"bad request: {exc}"})
            return
        if not isinstance(request, dict) or not isinstance(request.get("cmd"), str):
            _send(conn, {"ok": False, "error": "bad request: expected {\"cmd\": ...}"})
            return
        try:
            reply = self.handler(request)
        except Exception as exc:
            log.exception("control socket: handler failed for %r", request.get("cmd"))
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        _send(conn, reply)

    def close(self) -> None:
        """Stop serving and remove the socket file (only if it is still ours)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def _user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"#{uid}"


def _send(conn: socket.socket, message: dict[str, Any]) -> None:
    with contextlib.suppress(OSError):
        conn.sendall(json.dumps(message, default=_jsonable).encode() + b"\n")


def _receive(conn: socket.socket) -> Any:
    buf = bytearray()
    while b"\n" not in buf:
        chunk = conn.recv(65536)
        if not chunk:
            break
        buf += chunk
        if len(buf) > MAX_MESSAGE:
            raise ValueError("message too long")
    line = bytes(buf).split(b"\n", 1)[0]
    if not line:
        raise ValueError("empty message")
    return json.loads(line)


def _jsonable(value: Any) -> Any:
    """numpy scalars/arrays and paths in status dicts become plain JSON."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    return str(value)


def request(path: Path, message: dict[str, Any], timeout_s: float = 5.0) -> dict[str, Any]:
    """Send one request to the controller at `path` and return its reply.

    Raises FaultError with one sentence when nobody answers there.
    """
    path = Path(path)
    check_socket_path(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    sock.settimeout(timeout_s)
    try:
        try:
            sock.connect(str(path))
        except (FileNotFoundError, ConnectionRefusedError):
            raise NotRunningError(f"no controller running (socket {path})") from None
        except PermissionError:
            raise FaultError(f"permission denied on socket {path}: it belongs to another user "
                             "(run as that user, or pass --runtime-dir)") from None
        except OSError as exc:
            raise FaultError(f"cannot connect to socket {path}: {exc.strerror}") from None
        try:
            try:
                sock.sendall(json.dumps(message).encode() + b"\n")
            except (BrokenPipeError, ConnectionResetError):
                pass  # a refusing server may close first; its reason is still waiting to be read
            reply = _receive(sock)
        except socket.timeout:
            raise FaultError(f"the controller did not answer within {timeout_s:g} s "
                             f"(socket {path})") from None
        except (OSError, ValueError) as exc:
            raise FaultError(f"bad reply from the controller on socket {path}: {exc}") from None
    finally:
        sock.close()
    if not isinstance(reply, dict):
        raise FaultError(f"bad reply from the controller on socket {path}")
    return reply


def ask(path: Path, message: dict[str, Any], timeout_s: float = 5.0) -> dict[str, Any]:
    """`request`, but a refusal (not the owner, unknown command, ...) is a FaultError too."""
    reply = request(path, message, timeout_s)
    if not reply.get("ok"):
        raise FaultError(str(reply.get("error") or f"the controller refused {message.get('cmd')!r}"))
    return reply


def is_answering(path: Path, timeout_s: float = 1.0) -> bool:
    """True if a controller answers a ping on `path` (used to tell live sockets from stale ones)."""
    try:
        request(path, {"cmd": "ping"}, timeout_s)
    except FaultError:
        return False
    return True   # even a refusal means a live controller is there: never take its socket
