"""The local control socket's protocol and client: newline-delimited JSON over a Unix stream
socket, owner only, one request per connection.

Three layers keep other users out: the 0700 runtime directory, the 0600 socket file, and the
peer's uid read with SO_PEERCRED on every connection before anything it sent is read (so a
socket file with loosened permissions, or one passed to another process, still refuses
strangers). The server is `control_server`, run in its own process by `control_plane`.

Request:  {"cmd": "status"} | {"cmd": "stop", "reason": "..."} | {"cmd": "reload"} | {"cmd": "ping"}
Response: {"ok": true, ...} or {"ok": false, "error": "one sentence"}
"""

from __future__ import annotations

import contextlib
import json
import os
import pwd
import socket
import stat
import struct
from pathlib import Path
from typing import Any

from ..errors import ConfigError, FaultError, NoAnswerError, NotRunningError
from .paths import RuntimePaths

MAX_REQUEST = 4096            # the longest request: {"cmd": "stop", "reason": <a sentence>} is ~100 bytes
MAX_REPLY = 16 << 20          # a client's bound on a reply (a status is a few kB)
MAX_SOCKET_PATH = 107         # sun_path is 108 bytes with the terminating NUL
_UCRED = struct.Struct("3i")  # struct ucred {pid_t pid; uid_t uid; gid_t gid;}


def check_socket_path(path: Path) -> None:
    """Unix socket paths are short; say so plainly instead of failing deep in bind/connect."""
    length = len(os.fsencode(str(path)))
    if length > MAX_SOCKET_PATH:
        raise ConfigError(f"socket path {path} is {length} bytes, over the {MAX_SOCKET_PATH}-byte "
                          "limit of Unix sockets; choose a shorter --runtime-dir")


def bind_listener(path: Path) -> socket.socket:
    """A listening socket at `path`, bound with a 0177 umask so it is never, even briefly,
    reachable by others; a stale socket file there is replaced (the caller made sure nobody
    answers on it)."""
    check_socket_path(path)
    with contextlib.suppress(FileNotFoundError):
        if stat.S_ISSOCK(path.lstat().st_mode):
            path.unlink()
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
    sock.listen(socket.SOMAXCONN)
    return sock


def peer_credentials(conn: socket.socket) -> tuple[int, int, int]:
    """(pid, uid, gid) of the process at the other end of a connected Unix socket."""
    raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size)
    pid, uid, gid = _UCRED.unpack(raw)
    return pid, uid, gid


def peer_allowed(peer_uid: int, owner_uid: int) -> bool:
    """Only the uid that runs the controller may talk to it (root included: it is no exception)."""
    return peer_uid == owner_uid


def refusal_for(uid: int, owner_uid: int) -> dict[str, Any]:
    """The one-line answer to a peer that is not the owner."""
    return {"ok": False, "denied": True,
            "error": f"permission denied: uid {uid} is not the controller's owner (uid {owner_uid}); "
                     f"run as that user, e.g. 'sudo -u {user_name(owner_uid)} gma-ffc ...'"}


def user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"#{uid}"


def parse_request(line: bytes) -> tuple[dict[str, Any] | None, str]:
    """(request, "") for a well-formed request line, else (None, the one-sentence refusal)."""
    if not line.strip():
        return None, "bad request: empty message"
    try:
        request = json.loads(line)
    except ValueError as exc:          # malformed JSON, cut-off JSON, bytes that are not UTF-8
        return None, f"bad request: not JSON ({str(exc)[:120]})"
    if not isinstance(request, dict) or not isinstance(request.get("cmd"), str):
        return None, 'bad request: expected {"cmd": ...}'
    return request, ""


def encode_reply(message: dict[str, Any]) -> bytes:
    return json.dumps(message, default=jsonable).encode() + b"\n"


def jsonable(value: Any) -> Any:
    """numpy scalars/arrays and paths in status dicts become plain JSON."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    return str(value)


def _receive_reply(conn: socket.socket) -> Any:
    buf = bytearray()
    while b"\n" not in buf:
        chunk = conn.recv(65536)
        if not chunk:
            break
        buf += chunk
        if len(buf) > MAX_REPLY:
            raise ValueError("reply too long")
    line = bytes(buf).split(b"\n", 1)[0]
    if not line:
        raise ValueError("empty reply")
    return json.loads(line)


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
            reply = _receive_reply(sock)
        except socket.timeout:
            raise NoAnswerError(f"the controller did not answer within {timeout_s:g} s "
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
    return who_answers(path, timeout_s)[0]


def who_answers(path: Path, timeout_s: float = 1.0) -> tuple[bool, int | None]:
    """(whether a controller answers a ping on `path`, its pid as its answer gives it). The pid
    comes from the socket's process, which knows it from the start: a controller still building
    its model has written no pid file yet (a second `start` then named it "pid ?")."""
    try:
        reply = request(path, {"cmd": "ping"}, timeout_s)
    except FaultError:
        return False, None
    pid = reply.get("pid")   # even a refusal means a live controller is there: never take its socket
    return True, pid if isinstance(pid, int) and not isinstance(pid, bool) and pid > 0 else None


def refuse_if_running(runtime: RuntimePaths, pid_file_pid: int | None = None) -> None:
    """FaultError naming the controller that answers in `runtime`, or saying one is starting there
    when its pid cannot be told (its answer lacks it and it wrote no pid file yet)."""
    answering, pid = who_answers(runtime.socket)
    if not answering:
        return
    pid = pid or pid_file_pid
    folder = runtime.directory
    if pid is not None:
        raise FaultError(f"a controller is already running (pid {pid}, socket {runtime.socket}); stop it first "
                         f"with 'gma-ffc stop --runtime-dir {folder}'")
    raise FaultError(f"another controller is starting in {folder} (its socket {runtime.socket} answers, its pid "
                     f"is not known yet); wait until 'gma-ffc status --runtime-dir {folder}' shows it, then stop it "
                     f"with 'gma-ffc stop --runtime-dir {folder}', or give this one another --runtime-dir")
