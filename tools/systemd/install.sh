#!/usr/bin/env bash
# Install or upgrade tcs as a systemd service on the cabinet computer (run as root from a clone):
#   sudo tools/systemd/install.sh [--prefix /opt/tcs] [--template hwconfig/cabinet.toml]
#                                 [--wheelhouse DIR]
#
# Idempotent: a re-run upgrades in place. It puts the package in a virtual environment
# ($prefix/venv), creates the system user "tcs", installs the units and, only when there is
# none yet, the real-cabinet template as /etc/tcs/tcs.toml (root:tcs 0640; no users, no site:
# the service refuses to start until a user is made with tcs-passwd). An existing /etc/tcs is
# never overwritten. When the hardware file uses socketcan it installs the CAN bring-up
# (tcs-can@<channel>.service, /etc/tcs/can-<channel>.env) and orders tcs-server after it.
# Every step prints what it changed; at the end the hardware file is checked with
# `tcs-server --check-config`. It does not start or restart the service.
#
# Offline (a cabinet computer without the package index): make a wheelhouse on a machine that
# has the index, with the same Python version and architecture,
#   pip wheel -w wheelhouse /path/to/tcs-clone      # tcs and every dependency as wheels
# copy it over, and give it with --wheelhouse DIR: pip then installs from DIR only (--no-index).
#
# DESTDIR=DIR installs below DIR instead of / (no user, no systemctl: for tests and packaging);
# the venv's scripts then name $prefix, where the tree is meant to be copied;
# TCS_VENV_OPTIONS (e.g. --system-site-packages) is passed to `python3 -m venv`.
set -euo pipefail
prefix=/opt/tcs
src=$(cd "$(dirname "$0")/../.." && pwd)
template=$src/hwconfig/cabinet.toml
wheelhouse=""
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix=$2; shift 2 ;;
    --template|--config) template=$(cd "$(dirname "$2")" && pwd)/$(basename "$2"); shift 2 ;;
    --wheelhouse) wheelhouse=$(cd "$2" && pwd) || { echo "no wheelhouse directory $2" >&2; exit 2; }; shift 2 ;;
    *) echo "usage: $0 [--prefix DIR] [--template HARDWARE-FILE.toml] [--wheelhouse DIR]" >&2; exit 2 ;;
  esac
done
python3 -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null || {
  echo "tcs needs Python 3.11 or newer as python3 (found: $(python3 --version 2>&1))" >&2; exit 1; }
python3 -c 'import venv, ensurepip' 2>/dev/null || {
  echo "python3 has no venv/ensurepip module: install it (Debian: apt-get install python3-venv)" >&2; exit 1; }
root=${DESTDIR:-}
[ -n "$root" ] || [ "$(id -u)" -eq 0 ] || { echo "run as root" >&2; exit 1; }
etc=$root/etc/tcs
units=$root/etc/systemd/system
venv=$root$prefix/venv
hwfile=$etc/tcs.toml
changed=0

say() { echo "  $*"; }
note() { say "$*"; changed=1; }
# install_file SRC DEST MODE: copy when different, say so.
install_file() {
  if [ -e "$2" ] && cmp -s "$1" "$2"; then
    say "unchanged $2"
  else
    local what=installed; [ -e "$2" ] && what=updated
    install -D -m "$3" "$1" "$2"
    note "$what $2"
  fi
}
owned() { [ -z "$root" ] && chown "$1" "$2" || true; }

echo "tcs install from ${wheelhouse:-$src} into ${root:-/} (prefix $prefix):"

# -- user
if [ -z "$root" ]; then
  if id tcs >/dev/null 2>&1; then
    say "user tcs exists"
  else
    useradd --system --home-dir /var/lib/tcs --shell /usr/sbin/nologin tcs
    note "created system user tcs"
  fi
fi

# -- package
before=""
if [ -x "$venv/bin/python" ]; then
  before=$("$venv/bin/python" -c 'import tcs; print(tcs.__version__)' 2>/dev/null || true)
else
  # shellcheck disable=SC2086
  python3 -m venv ${TCS_VENV_OPTIONS:-} "$venv"
  note "created $venv"
fi
if [ -n "$wheelhouse" ]; then
  # offline: tcs and its dependencies from the wheelhouse only
  "$venv/bin/python" -m pip install --quiet --upgrade --no-index --find-links "$wheelhouse" tcs
else
  "$venv/bin/python" -m pip install --quiet --upgrade "$src"
fi
after=$("$venv/bin/python" -c 'import tcs; print(tcs.__version__)')
if [ -n "$root" ]; then
  # a DESTDIR venv is used from $prefix once the tree is copied there (a package, an image):
  # its scripts and activate name $prefix/venv, not $root$prefix/venv (this script itself only
  # runs "$venv/bin/python", which works from either place)
  grep -rlI --exclude-dir=__pycache__ -e "$root$prefix/venv" "$venv/bin" "$venv/pyvenv.cfg" 2>/dev/null |
    while read -r f; do sed -i "s#$root$prefix/venv#$prefix/venv#g" "$f"; done || true
fi
if [ -z "$before" ]; then
  note "installed tcs $after"
elif [ "$before" != "$after" ]; then
  note "upgraded tcs $before -> $after"
else
  say "reinstalled tcs $after from $src"
fi
install_file "$src/README.md" "$root$prefix/README.md" 0644
if [ -d "$root$prefix/hwconfig" ]; then
  # older installs copied hwconfig/ here (and nested it on a re-run); the files now ship
  # inside the package
  rm -rf "$root$prefix/hwconfig"
  note "removed $root$prefix/hwconfig of an older install (the shipped files are package data)"
fi

# -- hardware file
install -d -m 0750 "$etc"
owned root:tcs "$etc"
if [ -e "$hwfile" ]; then
  say "kept $hwfile"
else
  install -m 0640 "$template" "$hwfile"
  owned root:tcs "$hwfile"
  note "installed $hwfile from $(basename "$template") (no users yet)"
fi

# -- units
unit=$(mktemp)
trap 'rm -f "$unit"' EXIT
sed "s#/opt/tcs#$prefix#g" "$src/tools/systemd/tcs-server.service" > "$unit"
install_file "$unit" "$units/tcs-server.service" 0644
install_file "$src/tools/systemd/tcs-can@.service" "$units/tcs-can@.service" 0644
read -r interface channel bitrate < <("$venv/bin/python" - "$hwfile" <<'PY'
import sys, tomllib
try:
    can = tomllib.load(open(sys.argv[1], "rb")).get("can") or {}
except Exception:
    can = {}
print(can.get("interface", "virtual"), can.get("channel", "-"), can.get("bitrate", 1000000))
PY
)
dropin=$units/tcs-server.service.d/can.conf
if [ "$interface" = socketcan ]; then
  env=$etc/can-$channel.env
  if [ -e "$env" ]; then
    say "kept $env"
  else
    printf 'BITRATE=%s\nRESTART_MS=100\nTXQUEUELEN=1000\n' "$bitrate" > "$env"
    note "installed $env (bitrate $bitrate)"
  fi
  printf '[Unit]\nRequires=tcs-can@%s.service\nAfter=tcs-can@%s.service\n' "$channel" "$channel" > "$unit"
  install_file "$unit" "$dropin" 0644
  if [ -z "$root" ] && ! systemctl is-enabled --quiet "tcs-can@$channel.service" 2>/dev/null; then
    systemctl enable --quiet "tcs-can@$channel.service" && note "enabled tcs-can@$channel.service"
  fi
elif [ -e "$dropin" ]; then
  rm -f "$dropin"
  note "removed $dropin (the bus is $interface, not socketcan)"
fi
if [ -z "$root" ] && [ -d /run/systemd/system ]; then
  systemctl daemon-reload
fi
[ "$changed" -eq 1 ] || say "nothing changed"

# -- check
echo
# an older install put sim.toml, with its public development user, into /etc/tcs
"$venv/bin/python" - "$hwfile" <<'PY'
import sys, tomllib
from tcs.resources import hwconfig_file
public = {u.get("password") for u in tomllib.loads(hwconfig_file("sim.toml").read_text()).get("users", [])}
try:
    users = tomllib.loads(open(sys.argv[1], encoding="utf-8").read()).get("users", [])
except (OSError, ValueError):
    users = []
for user in users:
    if user.get("password") in public:
        print(f"WARNING: user {user.get('name')!r} of {sys.argv[1]} has the PUBLIC password hash of "
              "hwconfig/sim.toml (admin/admin): replace it with one made by tcs-passwd")
PY
if "$venv/bin/python" -m tcs.cli.server --check-config "$hwfile"; then
  echo "The hardware file is valid."
  if [ -z "$root" ] && systemctl is-active --quiet tcs-server 2>/dev/null; then
    echo "The service runs the old version until:  systemctl restart tcs-server"
  fi
else
  cat <<MSG
The hardware file is not complete yet (the service refuses to start until it is):
  - make a user:   $prefix/venv/bin/tcs-passwd NAME --rlevel 0 --wlevel 0
    and paste the printed [[users]] table into $hwfile;
  - [site] latitude/longitude/height; [server] host (0.0.0.0 to serve the observatory network);
  - [can] channel, bitrate; [drives.*] node ids, identities (tcs-commission scan), EDS; [axes.*] limits.
Check it again:  $prefix/venv/bin/tcs-server --check-config $hwfile
MSG
fi
cat <<MSG
Enable it:  systemctl enable --now tcs-server;  logs: journalctl -u tcs-server -f
Stop it (for tcs-commission):  systemctl stop tcs-server
MSG
