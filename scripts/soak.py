#!/usr/bin/env python3
"""Soak the controller service: hours at 1 kHz on the Modbus TCP emulator, with random faults.

A real `gma-ffc run` (control socket, telemetry, its own process) talks Modbus TCP to the hil_sim
emulator (another process), or with --driver sim steps the simulated rig in-process (reloads and
status polls only: there is no link to break). Random faults, from a seed: link drops and stalls (the emulator stops
answering: the controller goes safe and reconnects), late answers, bad sensor values (NaN and
absurd force readings, shorter than the config's fault threshold: the loop must ride over them),
SIGHUP reloads, and a status poll every second. Every --report-min it prints the service's RSS,
open descriptors and threads (its process and the control socket's), telemetry rows in the file
against the loop's ticks, the faults seen, and the loop's period jitter.

    nice -n 10 .venv/bin/python scripts/soak.py --hours 1 > soak.txt 2>&1 &
    .venv/bin/python scripts/soak.py --hours 0.05 --report-min 1      # a 3-minute look

What it must show (issue 33): RSS growth small and bounded, descriptors and threads flat,
telemetry rows equal to ticks plus the fault ticks the loop also records, less rows reported dropped.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
POLL_S = 1.0
FAULT_EVERY_S = (15.0, 45.0)      # a random fault this often (seconds between)
RELOAD_EVERY_S = (60.0, 240.0)    # a SIGHUP this often
GLITCH_S = 0.004                  # a bad sensor value lasts ~4 ms: below bad_ticks (100 ticks = 0.1 s)
BAD_TICKS = 100


def start_emulator(work: Path, nice: int) -> tuple[subprocess.Popen, int, str]:
    """The Modbus TCP emulator in its own process; its output goes to emulator.log."""
    log = open(work / "emulator.log", "w")
    relative = nice - os.nice(0)          # an absolute niceness, whatever this script runs at
    proc = subprocess.Popen(["nice", "-n", str(relative), sys.executable, "-m", "hil_sim.emulators", "modbus-tcp",
                             "--port", "0", "--control", str(work / "emu.sock")], stdout=log, stderr=log, cwd=work)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and proc.poll() is None:
        text = (work / "emulator.log").read_text()
        port = re.search(r"^connect: .*:(\d+)$", text, re.M)
        control = re.search(r"^control: (.*)$", text, re.M)
        if port and control:
            return proc, int(port.group(1)), control.group(1).strip()
        time.sleep(0.1)
    raise RuntimeError(f"the emulator did not start (see {work / 'emulator.log'})")


def write_config(work: Path, port: int | None, rate_hz: int, priority: int) -> Path:
    """config/modbus_tcp.yaml at the soak's rate and the emulator's port; the sim driver without a port."""
    cfg = yaml.safe_load((ROOT / "config" / "modbus_tcp.yaml").read_text())
    cfg.update(rate_hz=rate_hz, model=str(MODEL), watchdog_s=2.0,
               telemetry={"path": str(work / "soak.csv"), "flush_interval_s": 0.5},
               scheduler={"realtime_priority": priority},
               sensor={"bad_ticks": BAD_TICKS, "stale_ticks": 0},
               comms={"on_fault": "reconnect", "backoff_initial_s": 0.05, "backoff_max_s": 0.5, "max_attempts": 0})
    if port is None:
        cfg["driver"] = {"kind": "sim", "load_mass_kg": 15.3}
    else:
        cfg["driver"]["devices"]["amp"]["port"] = port
    path = work / "soak.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def emulator(control: str, command: str) -> None:
    from hil_sim.emulators import send_control

    send_control(control, command)


def proc_figures(pid: int) -> dict:
    """RSS (MB), open descriptors and threads of one process, from /proc."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss = re.search(r"VmRSS:\s+(\d+)", status)
    threads = re.search(r"Threads:\s+(\d+)", status)
    if rss is None or threads is None:
        raise RuntimeError(f"/proc/{pid}/status has no VmRSS or Threads line")
    return {"rss_mb": int(rss.group(1)) / 1024, "fds": len(os.listdir(f"/proc/{pid}/fd")),
            "threads": int(threads.group(1))}


def child_pid(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/task/{pid}/children").read_text().split()[0])
    except (OSError, IndexError, ValueError):
        return None


class RowCounter:
    """Data rows in the growing telemetry file, counted incrementally (whole lines only)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = 0
        self.rows = 0
        self.header_seen = False

    def update(self) -> int:
        with open(self.path, "rb") as fh:
            fh.seek(self.offset)
            data = fh.read()
        whole = data[:data.rfind(b"\n") + 1]
        self.offset += len(whole)
        for line in whole.splitlines():
            if line[:1].isdigit() or line[:1] == b"-":
                self.rows += 1
        return self.rows


class FaultInjector:
    """Random faults on a schedule drawn from the seed; counts what it did."""

    KINDS = ("drop", "stall", "late", "nan", "absurd")

    def __init__(self, rng: random.Random, control: str | None, service_pid: int) -> None:
        self.rng = rng
        self.control = control
        self.pid = service_pid
        self.kinds = self.KINDS if control else ()         # the sim driver: reloads and polls only
        self.counts = {k: 0 for k in (*self.kinds, "reload")}
        now = time.monotonic()
        self.next_fault = now + rng.uniform(*FAULT_EVERY_S)
        self.next_reload = now + rng.uniform(*RELOAD_EVERY_S)

    def tick(self) -> None:
        now = time.monotonic()
        if now >= self.next_reload:
            os.kill(self.pid, signal.SIGHUP)
            self.counts["reload"] += 1
            self.next_reload = now + self.rng.uniform(*RELOAD_EVERY_S)
        if now >= self.next_fault and self.kinds:
            kind = self.rng.choice(self.kinds)
            getattr(self, kind)()
            self.counts[kind] += 1
            self.next_fault = time.monotonic() + self.rng.uniform(*FAULT_EVERY_S)

    def _for(self, spec: str, seconds: float) -> None:
        assert self.control is not None
        emulator(self.control, f"fault {spec}")
        time.sleep(seconds)
        emulator(self.control, "clear")              # one fault at a time: clear them all

    def drop(self) -> None:
        self._for("drop", self.rng.uniform(0.2, 2.0))

    def stall(self) -> None:
        self._for("silent", self.rng.uniform(0.2, 2.0))

    def late(self) -> None:
        self._for(f"delay:{self.rng.uniform(0.0005, 0.003):.4f}", self.rng.uniform(1.0, 5.0))

    def nan(self) -> None:
        self._for("nan:force_N", GLITCH_S)

    def absurd(self) -> None:
        self._for("out_of_range:force_N", GLITCH_S)


def report_line(elapsed_h: float, service: dict, child: dict | None, status: dict, rows: int,
                faults_seen: dict, injected: dict) -> str:
    tel = status.get("telemetry") or {}
    ticks = status.get("ticks", 0)
    return (f"{elapsed_h:6.2f} h  RSS {service['rss_mb']:6.1f} MB (socket {child['rss_mb'] if child else float('nan'):5.1f})"
            f"  fds {service['fds']:3d}/{child['fds'] if child else -1:2d}  threads {service['threads']:2d}"
            f"  ticks {ticks:>9d}  rows in file {rows:>9d} (pushed {tel.get('rows', 0)}, dropped {tel.get('dropped', 0)})"
            f"  p99 {status.get('jitter_p99_us') or float('nan'):6.1f} us  max {status.get('jitter_max_us') or float('nan'):7.0f} us"
            f"  overruns {status.get('overruns', 0)}  reconnects {status.get('reconnects', 0)}"
            f"  faults seen {json.dumps(faults_seen, sort_keys=True)}  injected {json.dumps(injected, sort_keys=True)}"
            f"  load {os.getloadavg()[0]:.1f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--rate", type=int, default=1000, help="loop rate in Hz (default 1000)")
    parser.add_argument("--report-min", type=float, default=10.0, help="minutes between reports (default 10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--driver", choices=("modbus", "sim"), default="modbus",
                        help="modbus (default): the emulator, with link and sensor faults; sim: the in-process "
                             "simulated rig, SIGHUP reloads and status polls only")
    parser.add_argument("--priority", type=int, default=None, help="SCHED_FIFO priority (default 50 as root, else 0)")
    parser.add_argument("--emulator-nice", type=int, default=0,
                        help="the emulator's niceness, absolute (default 0: a rig's device does not wait for the "
                             "CPU; run this script itself under nice on a shared machine)")
    parser.add_argument("--keep", action="store_true", help="keep the work folder (telemetry, logs)")
    args = parser.parse_args()
    from gma_ffc.errors import GmaError
    from gma_ffc.service.control_socket import request

    priority = args.priority if args.priority is not None else (50 if os.geteuid() == 0 else 0)
    work = Path(tempfile.mkdtemp(prefix="gma-ffc-soak-"))
    emu, port, control = start_emulator(work, args.emulator_nice) if args.driver == "modbus" else (None, None, None)
    cfg = write_config(work, port, args.rate, priority)
    runtime = work / "run"
    log = open(work / "service.log", "w")
    final_json = work / "final.json"
    service = subprocess.Popen([sys.executable, "-m", "gma_ffc.cli", "run", "--config", str(cfg),
                                "--runtime-dir", str(runtime), "--stats-json", str(final_json)],
                               stdout=log, stderr=log, cwd=work)
    where = f"Modbus TCP (emulator port {port})" if port else "the sim driver"
    print(f"soak: {args.hours:g} h at {args.rate} Hz on {where}, seed {args.seed}, "
          f"SCHED_FIFO {priority or 'off'}; work folder {work}; service pid {service.pid}", flush=True)
    rng = random.Random(args.seed)
    rows = RowCounter(work / "soak.csv")
    seen: set[tuple] = set()
    faults_seen: dict[str, int] = {}
    status: dict = {}
    failed_polls = 0
    first: dict | None = None
    samples: list[dict] = []
    start = time.monotonic()
    next_report = start + 60.0           # the first report after a minute: past start-up and warm-up
    end = start + args.hours * 3600.0
    injector = None
    code = 0
    try:
        while time.monotonic() < end:
            if service.poll() is not None:
                print(f"soak: the service exited with code {service.returncode}; see {work / 'service.log'}")
                code = 1
                break
            try:
                status = request(runtime / "control.sock", {"cmd": "status"}, timeout_s=2.0).get("status") or status
            except GmaError:
                failed_polls += 1
            if injector is None and status.get("state") == "running":
                injector = FaultInjector(rng, control, service.pid)
            for entry in status.get("fault_history", []):
                key = (entry.get("fault"), entry.get("at_unix_s"))
                if key not in seen:
                    seen.add(key)
                    faults_seen[entry["fault"]] = faults_seen.get(entry["fault"], 0) + 1
            if injector is not None:
                injector.tick()
            now = time.monotonic()
            if now >= next_report and status:
                figures = proc_figures(service.pid)
                pid = child_pid(service.pid)
                child = proc_figures(pid) if pid else None
                sample = {"h": (now - start) / 3600, **figures, "child": child, "ticks": status.get("ticks", 0),
                          "rows": rows.update(), "status": status}
                first = first or sample
                samples.append(sample)
                print(report_line(sample["h"], figures, child, status, sample["rows"], faults_seen,
                                  injector.counts if injector else {}), flush=True)
                next_report = now + args.report_min * 60.0
            time.sleep(POLL_S)
    finally:
        if service.poll() is None:
            service.send_signal(signal.SIGTERM)
            service.wait(timeout=30)
        if emu is not None:
            emu.send_signal(signal.SIGTERM)
            emu.wait(timeout=10)
        log.close()
    final_rows = rows.update()
    final = json.loads(final_json.read_text())["status"] if final_json.exists() else {}
    print(summary(samples, final, final_rows, service.returncode, failed_polls, work))
    if not args.keep and code == 0:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    return code


def summary(samples: list[dict], final: dict, final_rows: int, exit_code: int | None, failed_polls: int,
            work: Path) -> str:
    """RSS growth, descriptors and threads over the reports; rows against ticks after the stop
    (the final status and the file agree then: nothing is in flight)."""
    if len(samples) < 2:
        return "soak: too short for a summary (fewer than two reports)"
    a, b = samples[0], samples[-1]
    fds = [s["fds"] for s in samples]
    threads = [s["threads"] for s in samples]
    child_fds = [s["child"]["fds"] for s in samples if s["child"]]
    rss_child = [s["child"]["rss_mb"] for s in samples if s["child"]]
    hours = b["h"] - a["h"]
    tel = final.get("telemetry") or {}
    faults: dict[str, int] = {}
    for entry in final.get("fault_history", []):
        faults[entry["fault"]] = faults.get(entry["fault"], 0) + 1
    return "\n".join([
        f"summary over {hours:.2f} h between the first and the last report:",
        f"  RSS {a['rss_mb']:.1f} -> {b['rss_mb']:.1f} MB ({(b['rss_mb'] - a['rss_mb']) / max(hours, 1e-9):+.2f} MB/h); "
        f"control socket process {min(rss_child, default=float('nan')):.1f}-{max(rss_child, default=float('nan')):.1f} MB",
        f"  open descriptors {min(fds)}-{max(fds)} (socket process {min(child_fds, default=-1)}-{max(child_fds, default=-1)}); "
        f"threads {min(threads)}-{max(threads)}",
        f"  after the stop: ticks {final.get('ticks')}, telemetry rows pushed {tel.get('rows')}, written "
        f"{tel.get('rows_written')}, dropped {tel.get('dropped')}; data rows in the file {final_rows}",
        f"  rows - ticks = {(tel.get('rows') or 0) - (final.get('ticks') or 0)}: the fault ticks (recorded at the safe "
        f"current, not timed), {sum(faults.values())} faults in the last {len(final.get('fault_history', []))} of the "
        f"history; reconnects {final.get('reconnects')}",
        f"  rate {final.get('achieved_rate_hz') or float('nan'):.1f} Hz, p99 jitter {final.get('jitter_p99_us')} us, "
        f"overruns {final.get('overruns')}, missed deadlines {final.get('missed_deadlines')}",
        f"  status polls that failed: {failed_polls}; service exit code {exit_code}; log {work / 'service.log'}",
    ])

if __name__ == "__main__":
    sys.exit(main())
