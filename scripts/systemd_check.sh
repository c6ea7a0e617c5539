#!/usr/bin/env bash
# Run config/systemd/gma-ffc.service under a real systemd manager and check what the unit promises
# (issue 33): start reaches READY, status, a bad reload is refused with the old config running, a
# good reload, a stalled loop trips WatchdogSec and systemd restarts the service, stop ramps to the
# safe current; then `systemd-analyze security` on the loaded unit.
#
# The manager is a throw-away container booted over this machine's /usr (systemd-nspawn
# --volatile=yes: / is a tmpfs that vanishes with it), with this checkout and its Python bound in
# read-only. The rig is the hil_sim Modbus TCP emulator, run inside as a transient unit.
set -euo pipefail

usage() {
    cat <<'TXT'
Usage: scripts/systemd_check.sh [--keep] [--python PATH]

Needs root and the Debian packages systemd and systemd-container. Prints a transcript with PASS or
FAIL per step and exits 0 only if every step passed. Without a usable systemd it says exactly why
and runs the strongest check that can run: systemd-analyze verify and security on the unit file,
and the service's notify protocol against a stand-in manager (tests/test_service_e2e.py).

  --keep         keep the work folder (container log, journal, telemetry)
  --python PATH  the Python whose gma-ffc to run (default: .venv/bin/python of this checkout)
TXT
}

here=$(cd "$(dirname "$0")/.." && pwd)
python=$here/.venv/bin/python
keep=0
while [ $# -gt 0 ]; do
    case "$1" in
        --keep) keep=1; shift ;;
        --python) python=$2; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "systemd_check.sh: error: unknown option '$1' (see --help)" >&2; exit 2 ;;
    esac
done

failures=0
step() { printf '\n=== %s\n' "$*"; }
pass() { printf 'PASS: %s\n' "$*"; }
fail() { printf 'FAIL: %s\n' "$*"; failures=$((failures + 1)); }

fallback() {
    echo "systemd cannot run as a manager here: $1"
    echo "running instead: systemd-analyze verify and security on the unit file, and the notify"
    echo "protocol against a stand-in manager"
    local unit
    unit=$(mktemp -d)/gma-ffc.service
    "$here/scripts/install_service.sh" --dry-run --prefix "$(dirname "$(dirname "$python")")" >"$unit" 2>/dev/null
    if command -v systemd-analyze >/dev/null; then
        systemd-analyze verify "$unit" && echo "PASS: systemd-analyze verify: clean"
        systemd-analyze security --offline=true "$unit" --no-pager | tail -n 3 || true
    else
        echo "systemd-analyze is not installed either (apt-get install systemd)"
    fi
    "$python" -m pytest -q -n 0 "$here/tests/test_service_e2e.py" -k "notify or unit_file"
    exit 1
}

[ "$(id -u)" = 0 ] || fallback "not root (systemd-nspawn needs root)"
command -v systemd-nspawn >/dev/null || fallback "systemd-nspawn is missing (apt-get install systemd-container)"
[ -x /usr/lib/systemd/systemd ] || fallback "/usr/lib/systemd/systemd is missing (apt-get install systemd)"
[ -x "$python" ] || { echo "systemd_check.sh: error: $python not found; pass --python" >&2; exit 2; }

prefix=$(dirname "$(dirname "$python")")
interpreter=$(readlink -f "$python")
pyroot=$(dirname "$(dirname "$interpreter")")      # the interpreter's own installation
work=$(mktemp -d /tmp/gma-ffc-systemd-XXXXXX)
chmod 755 "$work"
port=$("$python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
emu_sock=/run/gma-hil-emu.sock

# ---- what goes into the container ------------------------------------------------------------
"$here/scripts/install_service.sh" --dry-run --prefix "$prefix" >"$work/gma-ffc.service" 2>"$work/render.log"
config() {      # config(model, amplitude): the Modbus TCP rig at the emulator's port
    cat <<YAML
# gma-ffc under systemd (scripts/systemd_check.sh): Modbus TCP to the hil_sim emulator.
rate_hz: 250
model: $1
watchdog_s: 0.5
output_dirs: [/var/lib/gma-ffc]
driver:
  kind: modbus
  disable_on_safe: true
  devices:
    amp:
      transport: tcp
      host: 127.0.0.1
      port: $port
      timeout_s: 30.0     # a device that stops answering hangs the loop in its read: WatchdogSec's case
      register_map: $here/hil_sim/configs/devices/amplifier_int16.yaml
reference: {kind: sine, frequency_hz: 3.0, amplitude_um: $2, offset_um: 15.0}
limits: {current_min_A: 0.0, current_max_A: 3.0, slew_A_per_s: 5.0, safe_current_A: 0.0, stop_ramp_max_s: 2.0}
sensor: {bad_ticks: 3, stale_ticks: 0}
comms: {on_fault: reconnect, backoff_initial_s: 0.1, backoff_max_s: 1.0, max_attempts: 0}
telemetry: {path: /var/lib/gma-ffc/telemetry.csv}
scheduler: {realtime_priority: 50}
YAML
}
config "$here/config/models/sim_sdpi.yaml" 12.0 >"$work/good.yaml"
config "$here/config/models/sim_sdpi.yaml" 8.0 >"$work/good2.yaml"
printf 'format: gma-ffc-model\nversion: 1\nkind: sdpi\nplay: [1, 2\n' >"$work/bad_model.yaml"
config "$work/bad_model.yaml" 12.0 >"$work/bad.yaml"

# ---- boot --------------------------------------------------------------------------------------
step "boot a throw-away systemd (systemd-nspawn --volatile=yes over /usr, this checkout read-only)"
systemd-nspawn -D / --volatile=yes --register=no --keep-unit \
    --bind-ro="$here" --bind-ro="$pyroot" --bind="$work:/gma-check" \
    --boot -- systemd.firstboot=off >"$work/container.log" 2>&1 &
nspawn=$!
cleanup() {
    [ -n "${GMA_CHECK_HOLD:-}" ] && sleep "$GMA_CHECK_HOLD"
    if [ -n "${pid1:-}" ]; then nsenter -t "$pid1" -a systemctl poweroff >/dev/null 2>&1 || true; fi
    for _ in $(seq 50); do kill -0 "$nspawn" 2>/dev/null || break; sleep 0.2; done
    kill "$nspawn" 2>/dev/null || true
    if [ "$keep" = 1 ]; then echo "work folder kept: $work"; else rm -rf "$work"; fi
}
trap cleanup EXIT
pid1=""
for _ in $(seq 300); do
    pid1=$(ps -o pid= --ppid "$nspawn" 2>/dev/null | tr -d ' ' | head -n1 || true)
    if [ -n "$pid1" ]; then
        state=$(nsenter -t "$pid1" -a systemctl is-system-running 2>/dev/null || true)
        case "$state" in running|degraded) break ;; esac
    fi
    kill -0 "$nspawn" 2>/dev/null || fallback "systemd-nspawn exited: $(tail -n 3 "$work/container.log" | tr '\n' ' ')"
    sleep 0.2
done
case "${state:-}" in
    running|degraded) pass "systemd $(nsenter -t "$pid1" -a systemctl --version | head -n1 | cut -d' ' -f2) is PID 1 of the container, system $state" ;;
    *) fallback "the container's systemd did not come up (state '${state:-none}'); see $work/container.log" ;;
esac
inside() { nsenter -t "$pid1" -a "$@"; }
status_as_owner() { inside setpriv --reuid=gma-ffc --regid=gma-ffc --init-groups "$prefix/bin/gma-ffc" status "$@"; }
show() { inside systemctl show gma-ffc -p "$1" --value; }

step "install the unit as scripts/install_service.sh renders it; service user gma-ffc"
if ! (( $(sed -n 's/^CapBnd:\t//p' /proc/self/status | sed 's/^/0x/') >> 24 & 1 )); then
    echo "note: CAP_SYS_RESOURCE is not in this machine's capability bounding set: no process here, the"
    echo "      container's systemd included, can raise RLIMIT_RTPRIO above 0, so LimitRTPRIO=50 cannot take"
    echo "      effect and the loop runs at normal priority (its status says realtime_priority_refused)"
fi
inside useradd --system --no-create-home --home-dir /var/lib/gma-ffc --shell /usr/sbin/nologin --groups dialout --user-group gma-ffc
case "$interpreter" in /root/*)     # install_service.sh refuses this case on a real host, with the advice
    echo "note: this checkout's Python is $interpreter, under /root: the container opens /root to 0711 so the"
    echo "      service user can run it (on a rig, build the venv from a Python the service user can reach)"
    inside chmod 0711 /root ;;
esac
inside install -d -m 0755 /etc/gma-ffc
inside install -m 0644 /gma-check/good.yaml /etc/gma-ffc/config.yaml
inside install -m 0644 /gma-check/gma-ffc.service /etc/systemd/system/gma-ffc.service
inside systemctl daemon-reload
if out=$(inside systemd-analyze verify /etc/systemd/system/gma-ffc.service 2>&1) && [ -z "$out" ]; then
    pass "systemd-analyze verify: clean"
else
    fail "systemd-analyze verify: $out"
fi
grep -E '^(ProtectHome|ExecStart)=' "$work/gma-ffc.service"

step "the rig: hil_sim's Modbus TCP emulator as a transient unit, port $port"
inside systemd-run --unit=gma-hil-emu --quiet "$python" -m hil_sim.emulators modbus-tcp --port "$port" --control "$emu_sock"
for _ in $(seq 300); do inside test -S "$emu_sock" && break; sleep 0.2; done
emu() { inside "$python" -m hil_sim.emulators control "$emu_sock" "$@"; }
emu status >/dev/null && pass "emulator answering" || fail "emulator did not start"

step "start: systemctl start returns once the service sent READY=1 (Type=notify)"
t0=$(date +%s.%N)
if inside systemctl start gma-ffc; then
    t1=$(date +%s.%N)
    pass "active ($(show ActiveState)/$(show SubState)) after $(printf '%.1f' "$(echo "$t1 - $t0" | bc)") s (first start compiles numba's kernels into CacheDirectory)"
else
    fail "systemctl start: $(inside systemctl status gma-ffc --no-pager | tail -n 5)"
fi
pid_a=$(show MainPID)

step "status: systemd's view (STATUS= from the service) and the service's own, as its user"
inside systemctl status gma-ffc --no-pager --lines=0 | sed -n '1,6p'
status_as_owner && pass "gma-ffc status as user gma-ffc" || fail "gma-ffc status as user gma-ffc"
if out=$(inside "$prefix/bin/gma-ffc" status --runtime-dir /run/gma-ffc 2>&1); then
    fail "root was answered: $out"
else
    pass "root is not the owner and is refused: $out"
fi

step "reload with a bad model: refused, the old config keeps running"
ticks() { status_as_owner --json | "$python" -c 'import json, sys; print(json.load(sys.stdin)["ticks"])'; }
inside install -m 0644 /gma-check/bad.yaml /etc/gma-ffc/config.yaml
inside systemctl reload gma-ffc
sleep 1.5
t_a=$(ticks); sleep 1.5; t_b=$(ticks)
refused=$(status_as_owner | grep 'last reload' || true)
echo "$refused"
if [[ "$refused" == *REFUSED*bad_model.yaml* ]] && [ "$(show MainPID)" = "$pid_a" ] && [ "$t_b" -gt "$t_a" ]; then
    pass "refused naming the file; same pid $pid_a; ticks $t_a -> $t_b"
else
    fail "bad reload: '$refused', pid $(show MainPID) (was $pid_a), ticks $t_a -> $t_b"
fi

step "reload with a good config (amplitude 12 -> 8 um)"
inside install -m 0644 /gma-check/good2.yaml /etc/gma-ffc/config.yaml
inside systemctl reload gma-ffc
sleep 1.5
reloaded=$(status_as_owner | grep 'last reload' || true)
echo "$reloaded"
[[ "$reloaded" == *"ok at"* ]] && [ "$(show MainPID)" = "$pid_a" ] && pass "reloaded in place (pid $pid_a)" || fail "good reload: $reloaded"

step "a stalled loop: the emulator stops answering, the loop hangs in a 30 s read, WatchdogSec=5 fires"
restarts_before=$(show NRestarts)
emu fault silent >/dev/null
t0=$(date +%s)
for _ in $(seq 150); do
    [ "$(show NRestarts)" -gt "$restarts_before" ] && break
    sleep 0.2
done
emu clear >/dev/null
inside journalctl -u gma-ffc --no-pager -o cat | grep -E 'Watchdog timeout|SIGABRT|Scheduled restart|Failed with result' | tail -n 4
if [ "$(show NRestarts)" -gt "$restarts_before" ]; then
    pass "systemd killed the stalled service and restarted it after $(( $(date +%s) - t0 )) s (NRestarts $(show NRestarts))"
else
    fail "no restart within 30 s"
fi
for _ in $(seq 300); do [ "$(show SubState)" = running ] && [ "$(show MainPID)" != "$pid_a" ] && break; sleep 0.2; done
[ "$(show SubState)" = running ] && pass "running again, pid $(show MainPID) (was $pid_a)" || fail "not running again: $(show SubState)"

step "stop: SIGTERM, the output ramps to the safe current within the slew limit, exit 0"
sleep 1
inside systemctl stop gma-ffc
inside journalctl -u gma-ffc --no-pager -o cat | tail -n 3
result=$(show Result); code=$(show ExecMainStatus)
emu status >"$work/emulator_after_stop.json"
"$python" - "$work/emulator_after_stop.json" "$work/telemetry.csv" <<'PY' && pass "stop ramped to the safe current (result $result, exit $code)" || fail "stop (result $result, exit $code)"
import json, sys
snap = json.load(open(sys.argv[1]))
last = [v for _, kind, v in snap["history"] if kind == "setpoint"]
print(f"emulator after stop: setpoint {snap['setpoint_A']} A, output enabled {snap['output_enabled']}; "
      f"last setpoints {[round(v, 3) for v in last[-6:]]}")
sys.exit(0 if snap["setpoint_A"] == 0.0 and not snap["output_enabled"] else 1)
PY
[ "$result" = success ] && [ "$code" = 0 ] || fail "systemd recorded result $result, exit status $code"
inside cp /var/lib/gma-ffc/telemetry.csv /gma-check/telemetry.csv
"$python" - "$work/telemetry.csv" <<'PY' && pass "telemetry: the last rows ramp down to 0 A, at most slew/rate per tick" || fail "telemetry ramp"
import sys
import numpy as np
from gma_ffc.recordings import read_recording
rec = read_recording(sys.argv[1], require=("time_s",))
cmd = rec.columns["current_cmd_A"]
tail = cmd[-400:]
steps = np.abs(np.diff(tail))
print(f"telemetry: {len(rec)} rows; last commands {np.round(tail[-5:], 4).tolist()} A; largest step in the last 400 rows {steps.max():.4f} A (slew 5 A/s at 250 Hz: 0.02 A)")
sys.exit(0 if tail[-1] == 0.0 and steps.max() <= 5.0 / 250 * (1 + 1e-6) else 1)   # %.9g in the file
PY

step "systemd-analyze security gma-ffc.service"
inside systemd-analyze security gma-ffc.service --no-pager | tee "$work/security.txt" | grep -vE '^ *✓' || true

step "summary"
if [ "$failures" = 0 ]; then echo "all steps passed"; else echo "$failures step(s) failed"; fi
exit $(( failures > 0 ))
