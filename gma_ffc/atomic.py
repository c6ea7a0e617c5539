"""Write files so that a crash or an error never leaves a half-written output behind."""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from pathlib import Path
from typing import IO, Iterable, Iterator, Mapping

from .errors import InputError

# What an existing output path may be besides a regular file, in words; the rename would replace it
_NOT_A_FILE = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def output_target(path: str | os.PathLike) -> Path:
    """The file an output at `path` is written to: `path` itself, or the file a symlink there points
    to (written through, as an ordinary write would; a dangling link's target is created). An
    existing path that is not a regular file is refused: the atomic rename would replace the device,
    FIFO, socket or folder with a regular file."""
    target = Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        return target
    for test, words in _NOT_A_FILE:
        if test(mode):
            via = "" if target == Path(path) else f" (through the link {path})"
            raise InputError(f"output {target}{via} is {words}, not a regular file: refusing to replace it; "
                             "give the path of a regular file")
    return target


# What to do when a write fails, by errno; anything else: write the output elsewhere
_ADVICE = {errno.ENOSPC: "free some space on that disk or write it elsewhere",
           errno.EDQUOT: "free some of your disk quota or write it elsewhere",
           errno.EROFS: "that file system is read-only: write it elsewhere",
           errno.EACCES: "no permission to write there: write it elsewhere or change the folder's permissions",
           errno.EPERM: "no permission to write there: write it elsewhere or change the folder's permissions"}


def _advice(exc: OSError) -> str:
    return _ADVICE.get(exc.errno or 0, "write it elsewhere")


def write_failed(path: str | os.PathLike, exc: OSError,
                 kept: str = "any earlier file of that name is left as it was") -> InputError:
    """The one line for an output that could not be written: the output's own name (not the hidden
    temporary's, nor the empty name a failed write() carries), the reason and what to do."""
    reason = exc.strerror or str(exc)
    return InputError(f"{path}: cannot write it: {reason} ({kept}); {_advice(exc)}")


def check_folder_writable(folder: str | os.PathLike, label: str) -> None:
    """InputError now, before any work, if nothing can be created in `folder` (or, when it does not
    exist yet, in the nearest folder above it that does, where it would be made): a read-only or
    full file system, no permission, a file where a folder should be. Probes with an empty file;
    `label` starts the message: the output as the user gave it."""
    probe_in = nearest_existing(Path(folder))
    if not probe_in.is_dir():
        raise InputError(f"{label}: {probe_in} is a file, not a folder; give a path in a folder")
    probe = probe_in / f".gma-ffc-probe.{secrets.token_hex(4)}.tmp"
    try:
        os.close(os.open(probe, _TMP_FLAGS, 0o600))
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{label}: cannot write in {probe_in}: {exc.strerror or exc}; "
                         f"{_advice(exc)}") from None


def nearest_existing(folder: Path) -> Path:
    """`folder`, or its nearest ancestor that exists (a link counts, dangling or not): where the
    missing folders would be made."""
    while not os.path.lexists(folder) and folder != folder.parent:
        folder = folder.parent
    return folder


_TMP_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Yield a temporary file beside `path` (beside the file a symlink there points to); rename it
    onto that file only if the block succeeds. A path that is not a regular file is refused; a
    write that fails (a full disk, a read-only mount) is an InputError naming `path`."""
    target = output_target(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        dir_fd = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as exc:
        raise write_failed(path, exc) from None
    try:
        with atomic_write_at(dir_fd, target.name, mode, **kwargs) as handle:
            yield handle
    except OSError as exc:
        raise write_failed(path, exc) from None
    finally:
        os.close(dir_fd)


def atomic_write_all(folder: str | os.PathLike, contents: Mapping[str, bytes]) -> None:
    """Write each of `contents` (file name -> bytes) into `folder` as a temporary file, and rename
    them onto their names only once every one is written and synced: a failure on any leaves the
    folder's earlier files as they were (one run's set, never a mix of two)."""
    targets = {name: output_target(Path(folder) / name) for name in contents}
    temps: list[Path] = []
    try:
        for name, data in contents.items():
            temps.append(_write_temporary(targets[name], data))
    except OSError as exc:
        raise write_failed(Path(folder) / name, exc, f"none of the files in {folder} was replaced") from None
    finally:
        if len(temps) < len(targets):
            for tmp in temps:
                with contextlib.suppress(OSError):
                    tmp.unlink()
    for tmp, target in zip(temps, targets.values()):
        try:
            os.replace(tmp, target)
        except OSError as exc:
            raise write_failed(target, exc, "the files before it in the list were replaced") from None
    for parent in {t.parent for t in targets.values()}:
        _fsync_dir(parent)


def _write_temporary(target: Path, data: bytes) -> Path:
    """A synced temporary beside `target` holding `data` (removed again if writing it fails)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    dir_fd = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        with _synced_temporary(dir_fd, target.name, "wb") as (handle, tmp):
            handle.write(data)
    finally:
        os.close(dir_fd)
    return target.parent / tmp


@contextlib.contextmanager
def _synced_temporary(dir_fd: int, name: str, mode: str, **kwargs) -> Iterator[tuple[IO, str]]:
    """(handle, its name): a temporary for `name` in the open directory, created exclusively (never
    through a link), flushed and synced when the block ends, and removed if the block fails."""
    tmp = f".{name}.{secrets.token_hex(4)}.tmp"
    # 0666: the kernel applies the umask, as for an ordinary open()
    fd = os.open(tmp, _TMP_FLAGS, 0o666, dir_fd=dir_fd)
    try:
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle, tmp
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        _remove(tmp, dir_fd)
        raise


def _remove(tmp: str, dir_fd: int) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp, dir_fd=dir_fd)


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write_at(dir_fd: int, name: str, mode: str = "w", **kwargs) -> Iterator[IO]:
    """`atomic_write` inside an open directory: the temporary file is created there (exclusively,
    never through a link), synced, renamed onto `name`, and the directory synced, so after a
    crash at any moment `name` is either the old file or the whole new one."""
    with _synced_temporary(dir_fd, name, mode, **kwargs) as (handle, tmp):
        yield handle
    try:
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException:
        _remove(tmp, dir_fd)
        raise
    os.fsync(dir_fd)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether `a` and `b` name one file: the same path with links resolved, or the same device and
    inode (a hard link, a bind mount). A path that does not exist yet matches by its path only."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def refuse_overwrite(output: str | os.PathLike, inputs: "Iterable[str | os.PathLike]", what: str = "output",
                     advice: str = "choose another output name") -> None:
    """InputError if writing `output` would replace one of `inputs`: the same path, or the same
    file under another name (a symlink, a hard link, a bind mount: compared by device and inode).
    A command that fills a folder asks once for each file it writes there (`diagnose --out`), and
    says what the user can change (`advice`: the folder, as the files' names are the command's).
    An output that is not a regular file (a device, a FIFO) is refused here too, before any work."""
    output_target(output)
    out = Path(output)
    for src in inputs:
        p = Path(src)
        if same_file(out, p):
            raise InputError(f"{what} {out} is the input {p}: refusing to overwrite it; {advice}")
