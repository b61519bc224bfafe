#!/usr/bin/env bash
# The VM stage of CI: real kernel CAN and real systemd, in a QEMU guest (as root, from the clone):
#   tools/ci/vm/stage.sh [vcan] [stack] [systemd]      (default: all three)
#   vcan     tests/vcan on kernel vcan interfaces (socketcan), one pytest worker and interface per guest CPU
#   stack    tools/ci/vm/checks/stack.sh: tcs-sim drives and tcs-server on vcan0, slew and track
#   systemd  tools/ci/vm/checks/systemd.sh: install.sh, notify, watchdog, stop, kill -9, tcs-can@
# Builds (or reuses) the image in $TCS_VM_CACHE (/var/cache/tcs-vm), boots a fresh guest per
# part, prints each part's output, a summary with wall times, and exits non-zero when a part
# failed — or, loudly, with 3 when this machine cannot run the stage (and says why).
# Logs (output, console, journal): $TCS_VM_LOGDIR (default /tmp/tcs-vm-logs).
set -uo pipefail
here=$(cd "$(dirname "$0")" && pwd)
parts=("$@"); [ ${#parts[@]} -gt 0 ] || parts=(vcan stack systemd)
export TCS_VM_LOGDIR=${TCS_VM_LOGDIR:-/tmp/tcs-vm-logs}
t0=$(date +%s)
cannot() {
  echo "######## VM STAGE NOT RUN: $* ########" >&2
  echo "######## (kernel CAN and systemd were NOT tested on this machine) ########" >&2
  exit 3
}
[ "$(uname -s)" = Linux ] || cannot "not Linux"
[ "$(id -u)" -eq 0 ] || cannot "needs root (mmdebstrap, 9p shares); run: sudo $0"
if ! command -v qemu-system-x86_64 >/dev/null || ! command -v mmdebstrap >/dev/null; then
  command -v apt-get >/dev/null || cannot "no qemu-system-x86_64/mmdebstrap and no apt-get to install them"
fi
"$here/build-image.sh" || cannot "the guest image could not be built (see above: apt sources, pip index, disk space)"
accel=$("$here/accel.sh" 2>&1) || cannot "$accel"
[ "$accel" = kvm ] || echo "vm stage: no usable hardware virtualization (vmx/svm with /dev/kvm): software emulation (TCG), several times slower"
# a guest under emulation runs several times slower than hardware: the CAN tests stretch their
# protocol times by $slow (tests/vcan/cia402_rig.py: 5 under TCG, 1 with KVM); the stack and
# systemd checks measure their guest and stretch the simulated telescope's times to fit
# (checks/slowdown.py, checks/hwfile.py). TCS_VM_SLOWDOWN sets one factor for all.
slow=${TCS_VM_SLOWDOWN:-$([ "$accel" = kvm ] && echo 1 || echo 5)}
export TCS_VM_ENV="${TCS_VM_ENV:-} TCS_VM_SLOWDOWN"
echo "vm stage: image ready after $(( $(date +%s) - t0 )) s; accelerator $accel, slowdown ${TCS_VM_SLOWDOWN:-"$slow (CAN tests; the checks measure theirs)"}"
summary=()
rc=0
for part in "${parts[@]}"; do
  case "$part" in
    # one pytest worker per guest CPU, each on its own vcan (the project's default of 6 workers
    # would put gw5 on a vcan5 nobody made); the per-test time-out stretched like the rest
    vcan) cmd='n=$(nproc); tools/ci/vcan-up.sh $(seq -f "vcan%g" 0 $((n - 1))) >/dev/null && TCS_TEST_SLOWDOWN='"$slow"' TCS_CAN_INTERFACE=socketcan TCS_CAN_CHANNEL=vcan0 python -m pytest tests/vcan -p no:cacheprovider -q -n "$n" --timeout '"$((120 * slow))"' -rfE --durations=10' ;;
    stack) cmd='bash tools/ci/vm/checks/stack.sh vcan0' ;;
    systemd) cmd='bash tools/ci/vm/checks/systemd.sh' ;;
    *) echo "vm stage: unknown part $part (vcan, stack, systemd)" >&2; exit 2 ;;
  esac
  echo; echo "######## vm stage: $part"
  t=$(date +%s)
  TCS_VM_LOGDIR=$TCS_VM_LOGDIR/$part "$here/run.sh" "$cmd"; prc=$?
  summary+=("$part: $([ "$prc" = 0 ] && echo PASS || echo "FAIL (exit $prc)") in $(( $(date +%s) - t )) s")
  [ "$prc" = 0 ] || rc=1
done
echo; echo "######## vm stage summary ($accel; logs in $TCS_VM_LOGDIR)"
printf '  %s\n' "${summary[@]}"
echo "  total $(( $(date +%s) - t0 )) s"
exit "$rc"
