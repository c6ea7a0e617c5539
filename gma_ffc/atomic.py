"""Write files so that a crash or an error never leaves a half-written output behind."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterable, Iterator


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Yield a temporary file beside `path`; rename it onto `path` only if the block succeeds."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        # mkstemp makes the file 0600; give it the mode an ordinary open() would (0666 & ~umask).
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    """The process umask, read without changing it (setting it is racy in threaded processes)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def refuse_overwrite(output: str | os.PathLike, inputs: "Iterable[str | os.PathLike]", what: str = "output") -> None:
    """InputError if writing `output` would replace one of `inputs`: the same path, or the same
    file under another name (a symlink, a hard link, a bind mount: compared by device and inode).
    A command that fills a folder asks once for each file it writes there (`diagnose --out`)."""
    from .errors import InputError

    out = Path(output)
    try:
        out_stat = out.stat()
    except OSError:
        out_stat = None
    out_real = os.path.realpath(out)
    for src in inputs:
        p = Path(src)
        same = os.path.realpath(p) == out_real
        if not same and out_stat is not None:
            with contextlib.suppress(OSError):
                st = p.stat()
                same = (st.st_dev, st.st_ino) == (out_stat.st_dev, out_stat.st_ino)
        if same:
            raise InputError(f"{what} {out} is the input {p}: refusing to overwrite it; choose another output name")
