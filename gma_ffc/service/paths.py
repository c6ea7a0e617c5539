"""Where the service keeps its socket, pid file and log: one private directory per user.

The directory is 0700 and owned by us, the socket inside it 0600, so only the owner can reach
the controller (the socket additionally checks the peer's uid, see `control_socket`). The
location is, in order: --runtime-dir, $GMA_FFC_RUNTIME_DIR, $RUNTIME_DIRECTORY (set by systemd's
RuntimeDirectory=), /run/gma-ffc when it exists and is ours (the system service's, so its user
finds it without options), $XDG_RUNTIME_DIR/gma-ffc, /run/gma-ffc for root, /tmp/gma-ffc-<uid>.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError

SOCKET_NAME = "control.sock"
PID_NAME = "gma-ffc.pid"
LOG_NAME = "gma-ffc.log"
CLAIM_NAME = "claim.lock"      # held while a starting controller checks the socket and binds it
SYSTEM_RUNTIME_DIR = "/run/gma-ffc"   # RuntimeDirectory= of config/systemd/gma-ffc.service


@dataclass(frozen=True)
class RuntimePaths:
    """The service's files inside its private runtime directory."""

    directory: Path

    @property
    def socket(self) -> Path:
        return self.directory / SOCKET_NAME

    @property
    def pid_file(self) -> Path:
        return self.directory / PID_NAME

    @property
    def log_file(self) -> Path:
        return self.directory / LOG_NAME

    @property
    def claim_file(self) -> Path:
        return self.directory / CLAIM_NAME


def default_runtime_dir(environ: dict[str, str] | None = None) -> Path:
    """The runtime directory when none is given on the command line."""
    env = os.environ if environ is None else environ
    for key in ("GMA_FFC_RUNTIME_DIR", "RUNTIME_DIRECTORY"):
        if env.get(key):
            # systemd may pass several directories separated by ':'; the first is ours.
            return Path(env[key].split(":")[0])
    system = Path(SYSTEM_RUNTIME_DIR)
    try:
        if system.stat().st_uid == os.geteuid():
            return system
    except OSError:
        pass
    if env.get("XDG_RUNTIME_DIR"):
        return Path(env["XDG_RUNTIME_DIR"]) / "gma-ffc"
    uid = os.geteuid()
    return system if uid == 0 else Path(f"/tmp/gma-ffc-{uid}")


def system_service_hint(runtime: RuntimePaths) -> str:
    """'' or where the system service's controller answers, when `runtime` is not that folder and the
    folder belongs to another user: `gma-ffc status` as oneself said "no controller running" of a
    service that ran, its folder being another user's (the unit's User=)."""
    import pwd

    system = Path(SYSTEM_RUNTIME_DIR)
    try:
        owner = system.stat().st_uid
    except OSError:
        return ""
    if owner == os.geteuid() or os.path.abspath(runtime.directory) == str(system):
        return ""
    try:
        name = pwd.getpwuid(owner).pw_name
    except KeyError:
        name = str(owner)
    return (f"; the system service keeps its controller's socket in {system}, user {name}: ask as that user, "
            f"e.g. 'sudo -u {name} gma-ffc status'")


def runtime_paths(directory: str | os.PathLike | None = None) -> RuntimePaths:
    """Resolve the directory without touching the file system (clients only read)."""
    return RuntimePaths(Path(directory) if directory else default_runtime_dir())


def ensure_private_dir(path: Path) -> None:
    """Create `path` as 0700, or accept it if it is ours; refuse one someone else owns."""
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        info = path.lstat()
    except OSError as exc:
        raise ConfigError(f"runtime directory {path}: cannot create it ({exc.strerror}); give --runtime-dir (or "
                          "GMA_FFC_RUNTIME_DIR) a folder this user may create, e.g. "
                          f"/tmp/gma-ffc-{os.geteuid()}") from None
    if not stat.S_ISDIR(info.st_mode):
        raise ConfigError(f"runtime directory {path} is not a directory; give --runtime-dir a folder's path")
    if info.st_uid != os.geteuid():
        raise ConfigError(f"runtime directory {path} belongs to uid {info.st_uid}, not to us "
                          f"(uid {os.geteuid()}); pass --runtime-dir with a directory of your own")
    if stat.S_IMODE(info.st_mode) != 0o700:
        os.chmod(path, 0o700)


@contextlib.contextmanager
def claim_lock(runtime: RuntimePaths):
    """Held from a controller's look at the socket to its bind: two starting at once each saw
    nobody answering, and the second's bind replaced the first's socket (two loops, one
    unreachable). The second now waits here, then finds the first answering. The empty file
    stays after a stop, by design: unlinking it would let a waiter (holding the old file) and a
    newcomer (creating a new one) both hold "the" lock."""
    fd = os.open(runtime.claim_file, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)          # closing releases the flock
