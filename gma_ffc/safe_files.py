"""How the controller service opens the files it writes: never through a symbolic link, never over
a file that is not its own, never outside the directories it was given.

A service runs for days, often as root or a shared account, on a PC other people use; a path in
its config may point into a directory someone else can write. So every file it writes (the
telemetry recording and its lock, the learned correction, the final stats snapshot, the pid file
and the log) is opened here, and each refusal is one `OutputRefused` line naming the path (exit 2):

- the directories: a file must land, with every link resolved, inside one of `roots` (the config's
  `output_dirs`, or the folder the path names when there are none). Below a root, each directory
  is opened with O_NOFOLLOW relative to the one above it, so a link swapped in after the check
  is refused, not followed;
- the file itself is opened with O_NOFOLLOW (a link there is refused wherever it points) and
  checked through its descriptor: a regular file, ours, one link only;
- an existing file is kept unless its first bytes show it is one of ours of the same kind: a
  telemetry file of this rig (the same config), a learned correction, a stats snapshot, a pid file.
  Telemetry is truncated only after that check, on the same descriptor.

Files are replaced atomically (`atomic.atomic_write_at`) except the telemetry and the log, which
grow in place.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Callable, Iterator, Sequence

import yaml

from .atomic import atomic_write_at, nearest_existing
from .errors import InputError

HEAD_BYTES = 8192          # an existing file's first bytes: enough for a recording's metadata lines


class OutputRefused(InputError):
    """A file the service would write is not safe to write; the message names the path."""


@dataclass(frozen=True)
class Kind:
    """What a file is, how to recognise an existing one as ours, and the setting that names it."""

    what: str
    setting: str
    ours: Callable[[bytes], bool]
    in_place: bool = False      # grows in place (telemetry, its lock, the log); else replaced by a rename


def _digits_or_empty(head: bytes) -> bool:
    return head.strip().isdigit() or not head.strip()


def _recording_metadata(head: bytes) -> dict:
    """The `# key: value` lines at the top of a recording (docs/recordings.md)."""
    meta: dict = {}
    for line in head.decode("utf-8", "replace").splitlines():
        if not line.startswith("#"):
            break
        with contextlib.suppress(yaml.YAMLError):
            parsed = yaml.safe_load(line.lstrip("#").strip())
            if isinstance(parsed, dict):
                meta.update(parsed)
    return meta


def telemetry_kind(config_source: str) -> Kind:
    """A telemetry recording written by the controller running the config at `config_source`: the
    same file however it was named (the demo's relative path, `gma-ffc run`'s absolute one; a file
    that recorded a relative path is resolved against the current folder, as it was written)."""
    def ours(head: bytes) -> bool:
        meta = _recording_metadata(head)
        return (meta.get("source") == "gma-ffc controller" and meta.get("config") is not None
                and os.path.realpath(str(meta["config"])) == os.path.realpath(str(config_source)))

    return Kind(f"telemetry file of this rig (config {config_source})", "telemetry.path", ours, in_place=True)


TELEMETRY_LOCK = Kind("telemetry lock file", "telemetry.path", _digits_or_empty, in_place=True)
LEARNED = Kind("learned-correction file", "learning.file",
               lambda head: b"gma-ffc-learned-correction" in head or head.startswith(b"# gma-ffc learned"))
STATS = Kind("stats snapshot", "--stats-json", lambda head: head.lstrip().startswith(b"{") and b'"status"' in head[:200])
PID = Kind("pid file", "--runtime-dir", _digits_or_empty)
LOG = Kind("log file", "--runtime-dir", lambda head: True, in_place=True)       # appended to, never cut


def area_of(path: str | os.PathLike, roots: Sequence[str | os.PathLike]) -> tuple[Path, Path]:
    """(root, the path's directory relative to it, links resolved); OutputRefused when it is in
    none of `roots`. No roots: the directory the path names is its own root."""
    target = Path(os.path.abspath(path))
    parent = Path(os.path.realpath(target.parent))
    for root in (roots or [target.parent]):
        real_root = Path(os.path.realpath(root))
        if parent == real_root or real_root in parent.parents:
            return real_root, parent.relative_to(real_root)
    names = ", ".join(str(r) for r in roots)
    raise OutputRefused(f"{target} is outside the directories the config names for output ({names}); "
                        "put it in one of them, or add its folder to the config's output_dirs")


def _open_directory(path: Path, roots: Sequence[str | os.PathLike], kind: Kind) -> int:
    """The file's directory, opened from its root down without following a link (made if missing)."""
    root, below = area_of(path, roots)
    root.mkdir(parents=True, exist_ok=True)
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        for part in below.parts:
            with contextlib.suppress(FileExistsError):
                os.mkdir(part, 0o777, dir_fd=fd)
            try:
                child = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=fd)
            except OSError as exc:
                raise OutputRefused(f"{path}: its folder {part!r} under {root} became a link or is not a "
                                    f"folder ({exc.strerror}); refusing to write through it") from None
            os.close(fd)
            fd = child
    except BaseException:
        os.close(fd)
        raise
    return fd


def _refuse_unless_ours(fd: int, path: Path, kind: Kind) -> None:
    """Checks on an open descriptor (so nothing can be swapped in between check and write)."""
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        raise OutputRefused(f"{path} is not a regular file (a folder, device or pipe); choose another {kind.setting}")
    if info.st_uid != os.geteuid():
        raise OutputRefused(f"{path} belongs to uid {info.st_uid}, not to this service (uid {os.geteuid()}); "
                            f"move it away or choose another {kind.setting}")
    if info.st_nlink > 1:
        raise OutputRefused(f"{path} has {info.st_nlink} hard links (another name shares its content); "
                            f"remove the other links or choose another {kind.setting}")
    if info.st_size and not kind.ours(os.pread(fd, HEAD_BYTES, 0)):
        raise OutputRefused(f"{path} exists and is not a {kind.what}; refusing to overwrite it: "
                            f"move it away or choose another {kind.setting}")


def _open_no_follow(dir_fd: int, name: str, path: Path, kind: Kind, flags: int, mode: int = 0o666) -> int:
    try:
        return os.open(name, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, mode, dir_fd=dir_fd)
    except OSError as exc:
        if exc.errno == errno.ELOOP:                      # O_NOFOLLOW met a link
            raise OutputRefused(f"{path} is a symbolic link: refusing to write through it; remove the "
                                f"link or choose another {kind.setting}") from None
        raise OutputRefused(f"{path}: cannot open it for writing ({exc.strerror}); choose another "
                            f"{kind.setting}") from None


def open_for_writing(path: str | os.PathLike, roots: Sequence[str | os.PathLike], kind: Kind, *,
                     append: bool = False, mode: int = 0o666) -> int:
    """A raw descriptor for writing `path` from its start (an existing file of ours is truncated
    after the checks) or, with `append`, at its end; a new file gets `mode` less the umask. The
    caller closes it."""
    target = Path(os.path.abspath(path))
    dir_fd = _open_directory(target, roots, kind)
    try:
        fd = _open_no_follow(dir_fd, target.name, target, kind,
                             os.O_RDWR | os.O_CREAT | (os.O_APPEND if append else 0), mode)
    finally:
        os.close(dir_fd)
    try:
        _refuse_unless_ours(fd, target, kind)
        if not append:
            os.ftruncate(fd, 0)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    except BaseException:
        os.close(fd)
        raise
    return fd


def keep_previous(path: str | os.PathLike, roots: Sequence[str | os.PathLike], kind: Kind, keep: int) -> str | None:
    """Before a run writes `path` afresh: its earlier content, if any, is moved aside as NAME.1.EXT
    (an older NAME.1 to NAME.2, ..., up to NAME.`keep`; the oldest beyond goes), so a restart never
    cuts the run before it. Each name moved or removed must be a file of `kind` (the same checks as
    a write: no link, this user's, one link, its content ours), and moves are renames in one
    folder, opened without following a link. The name the previous content now has, or None
    (nothing to keep, or `keep` is 0)."""
    target = Path(os.path.abspath(path))
    if keep <= 0:
        return None
    dir_fd = _open_directory(target, roots, kind)
    try:
        if not _nonempty_ours(dir_fd, target.name, target, kind):
            return None
        names = [target.name] + [f"{target.stem}.{k}{target.suffix}" for k in range(1, keep + 1)]
        if _exists_at(dir_fd, names[-1]):
            _nonempty_ours(dir_fd, names[-1], target.with_name(names[-1]), kind)     # refuses what is not ours
            os.unlink(names[-1], dir_fd=dir_fd)
        for older, newer in zip(reversed(names[1:]), reversed(names[:-1])):
            if _exists_at(dir_fd, newer):
                _nonempty_ours(dir_fd, newer, target.with_name(newer), kind)
                os.rename(newer, older, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
        return str(target.with_name(names[1]))
    finally:
        os.close(dir_fd)


def _nonempty_ours(dir_fd: int, name: str, path: Path, kind: Kind) -> bool:
    """Whether `name` in the folder holds something (False: missing or empty); OutputRefused when it
    is not a file of `kind` to move or remove."""
    if not _exists_at(dir_fd, name):
        return False
    fd = _open_no_follow(dir_fd, name, path, kind, os.O_RDONLY)
    try:
        _refuse_unless_ours(fd, path, kind)
        return os.fstat(fd).st_size > 0
    finally:
        os.close(fd)


def _exists_at(dir_fd: int, name: str) -> bool:
    try:
        os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except FileNotFoundError:
        return False
    return True


def check_writable(path: str | os.PathLike, roots: Sequence[str | os.PathLike], kind: Kind) -> None:
    """Everything `open_for_writing` and `replace` check, changing nothing (a service checks its
    outputs before it starts, so a refusal is one line and exit 2, not a fault at the first tick)."""
    target = Path(os.path.abspath(path))
    root, below = area_of(target, roots)
    folder = root.joinpath(below)
    if not os.path.lexists(target) or not kind.in_place:       # a new file, or a rename over it
        _refuse_unwritable_folder(target, folder, kind)
    if not os.path.lexists(target):
        return
    if not os.path.isdir(folder):
        raise OutputRefused(f"{target}: its folder {folder} is not a folder; choose another {kind.setting}")
    dir_fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fd = _open_no_follow(dir_fd, target.name, target, kind, os.O_RDONLY)
    finally:
        os.close(dir_fd)
    try:
        _refuse_unless_ours(fd, target, kind)
    finally:
        os.close(fd)
    if kind.in_place and not _may_write(target):
        raise OutputRefused(f"{target}: {_why_not_writable(target)}; choose another {kind.setting}")


def _may_write(path: Path, mode: int = os.W_OK) -> bool:
    return os.access(path, mode, effective_ids=os.access in os.supports_effective_ids)


def _why_not_writable(path: Path) -> str:
    with contextlib.suppress(OSError):
        if os.statvfs(path).f_flag & os.ST_RDONLY:
            return "it is on a read-only file system"
    return "this user may not write it"


def _refuse_unwritable_folder(target: Path, folder: Path, kind: Kind) -> None:
    """The folder a new file (or a rename) lands in must take it: its nearest existing ancestor,
    where the missing folders would be made. Otherwise the write fails after the run, naming a
    temporary file."""
    existing = nearest_existing(folder)
    if not os.path.isdir(existing):
        raise OutputRefused(f"{target}: {existing} is not a folder; choose another {kind.setting}")
    if not _may_write(existing, os.W_OK | os.X_OK):
        raise OutputRefused(f"{target}: cannot create it in {existing}: {_why_not_writable(existing)}; "
                            f"choose another {kind.setting}")


@contextlib.contextmanager
def replace(path: str | os.PathLike, roots: Sequence[str | os.PathLike], kind: Kind,
            mode: str = "w", **kwargs) -> Iterator[IO]:
    """Write `path` atomically (whole or not at all) after the same checks; the rename replaces a
    link swapped in meanwhile instead of writing through it."""
    target = Path(os.path.abspath(path))
    dir_fd = _open_directory(target, roots, kind)
    try:
        if _exists_at(dir_fd, target.name):
            fd = _open_no_follow(dir_fd, target.name, target, kind, os.O_RDONLY)
            try:
                _refuse_unless_ours(fd, target, kind)
            finally:
                os.close(fd)
        with atomic_write_at(dir_fd, target.name, mode, **kwargs) as handle:
            yield handle
    finally:
        os.close(dir_fd)
