#!/usr/bin/env bash
# Build (or reuse) the QEMU guest of the VM stage: Debian's own kernel (with vcan, can-raw,
# can-bcm, 9p), systemd as PID 1, Python 3.11 and the project's dependencies ([dev] extra) from
# a wheelhouse downloaded on the host.   As root, from the clone:  tools/ci/vm/build-image.sh
#
# Inputs, read at run time (nothing is written into any file of the project): the host's apt
# sources (/etc/apt/sources.list, sources.list.d/*) and fetch options (apt-config), the host's
# pip configuration (pip download), pyproject.toml. The results are cached in $TCS_VM_CACHE
# (default /var/cache/tcs-vm) and rebuilt only when an input changed (a stamp of this folder,
# the requirements and the apt sources), so a second run takes a second and needs no network:
#   vmlinuz, initrd.img, rootfs.img (ext4, booted with snapshot=on), wheelhouse/, debs/ (apt cache)
# Heavy steps run under `nice -n 19` ($TCS_VM_NICE). Suite: the host's (VERSION_CODENAME) or
# $TCS_VM_SUITE; the guest's Python is that suite's python3 ($TCS_VM_PYVER, default 3.11).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../../.." && pwd)
cache=${TCS_VM_CACHE:-/var/cache/tcs-vm}
nice=${TCS_VM_NICE:-nice -n 19}
pyver=${TCS_VM_PYVER:-3.11}
t0=$(date +%s)
log() { echo "build-image [$(( $(date +%s) - t0 )) s] $*"; }
[ "$(id -u)" -eq 0 ] || { echo "build-image: run as root (mmdebstrap, mke2fs -d)" >&2; exit 1; }
. /etc/os-release
suite=${TCS_VM_SUITE:-${VERSION_CODENAME:?no VERSION_CODENAME in /etc/os-release: set TCS_VM_SUITE}}
mkdir -p "$cache"
exec 9>"$cache/.lock"; flock 9   # one build at a time per cache

# -- host tools
missing=()
command -v qemu-system-x86_64 >/dev/null || missing+=(qemu-system-x86)
command -v mmdebstrap >/dev/null || missing+=(mmdebstrap)
command -v mke2fs >/dev/null || missing+=(e2fsprogs)
python3 -m pip --version >/dev/null 2>&1 || missing+=(python3-pip)
if [ ${#missing[@]} -gt 0 ]; then
  log "apt-get install ${missing[*]}"
  [ -n "$(find /var/lib/apt/lists -maxdepth 1 -name '*Packages*' -print -quit)" ] || apt-get update -q
  DEBIAN_FRONTEND=noninteractive $nice apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

# -- wheelhouse: runtime + [dev] + build system of pyproject.toml, cp311 manylinux wheels
reqs=$(python3 - "$src/pyproject.toml" <<'PY'
import sys, tomllib
p = tomllib.load(open(sys.argv[1], "rb"))
extras = p["project"].get("optional-dependencies", {})
print("\n".join(p["build-system"]["requires"] + p["project"]["dependencies"] + extras.get("dev", []) + ["pip"]))
PY
)
whstamp=$(printf '%s\n%s\n' "$pyver" "$reqs" | sha256sum | cut -c1-16)
if [ "$(cat "$cache/wheelhouse.stamp" 2>/dev/null)" != "$whstamp" ]; then
  log "pip download (python $pyver)"
  rm -rf "$cache/wheelhouse.new"
  printf '%s\n' "$reqs" > "$cache/requirements.txt"
  $nice python3 -m pip download -q -d "$cache/wheelhouse.new" --only-binary=:all: \
    --python-version "$pyver" --implementation cp --abi "cp${pyver/./}" --abi abi3 --abi none \
    --platform manylinux_2_36_x86_64 --platform manylinux_2_28_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any \
    -r "$cache/requirements.txt"
  rm -rf "$cache/wheelhouse" && mv "$cache/wheelhouse.new" "$cache/wheelhouse"
  echo "$whstamp" > "$cache/wheelhouse.stamp"
fi
log "wheelhouse: $(ls "$cache/wheelhouse" | wc -l) wheels"

# -- the host's apt sources and the fetch options that matter
sources=()
for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
  [ -f "$f" ] && grep -q '^[[:space:]]*[^#[:space:]]' "$f" && sources+=("$f")
done
[ ${#sources[@]} -gt 0 ] || { echo "build-image: no apt sources configured on this host" >&2; exit 1; }
aptopts=()
for opt in Acquire::Check-Valid-Until Acquire::Check-Date Acquire::http::Proxy Acquire::https::Proxy Acquire::Retries; do
  val=$(apt-config dump "$opt" 2>/dev/null | sed -n "s|^$opt \"\(.*\)\";\$|\1|p" | head -1)
  [ -n "$val" ] && aptopts+=("--aptopt=$opt \"$val\";")
done

# linux-image-amd64: has vcan/can-raw/can-bcm (the cloud kernel has no CAN at all)
packages=systemd,systemd-sysv,udev,dbus,kmod,iproute2,procps,util-linux,sudo,can-utils,\
python3,python3-venv,linux-image-amd64,initramfs-tools,zstd
imgstamp=$( (cat "$here"/build-image.sh "$here"/guest/*; echo "$suite $packages $whstamp"; cat "${sources[@]}") | sha256sum | cut -c1-16)
if [ -e "$cache/rootfs.img" ] && [ "$(cat "$cache/image.stamp" 2>/dev/null)" = "$imgstamp" ]; then
  log "image up to date: $cache/rootfs.img"
  exit 0
fi

# -- root file system
root=$cache/rootfs.dir
stage=$cache/src-stage
rm -rf "$root" "$stage" "$cache/rootfs.img.new"
# what an editable install at /src needs (run.sh mounts the clone there): the entry points
# (tcs-server, tcs-sim, ...) exist in the image, no pip run at every boot
mkdir -p "$stage" "$cache/debs"
cp -a "$src/pyproject.toml" "$src/setup.py" "$src/README.md" "$src/tcs" "$src/hwconfig" "$stage/"
log "mmdebstrap $suite from ${sources[*]}"
excl=()   # not unpacked: docs, and kernel drivers a virtio-only guest never loads
for p in '/usr/share/doc/*' '/usr/share/man/*' '/usr/share/info/*' '/usr/share/locale/*' \
         '/lib/modules/*/kernel/drivers/'{gpu,media,infiniband,net/wireless,net/ethernet,staging,bluetooth,iio,hid,usb,isdn,input,scsi,ata,md,mtd,video,hwmon,platform,thunderbolt,misc}'/*' \
         '/lib/modules/*/kernel/'{sound,net/wireless,net/mac80211,net/bluetooth}'/*'; do
  excl+=("--dpkgopt=path-exclude=$p")
done
$nice mmdebstrap --variant=minbase --include="$packages" "${aptopts[@]}" "${excl[@]}" \
  '--dpkgopt=path-include=/usr/share/doc/*/copyright' --dpkgopt=force-unsafe-io --skip=download/empty \
  --setup-hook='mkdir -p "$1"/var/cache/apt/archives/' \
  --setup-hook="sync-in '$cache/debs' /var/cache/apt/archives/" \
  --essential-hook='mkdir -p "$1/etc/initramfs-tools/conf.d" "$1/etc/initramfs-tools/hooks"' \
  --essential-hook="upload '$here/guest/initramfs.conf' /etc/initramfs-tools/conf.d/tcs-vm.conf" \
  --essential-hook="upload '$here/guest/initramfs-hook' /etc/initramfs-tools/hooks/tcs-vm" \
  --essential-hook='chmod 0755 "$1/etc/initramfs-tools/hooks/tcs-vm"' \
  --customize-hook="sync-out /var/cache/apt/archives '$cache/debs'" \
  --customize-hook='rm -f "$1"/var/cache/apt/archives/*.deb "$1"/etc/apt/apt.conf.d/99mmdebstrap' \
  --customize-hook='mkdir -p "$1/opt/tcs-vm" "$1/src"' \
  --customize-hook="upload '$here/guest/tcs-vm-run' /usr/local/sbin/tcs-vm-run" \
  --customize-hook="upload '$here/guest/tcs-vm-run.service' /etc/systemd/system/tcs-vm-run.service" \
  --customize-hook="copy-in '$cache/wheelhouse' /opt/tcs-vm" \
  --customize-hook="upload '$cache/requirements.txt' /opt/tcs-vm/requirements.txt" \
  --customize-hook="upload '$here/guest/setup.sh' /opt/tcs-vm/setup.sh" \
  --customize-hook="sync-in '$stage' /src" \
  --customize-hook='chroot "$1" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin sh /opt/tcs-vm/setup.sh' \
  "$suite" "$root" "${sources[@]}"

# -- kernel, initramfs, ext4 image (raw; sparse)
cp "$(ls -1 "$root"/boot/vmlinuz-* | sort -V | tail -1)" "$cache/vmlinuz"
cp "$(ls -1 "$root"/boot/initrd.img-* | sort -V | tail -1)" "$cache/initrd.img"
used=$(du -sm "$root" | cut -f1)
size=$(( used + ${TCS_VM_FREE_MB:-1536} ))
log "mke2fs: $used MiB used, image $size MiB"
$nice mke2fs -q -t ext4 -L tcs-vm -d "$root" "$cache/rootfs.img.new" "${size}M"
rm -rf "$root" "$stage"
mv "$cache/rootfs.img.new" "$cache/rootfs.img"
echo "$imgstamp" > "$cache/image.stamp"
log "done: $cache/rootfs.img ($(du -sh "$cache/rootfs.img" | cut -f1) on disk)"
