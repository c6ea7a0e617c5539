"""The control socket under attack (issue 33).

Unit tests of the bounded server (each client's cost bounded in bytes, time and number, the
peer's uid checked before a byte is read) and of its process (a crash is survived, the service's
death ends it), then the whole service attacked by client processes with the loop at 1 kHz:
another uid, 10 MB requests, junk, a flood, 200 idle connections and a slow client. Its figures
are printed; scripts/bench_socket_attack.py runs it longer for the exact ones.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gma_ffc.service import control_server
from gma_ffc.service.control_plane import ControlPlane
from gma_ffc.service.control_server import ControlServer
from gma_ffc.service.control_socket import MAX_REQUEST, is_answering, request
from test_service_runner import wait_for

ROOT = Path(__file__).resolve().parents[1]


def echo_server(path: Path, calls: list, **kw) -> ControlServer:
    return ControlServer(path, lambda r: calls.append(r) or {"ok": True, "cmd": r["cmd"]}, **kw).start()


def raw(path: Path, payload: bytes, shut: bool = True, timeout: float = 3.0) -> dict:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(str(path))
        try:
            sock.sendall(payload)
            if shut:
                sock.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            pass                                 # refused before it all went in: the reply waits
        reply = b""
        while b"\n" not in reply:
            chunk = sock.recv(65536)
            if not chunk:
                break
            reply += chunk
    lines = reply.splitlines()
    assert len(lines) == 1, reply            # one line, always
    return json.loads(lines[0])


def test_an_oversize_request_is_refused_unread(tmp_path):
    """10 MB without a newline: refused after MAX_REQUEST + 1 bytes, while the client is still
    sending; the handler never sees it."""
    calls: list = []
    path = tmp_path / "s.sock"
    server = echo_server(path, calls)
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.connect(str(path))
            sock.setblocking(False)
            blob, sent = b"x" * (10 << 20), 0
            deadline = time.monotonic() + 5.0
            reply = b""
            while time.monotonic() < deadline and not reply.endswith(b"\n"):
                try:
                    sent += sock.send(blob[sent:sent + 65536]) if sent < len(blob) else 0
                except (BlockingIOError, BrokenPipeError, ConnectionResetError):
                    pass
                try:
                    reply += sock.recv(4096)
                except BlockingIOError:
                    time.sleep(0.001)
        assert sent < 2 << 20                     # the server answered long before 10 MB went in
        message = json.loads(reply)
        assert message["ok"] is False and f"longer than {MAX_REQUEST} bytes" in message["error"]
        assert server.counters["too_long"] == 1 and calls == []
    finally:
        server.close()


@pytest.mark.parametrize("payload, words", [
    (b'{"cmd": "status"', "not JSON"),                         # truncated, then the client closes
    (b'{cmd: status}\n', "not JSON"),
    (b"\xff\xfe\x00garbage\n", "not JSON"),                    # not even UTF-8
    (b'["status"]\n', 'expected {"cmd": ...}'),
    (b'{"cmd": 5}\n', 'expected {"cmd": ...}'),
    (b"\n", "empty message"),
])
def test_malformed_requests_get_one_line_refusals(tmp_path, payload, words):
    calls: list = []
    path = tmp_path / "s.sock"
    server = echo_server(path, calls)
    try:
        reply = raw(path, payload)
        assert reply["ok"] is False and reply["error"].startswith("bad request") and words in reply["error"]
        assert calls == []
        assert raw(path, b'{"cmd": "status"}\n') == {"ok": True, "cmd": "status"}   # and it serves on
    finally:
        server.close()


def test_idle_connections_never_lock_the_owner_out(tmp_path):
    """More idle connections than the cap: the oldest are closed, the owner's request is answered."""
    path = tmp_path / "s.sock"
    server = echo_server(path, [], max_connections=8)
    idle = []
    try:
        for _ in range(30):
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.connect(str(path))
            idle.append(sock)
        t0 = time.monotonic()
        assert request(path, {"cmd": "status"}, timeout_s=2.0) == {"ok": True, "cmd": "status"}
        assert time.monotonic() - t0 < 1.0
        for sock in idle[:20]:                           # the oldest were evicted: EOF
            sock.settimeout(2.0)
            assert sock.recv(100) == b""
        assert server.counters["evicted"] >= 22
    finally:
        for sock in idle:
            sock.close()
        server.close()


def test_a_slow_client_is_cut_off_at_its_deadline(tmp_path):
    path = tmp_path / "s.sock"
    server = echo_server(path, [], request_deadline_s=0.3)
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(3.0)
            sock.connect(str(path))
            t0 = time.monotonic()
            reply = b""
            for byte in b'{"cmd": "status"}\n':           # one byte every 0.1 s
                try:
                    sock.send(bytes([byte]))
                except (BrokenPipeError, ConnectionResetError):
                    break
                time.sleep(0.1)
            reply = sock.recv(4096)
        assert b"no whole request within 0.3 s" in reply
        assert time.monotonic() - t0 < 2.5 and server.counters["timed_out"] == 1
    finally:
        server.close()


def test_another_uid_is_refused_before_anything_is_read(tmp_path):
    calls: list = []
    path = tmp_path / "s.sock"
    server = echo_server(path, calls, owner_uid=os.geteuid() + 4321)
    try:
        reply = raw(path, b'{"cmd": "stop"}\n' + b" " * 100_000, shut=False)
        assert reply["ok"] is False and reply["denied"] is True and "permission denied" in reply["error"]
        assert calls == [] and server.counters["refused_uid"] == 1 and server.counters["served"] == 0
    finally:
        server.close()


def test_control_plane_serves_status_from_the_snapshot_and_forwards_commands(tmp_path):
    """The socket's process answers status itself, forwards stop/reload, and is started again if
    it dies; the service's side never reads a client's bytes."""
    handled: list = []
    path = tmp_path / "c.sock"
    plane = ControlPlane(path, lambda r: handled.append(r) or {"ok": True, "did": r["cmd"]}).start()
    try:
        assert request(path, {"cmd": "status"})["ok"] is False          # nothing published yet
        plane.publish({"state": "running", "ticks": 7})
        assert wait_for(lambda: request(path, {"cmd": "status"}).get("ok"))
        status = request(path, {"cmd": "status"})["status"]
        assert status["ticks"] == 7 and status["control_socket"]["served"] >= 1
        assert request(path, {"cmd": "reload"}) == {"ok": True, "did": "reload"}
        assert request(path, {"cmd": "frobnicate"})["error"].startswith("unknown command")
        assert [r["cmd"] for r in handled] == ["reload"]
        first = plane.child_pid
        os.kill(first, signal.SIGKILL)                                 # a crash of the socket's process
        assert wait_for(lambda: plane.child_pid != first and is_answering(path), 10.0)
        assert request(path, {"cmd": "status"})["status"]["ticks"] == 7   # the snapshot survived
    finally:
        plane.close()
    assert not path.exists()


SERVICE_DIES = r"""
import sys, time
from pathlib import Path
from gma_ffc.service.control_plane import ControlPlane
plane = ControlPlane(Path(sys.argv[1]), lambda r: {"ok": True}).start()
print(plane.child_pid, flush=True)
time.sleep(60)
"""


def test_the_socket_process_leaves_when_the_service_is_killed(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", SERVICE_DIES, str(tmp_path / "c.sock")],
                            stdout=subprocess.PIPE, text=True)
    try:
        child = int(proc.stdout.readline())
        proc.kill()                                  # kill -9: no clean-up code runs in the service
        proc.wait()
        assert wait_for(lambda: not _alive(child), 5.0)
    finally:
        if proc.poll() is None:
            proc.kill()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


# ---- the whole service under attack ----------------------------------------------------------------

# Margins a busy 2-core machine keeps: the loop's p99 jitter over all attacked segments pooled
# within 2x (+20 us) of the quiet segments interleaved with them, pooled, and the owner's slowest status in the
# attacked segments within 200 ms or 2x (+50 ms) the slowest in the quiet ones, whichever is
# larger (scripts/bench_socket_attack.py prints the 1.2x and 200 ms for a quiet machine;
# the design this replaced measured 2.7-5.6x for the flood and the 10 MB requests, and the owner's
# status failed or took 1 s behind 200 idle connections). No status may fail (5 s timeout).
JITTER_MARGIN = 2.0
JITTER_SLACK_US = 20.0
STATUS_LATENCY_S = 0.2
LATENCY_MARGIN = 2.0
LATENCY_SLACK_S = 0.05


@pytest.mark.realtime
def test_service_under_attack(capsys, monkeypatch):
    sys.path.insert(0, str(Path(__file__).parent))
    import socket_attack
    from socket_attack import ATTACKS, can_switch_uid, pooled_p99_us, run_session, table

    monkeypatch.setattr(socket_attack, "STATUS_TIMEOUT_S", 5.0)
    session = run_session(list(ATTACKS), cycles=4, segment_s=0.25)
    with capsys.disabled():
        print("\n" + table(session))
    assert session.exit_code == 0, session.log[-2000:]
    quiet = {q.name: q for q, _ in session.pairs}
    attacked = {a.name: a for _, a in session.pairs}
    pooled_quiet = pooled_p99_us(list(quiet.values()))
    pooled_attacked = pooled_p99_us(list(attacked.values()))
    assert pooled_attacked <= JITTER_MARGIN * pooled_quiet + JITTER_SLACK_US, (pooled_attacked, pooled_quiet)
    phases = [*quiet.values(), *attacked.values()]
    assert all(not p.status_failures for p in phases), [p.status_failures for p in phases]
    slowest_quiet = max(max(q.latencies_s) for q in quiet.values())
    slowest_attacked = max(max(a.latencies_s) for a in attacked.values())
    assert slowest_attacked <= max(STATUS_LATENCY_S, LATENCY_MARGIN * slowest_quiet + LATENCY_SLACK_S), \
        (slowest_attacked, slowest_quiet)
    # each attacker ran (a busy machine may let it send only a few), and each was answered as it deserved
    for kind in ("oversize", "malformed"):
        assert attacked[kind].attacker.get("refused", 0) >= 1 and "accepted" not in attacked[kind].attacker
    assert attacked["flood"].attacker.get("accepted", 0) >= 1
    idle = attacked["idle_slow"].attacker
    assert idle["idle_opened"] == 200 and idle["idle_closed_by_server"] >= 200 - control_server.MAX_CONNECTIONS
    counters = session.final_status["control_socket"]
    assert counters["too_long"] >= 1 and counters["evicted"] >= 200 - control_server.MAX_CONNECTIONS
    if can_switch_uid():
        other = attacked["other_uid"].attacker
        assert other.get("denied", 0) >= 1 and other.get("accepted", 0) == 0, other
        assert counters["refused_uid"] == other["denied"] + other.get("no_reply", 0)
