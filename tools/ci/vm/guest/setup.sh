#!/bin/sh
# tcs VM guest: run in the chroot at image build time, offline (wheels from /opt/tcs-vm/wheelhouse).
set -eu
echo tcs-vm > /etc/hostname
printf '127.0.0.1\tlocalhost\n127.0.1.1\ttcs-vm\n::1\tlocalhost ip6-localhost ip6-loopback\n' > /etc/hosts
echo '/dev/vda / ext4 rw,errors=remount-ro 0 1' > /etc/fstab
passwd -d root >/dev/null
# pip in the guest (install.sh's venv too): offline, from the wheelhouse
printf '[global]\nno-index = true\nfind-links = /opt/tcs-vm/wheelhouse\ndisable-pip-version-check = true\n' > /etc/pip.conf
printf '9p\n9pnet_virtio\n' > /etc/modules-load.d/tcs-vm.conf
mkdir -p /etc/systemd/system/serial-getty@ttyS0.service.d
printf '[Service]\nExecStart=\nExecStart=-/sbin/agetty --autologin root --keep-baud 115200,57600,38400,9600 %%I $TERM\n' \
  > /etc/systemd/system/serial-getty@ttyS0.service.d/autologin.conf
systemctl mask apt-daily.timer apt-daily-upgrade.timer systemd-networkd-wait-online.service \
  e2scrub_all.timer e2scrub_reap.service fstrim.timer 2>/dev/null || true
mkdir -p /etc/systemd/journald.conf.d
printf '[Journal]\nStorage=volatile\n' > /etc/systemd/journald.conf.d/tcs-vm.conf
chmod 0755 /usr/local/sbin/tcs-vm-run
systemctl enable tcs-vm-run.service
python3 -m venv /opt/tcs-vm/venv
/opt/tcs-vm/venv/bin/pip install -q -r /opt/tcs-vm/requirements.txt
/opt/tcs-vm/venv/bin/pip install -q --no-deps --no-build-isolation -e /src
cp /src/pyproject.toml /src/setup.py /opt/tcs-vm/
find /src -mindepth 1 -delete
/opt/tcs-vm/venv/bin/python -c 'import can, canopen, numpy, pytest; print("guest venv: python-can", can.__version__, "canopen", canopen.__version__)'
