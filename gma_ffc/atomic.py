"""Write files so that a crash or an error never leaves a half-written output behind."""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from pathlib import Path
from typing import IO, Iterable, Iterator

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


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Yield a temporary file beside `path` (beside the file a symlink there points to); rename it
    onto that file only if the block succeeds. A path that is not a regular file is refused."""
    target = output_target(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    dir_fd = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        with atomic_write_at(dir_fd, target.name, mode, **kwargs) as handle:
            yield handle
    finally:
        os.close(dir_fd)


@contextlib.contextmanager
def atomic_write_at(dir_fd: int, name: str, mode: str = "w", **kwargs) -> Iterator[IO]:
    """`atomic_write` inside an open directory: the temporary file is created there (exclusively,
    never through a link), synced, renamed onto `name`, and the directory synced, so after a
    crash at any moment `name` is either the old file or the whole new one."""
    tmp = f".{name}.{secrets.token_hex(4)}.tmp"
    # 0666: the kernel applies the umask, as for an ordinary open()
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666, dir_fd=dir_fd)
    try:
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp, dir_fd=dir_fd)
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


def refuse_overwrite(output: str | os.PathLike, inputs: "Iterable[str | os.PathLike]", what: str = "output") -> None:
    """InputError if writing `output` would replace one of `inputs`: the same path, or the same
    file under another name (a symlink, a hard link, a bind mount: compared by device and inode).
    A command that fills a folder asks once for each file it writes there (`diagnose --out`).
    An output that is not a regular file (a device, a FIFO) is refused here too, before any work."""
    output_target(output)
    out = Path(output)
    for src in inputs:
        p = Path(src)
        if same_file(out, p):
            raise InputError(f"{what} {out} is the input {p}: refusing to overwrite it; choose another output name")
