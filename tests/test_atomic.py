"""Outputs appear whole or not at all, with the permissions an ordinary write would give."""

from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

import pytest

from gma_ffc.atomic import atomic_write


def test_file_gets_umask_permissions_not_mkstemps_0600(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        with atomic_write(tmp_path / "a.txt") as fh:
            fh.write("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644


def test_a_failure_inside_leaves_neither_output_nor_temporary(tmp_path: Path) -> None:
    target = tmp_path / "b.txt"
    with pytest.raises(RuntimeError):
        with atomic_write(target) as fh:
            fh.write("half")
            raise RuntimeError("boom")
    assert not target.exists() and list(tmp_path.iterdir()) == []


def test_an_existing_file_survives_a_failed_rewrite(tmp_path: Path) -> None:
    target = tmp_path / "c.txt"
    target.write_text("old")
    with pytest.raises(ValueError):
        with atomic_write(target) as fh:
            fh.write("new")
            raise ValueError
    assert target.read_text() == "old"


def _special_nodes(tmp_path: Path) -> dict[str, Path]:
    """One of each kind of path an output must not replace (a device only as root: mknod needs it)."""
    import socket

    nodes = {"a FIFO (named pipe)": tmp_path / "fifo", "a folder": tmp_path / "dir", "a socket": tmp_path / "sock"}
    os.mkfifo(nodes["a FIFO (named pipe)"])
    nodes["a folder"].mkdir()
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(nodes["a socket"]))
    sock.close()
    if os.geteuid() == 0:
        nodes["a character device"] = tmp_path / "fakenull"
        os.mknod(nodes["a character device"], stat.S_IFCHR | 0o644, os.makedev(1, 3))
    return nodes


def test_a_device_fifo_socket_or_folder_is_refused_not_replaced(tmp_path: Path) -> None:
    """The temp-then-rename replaced /dev/null (as root) or a FIFO with a regular file, exit 0."""
    from gma_ffc.errors import InputError

    for words, node in _special_nodes(tmp_path).items():
        kind = stat.S_IFMT(node.lstat().st_mode)
        with pytest.raises(InputError, match=re.escape(f"is {words}, not a regular file")):
            with atomic_write(node) as fh:
                fh.write("x")
        assert stat.S_IFMT(node.lstat().st_mode) == kind
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_symlink_is_written_through_to_its_file_and_stays_a_link(tmp_path: Path) -> None:
    (tmp_path / "target.csv").write_text("old")
    (tmp_path / "link.csv").symlink_to("target.csv")
    (tmp_path / "dangling.csv").symlink_to("new.csv")
    for link in ("link.csv", "dangling.csv"):
        with atomic_write(tmp_path / link) as fh:
            fh.write("new")
        assert (tmp_path / link).is_symlink() and (tmp_path / link).read_text() == "new"
    assert (tmp_path / "target.csv").read_text() == "new" and (tmp_path / "new.csv").read_text() == "new"


def test_a_link_to_a_fifo_is_refused_naming_both(tmp_path: Path) -> None:
    from gma_ffc.errors import InputError

    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "out.csv").symlink_to("fifo")
    with pytest.raises(InputError, match=r"fifo \(through the link .*out.csv\) is a FIFO"):
        with atomic_write(tmp_path / "out.csv") as fh:
            fh.write("x")
    assert stat.S_ISFIFO((tmp_path / "fifo").lstat().st_mode)


def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_names_the_output_not_an_empty_name_and_keeps_the_old_file(tmp_path: Path, monkeypatch) -> None:
    """A failed write said 'error: : No space left on device' (a write() carries no file name)."""
    from gma_ffc.errors import InputError

    target = tmp_path / "out.csv"
    target.write_text("old")
    monkeypatch.setattr(os, "fsync", _no_space)
    with pytest.raises(InputError, match=re.escape(f"{target}: cannot write it: No space left on device")) as info:
        with atomic_write(target) as fh:
            fh.write("new")
    assert "free some space" in str(info.value) and ".tmp" not in str(info.value)
    assert target.read_text() == "old" and not list(tmp_path.glob(".*.tmp"))


def test_a_set_of_files_is_replaced_all_or_none(tmp_path: Path, monkeypatch) -> None:
    """diagnose wrote its files one by one: a full disk on the second left a mix of two runs."""
    from gma_ffc import atomic
    from gma_ffc.errors import InputError

    for name in ("a.yaml", "b.html", "c.json"):
        (tmp_path / name).write_text("old")
    real = atomic._write_temporary

    def fail_on_b(target: Path, data: bytes) -> Path:
        if target.name == "b.html":
            _no_space()
        return real(target, data)

    monkeypatch.setattr(atomic, "_write_temporary", fail_on_b)
    with pytest.raises(InputError, match=re.escape(f"{tmp_path / 'b.html'}: cannot write it: No space left")):
        atomic.atomic_write_all(tmp_path, {"a.yaml": b"new", "b.html": b"new", "c.json": b"new"})
    assert [p.read_text() for p in sorted(tmp_path.iterdir())] == ["old"] * 3   # and no temporaries
    monkeypatch.setattr(atomic, "_write_temporary", real)
    atomic.atomic_write_all(tmp_path, {"a.yaml": b"new", "b.html": b"new", "c.json": b"new"})
    assert [p.read_text() for p in sorted(tmp_path.iterdir())] == ["new"] * 3


def test_check_writable_finds_a_read_only_folder_and_a_file_in_the_way(tmp_path: Path, monkeypatch) -> None:
    from gma_ffc.atomic import check_folder_writable
    from gma_ffc.errors import InputError

    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="--out x: .*file is a file, not a folder"):
        check_folder_writable(tmp_path / "file" / "sub", "--out x")
    check_folder_writable(tmp_path / "new" / "deeper", "--out y")           # made later, where it can be
    assert not (tmp_path / "new").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if flags & os.O_CREAT:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    with pytest.raises(InputError, match=f"--out z: cannot write in {re.escape(str(tmp_path))}: Read-only file "
                                         "system; that file system is read-only: write it elsewhere"):
        check_folder_writable(tmp_path / "diag", "--out z")
