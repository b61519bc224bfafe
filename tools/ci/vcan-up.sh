#!/bin/sh
# Create kernel virtual CAN interfaces for the CAN tests (any Linux box with kernel CAN):
#   tools/ci/vcan-up.sh [vcan0 [vcan1 ...]]     (re-runs itself with sudo when not root)
# then:  TCS_CAN_INTERFACE=socketcan TCS_CAN_CHANNEL=vcan0 python3 -m pytest tests/vcan
# pytest-xdist worker gwN uses the N-th interface after TCS_CAN_CHANNEL (tests/vcan/conftest.py):
# with the default -n 4 create vcan0 … vcan3 (more do no harm), so that the workers' drives cannot hear each other.
# Idempotent. Loads the vcan module (on Ubuntu's cloud kernels it is in
# linux-modules-extra-$(uname -r), installed when missing), adds each interface, brings it up.
set -eu
[ $# -gt 0 ] || set -- vcan0
if [ "$(id -u)" -ne 0 ]; then
  exec sudo "$0" "$@"
fi
if ! modprobe vcan 2>/dev/null; then
  if command -v apt-get >/dev/null 2>&1; then
    apt-get install -y -q "linux-modules-extra-$(uname -r)" >/dev/null
    modprobe vcan
  else
    echo "vcan-up: cannot load the vcan kernel module" >&2
    exit 1
  fi
fi
for ch in "$@"; do
  ip link show "$ch" >/dev/null 2>&1 || ip link add dev "$ch" type vcan
  ip link set "$ch" txqueuelen 1000
  ip link set "$ch" up
  ip -brief link show "$ch"
done
