#!/usr/bin/env bash
# Boot the guest built by build-image.sh and run a command in the project inside it:
#   tools/ci/vm/run.sh 'CMD ...'    (as root) CMD runs with bash in /src (this clone, shared
#                                   read-write over virtio-9p), as root, the guest's venv active
#                                   (Python 3.11 + the [dev] dependencies, tcs installed editable).
#                                   Prints CMD's output as it comes; exits with CMD's exit status
#                                   (124: $TCS_VM_TIMEOUT ran out; 125: the guest ended without a
#                                   status, the console's tail is printed).
#   tools/ci/vm/run.sh              an interactive root shell on the serial console (poweroff ends it)
# The guest has no network; its disk is a snapshot (every boot starts from the built image).
# Environment:
#   TCS_VM_CACHE    the image (default /var/cache/tcs-vm)
#   TCS_VM_ACCEL    auto (default) | kvm | tcg. auto: KVM only when /dev/kvm is usable AND the CPU
#                   has vmx/svm (hardware virtualization); else TCG (software emulation, ~5-10x
#                   slower). A /dev/kvm without vmx/svm (e.g. nested PVM) hangs a stock kernel.
#   TCS_VM_CPUS, TCS_VM_MEM   vCPUs (2), MiB (2048)
#   TCS_VM_TIMEOUT  seconds before the guest is killed (3600)
#   TCS_VM_ENV      names of host variables passed into CMD's environment
#   TCS_VM_LOGDIR   keep output.log, console.log and what CMD wrote to /run-share/out there
set -uo pipefail
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../../.." && pwd)
cache=${TCS_VM_CACHE:-/var/cache/tcs-vm}
for f in vmlinuz initrd.img rootfs.img; do
  [ -e "$cache/$f" ] || { echo "run: no $cache/$f: run tools/ci/vm/build-image.sh first" >&2; exit 2; }
done
accel=$("$here/accel.sh") || exit 2
case "$accel" in
  kvm) cpu=(-enable-kvm -cpu host) ;;
  tcg) cpu=(-accel tcg,thread=multi -cpu max) ;;
esac
share=$(mktemp -d /tmp/tcs-vm-run.XXXXXX)
cleanup() {
  if [ -n "${TCS_VM_LOGDIR:-}" ]; then
    mkdir -p "$TCS_VM_LOGDIR" && cp -f "$share"/output.log "$share"/console.log "$TCS_VM_LOGDIR"/ 2>/dev/null
    [ -d "$share/out" ] && cp -rf "$share/out/." "$TCS_VM_LOGDIR"/
  fi
  rm -rf "$share"
}
trap cleanup EXIT
{
  echo "export TCS_VM_ACCEL=$accel"
  for v in ${TCS_VM_ENV:-}; do [ -n "${!v+x}" ] && printf 'export %s=%q\n' "$v" "${!v}"; done
} > "$share/env"
append="root=/dev/vda rw console=ttyS0,115200 quiet loglevel=3 systemd.show_status=0 panic=-1"
qemu=(qemu-system-x86_64 "${cpu[@]}" -machine q35 -smp "${TCS_VM_CPUS:-2}" -m "${TCS_VM_MEM:-2048}"
  -kernel "$cache/vmlinuz" -initrd "$cache/initrd.img"
  -drive "file=$cache/rootfs.img,if=virtio,format=raw,snapshot=on"
  -virtfs "local,path=$src,mount_tag=src,security_model=none,id=src"
  -virtfs "local,path=$share,mount_tag=run,security_model=none,id=run"
  -device virtio-rng-pci -nic none -no-reboot)
if [ $# -eq 0 ]; then
  echo "run: interactive guest ($accel); the clone: mount -t 9p -o trans=virtio,version=9p2000.L src /src"
  exec "${qemu[@]}" -nographic -append "$append"
fi
printf '%s\n' "$*" > "$share/cmd.sh"
: > "$share/output.log"
timeout -s KILL "${TCS_VM_TIMEOUT:-3600}" "${qemu[@]}" -display none -monitor none \
  -serial "file:$share/console.log" -append "$append systemd.mask=serial-getty@ttyS0.service" &
vm=$!
tail -n +1 -F --pid="$vm" "$share/output.log" 2>/dev/null &
wait "$vm"; qrc=$?
wait 2>/dev/null
[ -e "$share/rc" ] && exit "$(cat "$share/rc")"
if [ "$qrc" -eq 137 ]; then
  echo "run: guest killed after ${TCS_VM_TIMEOUT:-3600} s" >&2; rc=124
else
  echo "run: the guest ended without an exit status (qemu exit $qrc); console:" >&2; rc=125
fi
tail -n 40 "$share/console.log" >&2
exit "$rc"
