#!/bin/busybox sh
# PID 1 of the throwaway CAN test VM started by tests/can-vm/run.sh.
#
# The initramfs holds only busybox, this script, the kernel modules needed to
# reach the host over 9p and to create vcan interfaces, and (appended per run)
# /job/job.sh + /job/vcan.conf + /job/keep.conf. Everything else (test binary, its shared
# libraries, iproute2, can-utils) comes from the host's root, shared read-only.
#
# Protocol with run.sh on the serial console (lines, CR stripped by the host):
#   @@TENDRIL_CAN_VM_BEGIN@@           the command starts; its output follows
#   @@TENDRIL_CAN_VM_EXIT=<status>@@   the command ended with <status>
#   @@TENDRIL_CAN_VM_SETUP_FAILED: <why>@@   the VM could not run the command
# After either end marker the VM powers off, which ends qemu.

/bin/busybox mkdir -p /proc /sys /dev /bin /sbin
/bin/busybox --install -s /bin
export PATH=/bin:/sbin

mount -t devtmpfs devtmpfs /dev
# The kernel found no /dev/console in the archive (it is built without
# privileges, so it holds no device nodes): reopen the console now.
exec </dev/null >/dev/console 2>&1
mount -t proc proc /proc
mount -t sysfs sysfs /sys

# Progress with guest uptime, for console.log (run.sh shows it on failures).
stage() {
  read -r uptime_s _ </proc/uptime
  echo "tendril-can-vm: $* at ${uptime_s} s"
}

power_off() {
  sync
  poweroff -f
  # poweroff only returns if ACPI is unusable; qemu runs with -no-reboot.
  reboot -f
  sleep 5
  echo b >/proc/sysrq-trigger
}

setup_failed() {
  echo "@@TENDRIL_CAN_VM_SETUP_FAILED: $*@@"
  power_off
}

stage "init started"
# Modules in dependency order, resolved on the host from their .modinfo.
while read -r module; do
  [ -n "$module" ] || continue
  insmod "/modules/$module" || setup_failed "insmod $module failed"
done </modules/load.order

stage "modules loaded"
mkdir -p /host
# cache=loose: the share is read-only and lives only for this run, so caching
# file data in the guest is safe and makes loading large test binaries faster.
mount -t 9p -o trans=virtio,version=9p2000.L,msize=512000,cache=loose,ro host /host ||
  mount -t 9p -o trans=virtio,version=9p2000.L,ro host /host ||
  setup_failed "cannot mount the host root over 9p (mount_tag host)"

mount -t proc proc /host/proc || setup_failed "cannot mount /proc in the host tree"
mount -t sysfs sysfs /host/sys || setup_failed "cannot mount /sys in the host tree"
mkdir -p /dev/pts /dev/shm
mount -t devpts devpts /dev/pts
mount -t tmpfs -o mode=1777 tmpfs /dev/shm
mount -o rbind /dev /host/dev || setup_failed "cannot bind /dev into the host tree"
# Writable scratch space on top of the read-only share. keep.conf: entries of /tmp or /var/tmp (one per
# line: the clone or file that holds the command or the working directory) that stay visible, bound
# back over the tmpfs from where the share shows them.
mkdir -p /keep
n=0
while read -r entry; do
  [ -n "$entry" ] || continue
  n=$((n + 1))
  if [ -d "/host$entry" ]; then mkdir -p "/keep/$n"; else : >"/keep/$n"; fi
  mount -o bind "/host$entry" "/keep/$n" || setup_failed "cannot hold $entry for the VM"
done </job/keep.conf
for dir in /tmp /var/tmp /run; do
  if [ -d "/host$dir" ]; then
    mount -t tmpfs -o mode=1777 tmpfs "/host$dir" || setup_failed "cannot mount tmpfs on $dir"
  fi
done
n=0
while read -r entry; do
  [ -n "$entry" ] || continue
  n=$((n + 1))
  if [ -d "/keep/$n" ]; then mkdir -p "/host$entry"; else : >"/host$entry"; fi
  mount -o bind "/keep/$n" "/host$entry" || setup_failed "cannot show $entry in the VM"
done </job/keep.conf

stage "host root mounted"

# vcan.conf: one interface per line, "<name> <mtu>" (16 = classic CAN, 72 = CAN FD).
# All links are set up by one run of the host's ip (each exec over 9p under
# TCG costs a noticeable fraction of a second).
mkdir -p /host/run/tendril-can-vm
{
  echo "link set lo up"
  while read -r ifname mtu; do
    [ -n "$ifname" ] || continue
    echo "link add dev $ifname type vcan"
    echo "link set dev $ifname mtu $mtu"
    echo "link set dev $ifname up"
  done </job/vcan.conf
} >/host/run/tendril-can-vm/links.ip
chroot /host /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin \
  ip -batch /run/tendril-can-vm/links.ip ||
  setup_failed "ip -batch failed to create the vcan links: $(tr '\n' ';' </job/vcan.conf)"
stage "links up"

cp /job/job.sh /host/run/tendril-can-vm/job.sh || setup_failed "cannot copy the job script"

read -r uptime_s _ </proc/uptime
echo "tendril-can-vm: guest ready after ${uptime_s} s of guest uptime"
echo "@@TENDRIL_CAN_VM_BEGIN@@"
chroot /host /bin/sh /run/tendril-can-vm/job.sh </dev/null
status=$?
# The leading newline ends a last output line that had none; run.sh drops
# the empty line this produces otherwise.
printf '\n@@TENDRIL_CAN_VM_EXIT=%d@@\n' "$status"
power_off
