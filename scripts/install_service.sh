#!/usr/bin/env bash
# Install the gma-ffc systemd unit (config/systemd/gma-ffc.service) with this host's paths,
# check it with `systemd-analyze verify`, create the service user, and enable it.
set -euo pipefail

usage() {
    cat <<'TXT'
Usage: install_service.sh [options]

Installs config/systemd/gma-ffc.service as a system service: fills in where gma-ffc is installed,
the config file and the user, verifies the unit with systemd-analyze (refusing one with any
warning), creates the user (system account, in group dialout for serial ports), creates
/etc/gma-ffc, reloads systemd and enables the unit.

Options:
  --prefix DIR     gma-ffc is DIR/bin/gma-ffc (default: found on PATH, else /usr/local)
  --config FILE    controller config the service runs (default /etc/gma-ffc/config.yaml)
  --user NAME      account the service runs as (default gma-ffc)
  --unit-dir DIR   where the unit goes (default /etc/systemd/system)
  --now            also start the service (after enabling it)
  --no-enable      install and verify only
  -n, --dry-run    change nothing: print the rendered unit on stdout and the commands on stderr
  -h, --help       this help

Exit codes: 0 done, 2 bad usage or a unit that does not verify, 1 a failing system command.
TXT
}

die() { echo "install_service.sh: error: $1" >&2; exit "${2:-2}"; }

here=$(cd "$(dirname "$0")/.." && pwd)
template="$here/config/systemd/gma-ffc.service"
prefix=""
config=/etc/gma-ffc/config.yaml
user=gma-ffc
unit_dir=/etc/systemd/system
dry_run=0
enable=1
now=0

while [ $# -gt 0 ]; do
    case "$1" in
        --prefix) [ $# -ge 2 ] || die "--prefix needs a directory"; prefix=$2; shift 2 ;;
        --prefix=*) prefix=${1#*=}; shift ;;
        --config) [ $# -ge 2 ] || die "--config needs a file"; config=$2; shift 2 ;;
        --config=*) config=${1#*=}; shift ;;
        --user) [ $# -ge 2 ] || die "--user needs a name"; user=$2; shift 2 ;;
        --user=*) user=${1#*=}; shift ;;
        --unit-dir) [ $# -ge 2 ] || die "--unit-dir needs a directory"; unit_dir=$2; shift 2 ;;
        --unit-dir=*) unit_dir=${1#*=}; shift ;;
        --now) now=1; shift ;;
        --no-enable) enable=0; shift ;;
        -n|--dry-run) dry_run=1; shift ;;
        -h|--help) usage; exit 0 ;;
        *) die "unknown option '$1' (see --help)" ;;
    esac
done

[ -f "$template" ] || die "unit template $template not found" 1
if [ -z "$prefix" ]; then
    if found=$(command -v gma-ffc 2>/dev/null); then
        prefix=$(cd "$(dirname "$found")/.." && pwd)
    else
        prefix=/usr/local
    fi
fi
case "$prefix" in /*) ;; *) die "--prefix must be an absolute path, got '$prefix'" ;; esac
case "$config" in /*) ;; *) die "--config must be an absolute path, got '$config'" ;; esac
[[ "$user" =~ ^[a-z_][a-z0-9_-]*$ ]] || die "--user '$user' is not a valid user name"
exe="$prefix/bin/gma-ffc"
if [ ! -x "$exe" ]; then
    [ "$dry_run" = 1 ] || die "$exe not found or not executable: install gma-ffc there or pass --prefix"
    echo "warning: $exe not found (dry run continues)" >&2
fi

rendered=$(mktemp -d)
trap 'rm -rf "$rendered"' EXIT
unit="$rendered/gma-ffc.service"
sed -e "s#^ExecStart=/usr/local/bin/gma-ffc run --config /etc/gma-ffc/config.yaml#ExecStart=$exe run --config $config#" \
    -e "s#^User=gma-ffc#User=$user#" -e "s#^Group=gma-ffc#Group=$user#" "$template" > "$unit"
grep -q "^ExecStart=$exe run --config $config\$" "$unit" || die "could not fill in ExecStart (template changed?)" 1
# ProtectHome=yes would hide a gma-ffc, its Python (a venv made from a pyenv or conda Python keeps
# its interpreter in a home directory: the service would fail with status=203/EXEC) or the config
# under a home directory.
interpreter=""
if [ -f "$exe" ]; then
    shebang=$(head -n1 "$exe" | sed -n 's/^#![[:space:]]*//p' | cut -d' ' -f1)
    [ -n "$shebang" ] && interpreter=$(readlink -f "$shebang" 2>/dev/null || echo "$shebang")
fi
# The service user must be able to reach the interpreter (a pyenv Python under /root is not).
blocked=""
dir=$(dirname "${interpreter:-/}")
while [ -n "$interpreter" ] && [ "$user" != root ] && [ "$dir" != / ]; do
    perms=$(stat -c '%A' "$dir" 2>/dev/null || echo "")
    [ "${perms:9:1}" = x ] || [ "${perms:9:1}" = t ] || { blocked=$dir; break; }
    dir=$(dirname "$dir")
done
if [ -n "$blocked" ]; then
    msg="user $user cannot reach $interpreter ($blocked is mode $(stat -c '%a' "$blocked")): build the venv from a Python it can run, e.g. '/usr/bin/python3 -m venv /opt/gma-ffc', or give $blocked o+x"
    [ "$dry_run" = 1 ] && echo "warning: $msg" >&2 || die "$msg"
fi
case "$prefix:$config:$interpreter" in
    /home/*|/root/*|*:/home/*|*:/root/*)
        sed -i 's#^ProtectHome=yes#ProtectHome=read-only#' "$unit"
        echo "note: gma-ffc, its Python or its config is under /home or /root ($prefix," \
             "${interpreter:-?}, $config): using ProtectHome=read-only" >&2 ;;
esac

if command -v systemd-analyze >/dev/null 2>&1 && [ -x "$exe" ]; then
    # verify exits 0 even on unknown keys; any output at all is a problem with the unit.
    out=$(systemd-analyze verify "$unit" 2>&1) || die "the unit does not verify: $out"
    [ -z "$out" ] || die "the unit does not verify cleanly: $out"
    echo "unit verified with systemd-analyze" >&2
else
    echo "note: systemd-analyze or $exe missing, unit not verified" >&2
fi

run() {
    if [ "$dry_run" = 1 ]; then
        echo "would run: $*" >&2
    else
        "$@" || die "'$*' failed" 1
    fi
}

if [ "$dry_run" = 1 ]; then
    cat "$unit"
fi
if ! id -u "$user" >/dev/null 2>&1; then
    run useradd --system --no-create-home --home-dir /var/lib/gma-ffc --shell /usr/sbin/nologin \
        --groups dialout --user-group "$user"
fi
run install -d -m 0755 "$(dirname "$config")"
run install -d -m 0755 "$unit_dir"
run install -m 0644 "$unit" "$unit_dir/gma-ffc.service"
if [ ! -f "$config" ]; then
    # the config's relative 'model' (models/sim_sdpi.yaml) resolves against the config's folder:
    # copied alone, the config names a model that is not there
    echo "note: $config does not exist yet: copy one of $here/config/*.yaml there;" \
         "copy its model (or your own, from 'gma-ffc identify') to $(dirname "$config")/model.yaml and set" \
         "'model: model.yaml'; point 'telemetry.path' into /var/lib/gma-ffc and set" \
         "'output_dirs: [/var/lib/gma-ffc]'" >&2
fi
if command -v systemctl >/dev/null 2>&1 && [ -d /run/systemd/system ]; then
    run systemctl daemon-reload
    [ "$enable" = 1 ] && run systemctl enable gma-ffc.service
    [ "$now" = 1 ] && run systemctl start gma-ffc.service
else
    echo "note: systemd is not running here: run 'systemctl daemon-reload' and" \
         "'systemctl enable --now gma-ffc' on the target" >&2
fi
[ "$dry_run" = 1 ] || echo "installed $unit_dir/gma-ffc.service (ExecStart=$exe, config $config, user $user)"
