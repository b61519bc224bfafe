#!/usr/bin/env bash
# Install tcs as a systemd service on the cabinet computer (run as root from a clone):
#   sudo tools/systemd/install.sh [--prefix /opt/tcs] [--config hwconfig/sim.toml]
# Puts the package in a virtual environment, creates the system user "tcs", installs the unit
# and an example hardware file in /etc/tcs/tcs.toml (never overwriting an existing one), then
# says what to edit. It does not start the service.
set -euo pipefail
prefix=/opt/tcs
example=hwconfig/sim.toml
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix=$2; shift 2 ;;
    --config) example=$2; shift 2 ;;
    *) echo "usage: $0 [--prefix DIR] [--config EXAMPLE.toml]" >&2; exit 2 ;;
  esac
done
src=$(cd "$(dirname "$0")/../.." && pwd)
[ "$(id -u)" -eq 0 ] || { echo "run as root" >&2; exit 1; }

id tcs >/dev/null 2>&1 || useradd --system --home-dir /var/lib/tcs --shell /usr/sbin/nologin tcs
mkdir -p "$prefix" /etc/tcs
python3 -m venv "$prefix/venv"
"$prefix/venv/bin/pip" install --quiet --upgrade pip
"$prefix/venv/bin/pip" install --quiet "$src"
cp "$src/README.md" "$prefix/README.md"
cp -r "$src/hwconfig" "$prefix/hwconfig"
if [ ! -e /etc/tcs/tcs.toml ]; then
  install -m 0640 -o root -g tcs "$src/$example" /etc/tcs/tcs.toml
  cp -r "$src/hwconfig/eds" /etc/tcs/eds
fi
sed "s#/opt/tcs#$prefix#g" "$src/tools/systemd/tcs-server.service" > /etc/systemd/system/tcs-server.service
systemctl daemon-reload
cat <<MSG
Installed tcs in $prefix and the unit tcs-server.service.
Now edit /etc/tcs/tcs.toml:
  - [site] latitude/longitude/height, [time] tai_utc/ut1_utc;
  - [[users]]: replace admin/admin with hashes from: $prefix/venv/bin/tcs-passwd NAME;
  - [server] host (0.0.0.0 to serve the observatory network), port;
  - [can] interface = "socketcan", channel = "can0"; [drives.*] identities; [axes.*] limits;
  - remove [simulation] (a real cabinet has real drives).
Check it:        $prefix/venv/bin/tcs-server --config /etc/tcs/tcs.toml   (Ctrl-C to stop)
Then enable it:  systemctl enable --now tcs-server;  logs: journalctl -u tcs-server -f
MSG
