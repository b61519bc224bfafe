#!/bin/sh
# Print how this host can run the VM stage's guest: "kvm", "tcg", or (exit 1) why it cannot.
#   TCS_VM_ACCEL=kvm|tcg forces one; auto (default): kvm only where /dev/kvm is usable AND the
#   CPU shows vmx/svm (hardware virtualization). A /dev/kvm without them (e.g. nested PVM, module
#   kvm_pvm) runs only PVM-built guest kernels and hangs Debian's, so that host gets tcg.
accel=${TCS_VM_ACCEL:-auto}
command -v qemu-system-x86_64 >/dev/null 2>&1 || { echo "no qemu-system-x86_64 (apt-get install qemu-system-x86)" >&2; exit 1; }
[ "$(uname -m)" = x86_64 ] || { echo "the guest is x86_64; this host is $(uname -m)" >&2; exit 1; }
case "$accel" in
  kvm|tcg) echo "$accel" ;;
  auto)
    if [ -r /dev/kvm ] && [ -w /dev/kvm ] && grep -q -m1 -w -E 'vmx|svm' /proc/cpuinfo; then echo kvm; else echo tcg; fi ;;
  *) echo "TCS_VM_ACCEL must be auto, kvm or tcg" >&2; exit 1 ;;
esac
