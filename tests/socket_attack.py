"""The control socket under attack: a real `gma-ffc run` at 1 kHz on the sim driver, attacked by
separate client processes in phases interleaved with quiet ones.

Per phase it measures the loop's period jitter (from the telemetry's tick start times, so the
observer is outside the service), the owner's `status` latency (polled every 50 ms throughout),
and what the attacker got. Used by tests/test_service_attack.py (short phases, margins a busy
machine keeps) and scripts/bench_socket_attack.py (longer phases, the exact figures).

The attacker side runs as `python -I -c SOURCE attack KIND SOCKET SECONDS` and uses the
standard library only, so it runs as another uid too (it needs no access to this checkout).
"""

from __future__ import annotations

import json
import math
import os
import random
import signal
import socket
import sys
import time

# ---- the attacker side (standard library only) --------------------------------------------------

IDLE_CONNECTIONS = 200          # the count
OVERSIZE_BYTES = 10 * 1024 * 1024
STATUS = b'{"cmd": "status"}\n'
JUNK = (b'{"cmd": "status"', b'{cmd: status}\n', b"\n", b"[1, 2, 3]\n", b'{"cmd": 5}\n',
        b'{"cmd": "status", "x": "\xff\xfe"}\n', b'"status"\n', b"{" * 3000 + b"\n",
        b'{"cmd": "st', b"\x00\x01\x02\x03\n")


_stopped = False


def _on_term(_signum, _frame) -> None:
    global _stopped
    _stopped = True


def running(rounds: int) -> bool:
    """True until the harness sends SIGTERM (it pauses the attack with SIGSTOP in between); the
    first round always runs, so a starved attacker still attacks once."""
    return rounds == 0 or not _stopped


def _connect(path: str, timeout: float = 2.0) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    sock.connect(path)
    return sock


def _bump(counts: dict, key: str, n: int = 1) -> None:
    counts[key] = counts.get(key, 0) + n


def _exchange(path: str, payload: bytes, counts: dict, shut: bool = False) -> None:
    """Connect, send, read the reply; count what happened (never raises)."""
    try:
        sock = _connect(path)
    except PermissionError:
        _bump(counts, "connect_denied")
        return
    except OSError as exc:
        _bump(counts, f"connect_{type(exc).__name__}")
        return
    with sock:
        try:
            sock.sendall(payload)
            if shut:
                sock.shutdown(socket.SHUT_WR)
        except OSError:
            _bump(counts, "send_cut")       # the server closed early (a refusal, or too long)
        reply = b""
        try:
            while b"\n" not in reply:
                chunk = sock.recv(65536)
                if not chunk:
                    break
                reply += chunk
        except OSError:
            pass
    _count_reply(reply, counts)


def _count_reply(reply: bytes, counts: dict) -> None:
    _bump(counts, "requests")
    if not reply:
        _bump(counts, "no_reply")
        return
    try:
        message = json.loads(reply.split(b"\n", 1)[0])
    except ValueError:
        message = {}
    _bump(counts, "accepted" if message.get("ok") is True else "denied" if message.get("denied") else "refused")


def attack_other_uid(path: str) -> dict:
    """Status and stop requests as fast as they go, from whatever uid this process has."""
    counts: dict = {}
    while running(counts.get("requests", 0)):
        _exchange(path, STATUS, counts)
        _exchange(path, b'{"cmd": "stop", "reason": "attack"}\n', counts)
    return counts


def attack_oversize(path: str) -> dict:
    """10 MB requests, one after another."""
    counts: dict = {}
    blob = b'{"cmd": "status", "pad": "' + b"x" * OVERSIZE_BYTES + b'"}\n'
    while running(counts.get("requests", 0)):
        _exchange(path, blob, counts)
    return counts


def attack_malformed(path: str) -> dict:
    """Malformed and truncated JSON, binary noise, requests cut off by a half-close."""
    counts: dict = {}
    rng = random.Random(1)
    i = 0
    while running(i):
        if i % 3 == 2:
            payload = bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 4096)))
        else:
            payload = JUNK[i % len(JUNK)]
        _exchange(path, payload, counts, shut=True)
        i += 1
    return counts


def attack_flood(path: str) -> dict:
    """A request every microsecond (as fast as a client can): connect, ask, read, again."""
    counts: dict = {}
    while running(counts.get("requests", 0)):
        _exchange(path, STATUS, counts)
    return counts


def attack_idle_slow(path: str) -> dict:
    """Hold IDLE_CONNECTIONS connections open, then a slow client sending one byte a second
    (until the server cuts it off: it must, or the client would hold a slot for ever)."""
    counts: dict = {}
    idle = []
    for _ in range(IDLE_CONNECTIONS):
        try:
            idle.append(_connect(path, timeout=0.5))
        except OSError as exc:
            _bump(counts, f"idle_connect_{type(exc).__name__}")
    counts["idle_opened"] = len(idle)
    started = time.monotonic()
    sent, reply = 0, b""
    try:
        slow = _connect(path)
    except OSError:
        counts["slow_connect_failed"] = 1
        slow = None
    while slow is not None and running(sent):
        try:
            slow.sendall(STATUS[sent % len(STATUS):sent % len(STATUS) + 1])
            sent += 1
            slow.settimeout(1.0)            # one byte a second; the server may answer meanwhile
            reply = slow.recv(4096)
        except socket.timeout:
            continue
        except OSError:
            pass
        counts["slow_cut_after_s"] = round(time.monotonic() - started, 1)
        counts["slow_bytes_sent"] = sent
        if reply:
            _count_reply(reply, counts)
        slow.close()
        slow = None
    closed = 0
    for sock in idle:
        sock.setblocking(False)
        try:
            closed += sock.recv(4096) == b""
        except BlockingIOError:
            pass
        except OSError:
            closed += 1
        sock.close()
    counts["idle_closed_by_server"] = closed
    return counts


ATTACKS = {"other_uid": attack_other_uid, "oversize": attack_oversize, "malformed": attack_malformed,
           "flood": attack_flood, "idle_slow": attack_idle_slow}


def _attacker_main(argv: list[str]) -> int:
    signal.signal(signal.SIGTERM, _on_term)
    kind, path = argv[0], argv[1]
    print("ready", flush=True)              # the harness starts its segments from here
    print(json.dumps(ATTACKS[kind](path)), flush=True)
    return 0


if __name__ == "__main__" and len(sys.argv) > 1 and sys.argv[1] == "attack":
    sys.exit(_attacker_main(sys.argv[2:]))


# ---- the owner side: the service, the phases, the figures ---------------------------------------

import shutil  # noqa: E402  (below: the attacker side above must stay standard-library only)
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
NOBODY = 65534
STATUS_POLL_S = 0.05
STATUS_TIMEOUT_S = 2.0
SETTLE_S = 0.05          # the first ticks of a segment are left out (the switch itself)


@dataclass
class Phase:
    """One attack's quiet or attacked side: the segments it covers, pooled."""

    name: str
    attacked: bool
    windows: list[tuple[float, float]] = field(default_factory=list)     # unix start, end
    latencies_s: list[float] = field(default_factory=list)
    status_failures: list[str] = field(default_factory=list)
    attacker: dict = field(default_factory=dict)
    jitter: dict = field(default_factory=dict)
    jitter_us: Any = None                 # every interval's jitter, for pooling across attacks


@dataclass
class Session:
    pairs: list[tuple[Phase, Phase]]      # (quiet, attacked) per attack, interleaved in time
    final_status: dict
    exit_code: int | None
    log: str
    priority: int


def can_switch_uid() -> bool:
    return os.geteuid() == 0 and shutil.which("setpriv") is not None


def write_config(directory: Path, rate_hz: int, priority: int) -> Path:
    cfg = directory / "attack.yaml"
    cfg.write_text(f"""\
rate_hz: {rate_hz}
clock: real
model: {MODEL}
watchdog_s: 2.0
driver: {{kind: sim, load_mass_kg: 15.3}}
reference: {{kind: sine, frequency_hz: 3.0, amplitude_um: 12.0, offset_um: 15.0}}
limits: {{current_min_A: 0.0, current_max_A: 3.0, slew_A_per_s: 500.0}}
telemetry: {{path: {directory / 'telemetry.csv'}, flush_interval_s: 0.5}}
scheduler: {{realtime_priority: {priority}}}
""")
    return cfg


class StatusPoller(threading.Thread):
    """The owner asking `status` every 50 ms; each answer's latency goes to the current phase."""

    def __init__(self, sock_path: Path) -> None:
        super().__init__(daemon=True)
        self.sock_path = sock_path
        self.phase: Phase | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        from gma_ffc.errors import GmaError
        from gma_ffc.service.control_socket import request

        while not self.stop.wait(STATUS_POLL_S):
            phase = self.phase
            t0 = time.monotonic()
            try:
                reply = request(self.sock_path, {"cmd": "status"}, timeout_s=STATUS_TIMEOUT_S)
                problem = None if reply.get("ok") else str(reply.get("error"))
            except GmaError as exc:
                problem = str(exc)
            if phase is None:
                continue
            if problem is None:
                phase.latencies_s.append(time.monotonic() - t0)
            else:
                phase.status_failures.append(problem)


def _spawn_attacker(kind: str, sock_path: Path) -> subprocess.Popen:
    source = Path(__file__).read_text()
    cmd = [sys.executable, "-I", "-c", source, "attack", kind, str(sock_path)]
    if kind == "other_uid":
        cmd = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", *cmd]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd="/")


def _loosen(runtime: Path, sock_path: Path) -> None:
    """Open the directory and socket modes, so only the peer-uid check stands between nobody and
    the controller (the issue's finding: it held even so)."""
    os.chmod(runtime.parent, 0o711)
    os.chmod(runtime, 0o711)
    os.chmod(sock_path, 0o666)


def _segment(poller: StatusPoller, phase: Phase, seconds: float) -> None:
    poller.phase = phase
    start = time.time()
    time.sleep(seconds)
    phase.windows.append((start, time.time()))
    poller.phase = None


def _run_attack(poller: StatusPoller, kind: str, cycles: int, segment_s: float, sock_path: Path,
                runtime: Path) -> tuple[Phase, Phase]:
    """The attacker process runs throughout, paused (SIGSTOP) in the quiet segments: quiet and
    attacked alternate every `segment_s`, so a slow change of the machine's load hits both."""
    quiet, attacked = Phase(kind, False), Phase(kind, True)
    if kind == "other_uid":
        _loosen(runtime, sock_path)
    proc = _spawn_attacker(kind, sock_path)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()                 # "ready": started, however busy the machine is
        for _ in range(cycles):
            proc.send_signal(signal.SIGSTOP)
            _segment(poller, quiet, segment_s)
            proc.send_signal(signal.SIGCONT)
            _segment(poller, attacked, segment_s)
        proc.send_signal(signal.SIGSTOP)
        _segment(poller, quiet, segment_s)
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        if kind == "other_uid":
            os.chmod(runtime, 0o700)
            os.chmod(sock_path, 0o600)
    try:
        attacked.attacker = json.loads(out.strip().splitlines()[-1])
    except (ValueError, IndexError):
        attacked.attacker = {"attacker_failed": (err or out)[-400:]}
    return quiet, attacked


def pooled_p99_us(phases: list[Phase]) -> float:
    """p99 of every interval of several phases together (steadier than a median of their p99s)."""
    import numpy as np

    return float(np.percentile(np.concatenate([p.jitter_us for p in phases]), 99))


def _jitter(time_s, start_unix: float, phase: Phase, period_s: float) -> dict:
    """Period jitter of the ticks that started within the phase's segments, pooled."""
    import numpy as np

    unix = start_unix + time_s
    parts, overruns = [], 0
    for start, end in phase.windows:
        t = time_s[(unix >= start + SETTLE_S) & (unix <= end)]
        dt = np.diff(t)
        k = np.where(dt / period_s < 1.5, 1.0, np.round(dt / period_s))
        parts.append(np.abs(dt - k * period_s) * 1e6)
        overruns += int((k > 1).sum())
    jit = np.concatenate(parts) if parts else np.zeros(0)
    phase.jitter_us = jit
    if jit.size == 0:
        return {"intervals": 0, "p50_us": math.nan, "p99_us": math.nan, "max_us": math.nan, "overruns": 0}
    return {"intervals": int(jit.size), "p50_us": float(np.percentile(jit, 50)),
            "p99_us": float(np.percentile(jit, 99)), "max_us": float(jit.max()), "overruns": overruns}


def run_session(attacks: list[str], cycles: int, segment_s: float, rate_hz: int = 1000,
                priority: int | None = None) -> Session:
    """Start the service, run each attack in alternating quiet/attacked segments, stop it, measure."""
    from gma_ffc.recordings import read_recording
    from gma_ffc.service.control_socket import request

    if priority is None:
        priority = 50 if os.geteuid() == 0 else 0
    if not can_switch_uid():
        attacks = [a for a in attacks if a != "other_uid"]
    work = Path(tempfile.mkdtemp(prefix="gma-ffc-attack-"))   # under /tmp: nobody may traverse it
    runtime = work / "run"
    sock_path = runtime / "control.sock"
    cfg = write_config(work, rate_hz, priority)
    log_path = work / "service.log"
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "GMA_FFC_RUNTIME_DIR")}
    with open(log_path, "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "gma_ffc.cli", "run", "--config", str(cfg),
                                 "--runtime-dir", str(runtime)], stdout=log, stderr=log, env=env, cwd=work)
    poller = StatusPoller(sock_path)
    pairs: list[tuple[Phase, Phase]] = []
    final: dict = {}
    code = None
    try:
        _wait_running(sock_path, proc)
        time.sleep(1.0)                     # past start-up
        poller.start()
        for kind in attacks:
            pairs.append(_run_attack(poller, kind, cycles, segment_s, sock_path, runtime))
        poller.stop.set()
        poller.join(5)
        final = request(sock_path, {"cmd": "status"}, timeout_s=5.0).get("status", {})
        request(sock_path, {"cmd": "stop", "reason": "attack session over"}, timeout_s=5.0)
        code = proc.wait(timeout=30)
    finally:
        poller.stop.set()
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    rec = read_recording(work / "telemetry.csv", require=("time_s",))
    start_unix = float(rec.metadata["start_unix_s"])
    for pair in pairs:
        for phase in pair:
            phase.jitter = _jitter(rec.time_s, start_unix, phase, 1.0 / rate_hz)
    session = Session(pairs, final, code, log_path.read_text(), priority)
    shutil.rmtree(work, ignore_errors=True)
    return session


def _wait_running(sock_path: Path, proc: subprocess.Popen, timeout_s: float = 90.0) -> None:
    from gma_ffc.errors import GmaError
    from gma_ffc.service.control_socket import request

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the service exited with {proc.returncode} before it ran")
        try:
            status = request(sock_path, {"cmd": "status"}, timeout_s=2.0).get("status", {})
            if status.get("state") == "running" and status.get("ticks", 0) > 0:
                return
        except GmaError:
            pass
        time.sleep(0.1)
    raise RuntimeError("the service did not start running")


def latency_ms(phase: Phase, q: float) -> float:
    import numpy as np

    return float(np.percentile(phase.latencies_s, q) * 1e3) if phase.latencies_s else math.nan


def table(session: Session) -> str:
    """Two lines per attack (its quiet and attacked segments, pooled) and the attacker's tally."""
    lines = [f"loop at 1 kHz, SCHED_FIFO {session.priority or 'off'}; loadavg "
             f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}",
             f"{'attack':<10} {'side':<8} {'ticks':>6} {'p50 us':>7} {'p99 us':>7} {'ratio':>6} {'max us':>8} "
             f"{'overruns':>8} {'status p50/max ms':>18} {'fails':>5}"]
    for quiet, attacked in session.pairs:
        for phase in (quiet, attacked):
            j = phase.jitter
            ratio = f"{j['p99_us'] / quiet.jitter['p99_us']:.2f}" if phase.attacked else ""
            lines.append(f"{phase.name:<10} {'attacked' if phase.attacked else 'quiet':<8} {j['intervals']:>6} "
                         f"{j['p50_us']:>7.1f} {j['p99_us']:>7.1f} {ratio:>6} {j['max_us']:>8.1f} "
                         f"{j['overruns']:>8} {latency_ms(phase, 50):>8.1f} /{latency_ms(phase, 100):>7.1f} "
                         f"{len(phase.status_failures):>5}")
        lines.append(f"{'':<10} attacker: {json.dumps(attacked.attacker, sort_keys=True)}")
    quiet = pooled_p99_us([q for q, _ in session.pairs])
    attacked = pooled_p99_us([a for _, a in session.pairs])
    lines.append(f"all attacks pooled: p99 quiet {quiet:.1f} us, attacked {attacked:.1f} us, ratio {attacked / quiet:.2f}")
    counters = session.final_status.get("control_socket")
    if counters:
        lines.append(f"the server's own tally: {json.dumps(counters, sort_keys=True)}")
    return "\n".join(lines)
