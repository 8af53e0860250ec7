#!/usr/bin/env bash
# Run one command inside a throwaway qemu VM whose kernel has SocketCAN and
# vcan, and exit with the command's exit status.
#
#   tests/can-vm/run.sh /abs/path/to/binary [args...]
#
# Why: CI kernels have no AF_CAN, so SocketCanBus cannot be tested on the host.
# The VM boots the stock Debian kernel (linux-image-amd64) under TCG with a
# busybox-static initramfs, mounts the host's root read-only over 9p, creates
# vcan interfaces with the host's iproute2, chroots into the host tree and
# runs the command there. Its stdout and stderr appear on this script's stdout.
#
# Needs (Debian packages): qemu-system-x86, busybox-static, cpio, iproute2,
# util-linux (flock), coreutils; to fetch the kernel once: apt, dpkg; xz-utils
# or zstd only if the kernel's modules are compressed. can-utils for
# vcan_selfcheck.sh. Nothing is installed, only downloaded into the cache.
#
# Environment:
#   TENDRIL_CACHE                cache root (default $HOME/.cache/tendril);
#                                this script uses <root>/can-vm
#   TENDRIL_CAN_VM_TIMEOUT       seconds before qemu is killed (default 300)
#   TENDRIL_CAN_VM_VCAN          interfaces to create, "name[:fd] ..."
#                                (default "vcan0:fd vcan1": vcan0 accepts CAN FD
#                                frames, mtu 72; vcan1 is classic-only, mtu 16)
#   TENDRIL_CAN_VM_KERNEL_PKG    kernel package (default: what linux-image-amd64
#                                depends on, or the newest one already cached)
#   TENDRIL_CAN_VM_KERNEL_DEB    use this linux-image .deb instead of apt-get
#   TENDRIL_CAN_VM_ACCEL         qemu accelerator (default tcg; kvm hung on CI)
#   TENDRIL_CAN_VM_MEMORY        guest memory (default 1024M)
#   TENDRIL_CAN_VM_BOOT=bzimage  boot the compressed vmlinuz through the BIOS
#                                instead of the extracted vmlinux's PVH entry
#   TENDRIL_CAN_VM_KEEP_LOG=1    keep the VM console log and print its path
#   TENDRIL_CAN_VM_APPEND        extra kernel arguments (e.g. loglevel=7)
# Variables named GTEST_* and TENDRIL_* are passed on to the command, which
# also gets TENDRIL_CAN_VM=1, HOME=/tmp and this working directory (or /).
#
# Exit status: the command's, or 124 when the timeout hit, 125 when the VM
# could not run the command, 2 for bad usage or missing prerequisites.

set -euo pipefail

SCRIPT_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
readonly SCRIPT_DIR
readonly INIT_SCRIPT="$SCRIPT_DIR/init.sh"
readonly CACHE_DIR="${TENDRIL_CACHE:-${HOME:-/root}/.cache/tendril}/can-vm"
readonly TIMEOUT_S="${TENDRIL_CAN_VM_TIMEOUT:-300}"
readonly VCAN_SPEC="${TENDRIL_CAN_VM_VCAN:-vcan0:fd vcan1}"
readonly ACCEL="${TENDRIL_CAN_VM_ACCEL:-tcg}"
readonly MEMORY="${TENDRIL_CAN_VM_MEMORY:-1024M}"
# Top-level modules; their dependencies are added from .modinfo.
# uinput and evdev: the input-device tests create a real joystick inside the VM.
readonly WANTED_MODULES=(virtio_pci 9pnet_virtio 9p can_raw vcan uinput evdev)

log() { echo "can-vm: $*" >&2; }
die() {
  local status=$1
  shift
  log "error: $*"
  exit "$status"
}

usage() {
  cat >&2 <<'EOF'
usage: tests/can-vm/run.sh /absolute/path/to/command [args...]
Runs the command inside a qemu VM with SocketCAN (vcan0, vcan1) and exits with
its status. See the header of this script for the environment it reads.
EOF
  exit 2
}

[[ $# -ge 1 ]] || usage
[[ $1 != -h && $1 != --help ]] || usage

# ---------------------------------------------------------------- checks ----

# command -> Debian package, for the error message.
declare -A PACKAGE_OF=(
  [qemu-system-x86_64]=qemu-system-x86 [cpio]=cpio [flock]=util-linux
  [timeout]=coreutils [sha256sum]=coreutils [mkfifo]=coreutils
  [dpkg-deb]=dpkg [apt-get]=apt [apt-cache]=apt [xz]=xz-utils [zstd]=zstd
)

require_commands() {
  local missing=() cmd
  for cmd in "$@"; do
    command -v "$cmd" >/dev/null 2>&1 || missing+=("$cmd (package ${PACKAGE_OF[$cmd]:-?})")
  done
  if [[ ${#missing[@]} -gt 0 ]]; then
    die 2 "missing prerequisites: ${missing[*]}; install them with apt-get install"
  fi
}

require_commands qemu-system-x86_64 cpio flock timeout sha256sum mkfifo

find_static_busybox() {
  local candidate
  for candidate in /bin/busybox /usr/bin/busybox "$(command -v busybox 2>/dev/null || true)"; do
    [[ -n $candidate && -x $candidate ]] || continue
    # A dynamically linked busybox cannot run from the initramfs.
    if ! LC_ALL=C ldd "$candidate" >/dev/null 2>&1; then
      echo "$candidate"
      return 0
    fi
  done
  return 1
}
BUSYBOX="$(find_static_busybox)" ||
  die 2 "missing prerequisite: a statically linked busybox (package busybox-static)"

# The host's iproute2 runs inside the VM (busybox ip cannot create vcan links).
[[ -x /usr/sbin/ip || -x /sbin/ip ]] ||
  die 2 "missing prerequisite: ip (package iproute2) in the host tree"

COMMAND_PATH="$1"
[[ $COMMAND_PATH == /* ]] ||
  die 2 "the command must be an absolute path (the VM sees the host's root, not this directory): $COMMAND_PATH"
[[ -f $COMMAND_PATH && -x $COMMAND_PATH ]] ||
  die 2 "not an executable file: $COMMAND_PATH"
case "$COMMAND_PATH" in
  /run/* | /proc/* | /sys/* | /dev/*)
    die 2 "$COMMAND_PATH is under a directory the VM replaces with an empty one; build it elsewhere" ;;
esac
# /tmp and /var/tmp are fresh tmpfs in the VM (the share is read-only), but a clone under /tmp (a CI
# checkout, /tmp/fresh) must still run: the entry of /tmp or /var/tmp that holds the command or the
# working directory stays visible there (read-only, like the rest of the host), bound over the tmpfs.
KEEP_CONF=""
for path in "$COMMAND_PATH" "$PWD"; do
  case "$path" in
    /tmp/?*) base=/tmp ;;
    /var/tmp/?*) base=/var/tmp ;;
    *) continue ;;
  esac
  rest="${path#"$base"/}"
  entry="$base/${rest%%/*}"
  [[ $entry != *$'\n'* ]] || die 2 "a path with a newline cannot be kept in the VM: $entry"
  [[ $'\n'"$KEEP_CONF" == *$'\n'"$entry"$'\n'* ]] || KEEP_CONF+="$entry"$'\n'
done
[[ $TIMEOUT_S =~ ^[1-9][0-9]*$ ]] || die 2 "TENDRIL_CAN_VM_TIMEOUT must be a positive number of seconds, not '$TIMEOUT_S'"
[[ -f $INIT_SCRIPT ]] || die 2 "missing $INIT_SCRIPT"

# "vcan0:fd vcan1" -> lines "vcan0 72" / "vcan1 16".
VCAN_CONF=""
for spec in $VCAN_SPEC; do
  name="${spec%%:*}"
  [[ $name =~ ^[A-Za-z0-9_.-]{1,15}$ ]] || die 2 "bad interface name in TENDRIL_CAN_VM_VCAN: '$spec'"
  [[ $'\n'"$VCAN_CONF" != *$'\n'"$name "* ]] || die 2 "interface $name appears twice in TENDRIL_CAN_VM_VCAN"
  case "$spec" in
    *:fd) VCAN_CONF+="$name 72"$'\n' ;;
    *:*) die 2 "bad interface option in TENDRIL_CAN_VM_VCAN: '$spec' (only :fd is known)" ;;
    *) VCAN_CONF+="$name 16"$'\n' ;;
  esac
done

# ---------------------------------------------------------------- cache -----

if ! mkdir -p "$CACHE_DIR" 2>/dev/null || [[ ! -w $CACHE_DIR ]]; then
  die 2 "cannot write the cache directory $CACHE_DIR (set TENDRIL_CACHE to a writable directory)"
fi
exec 9>"$CACHE_DIR/.lock"
# Parallel runs (ctest -j) share the cache; only one prepares it.
flock 9

# A prepared kernel directory is complete when it was prepared for the current module list.
kernel_complete() {
  [[ -f $1/.complete && "$(cat "$1/.complete")" == "${WANTED_MODULES[*]}" ]]
}

# Prints the directory of a prepared kernel: vmlinuz, modules/*.ko, modules/load.order.
prepare_kernel() {
  local package="${TENDRIL_CAN_VM_KERNEL_PKG:-}" deb="${TENDRIL_CAN_VM_KERNEL_DEB:-}"
  local kernel_dir

  if [[ -z $package && -z $deb ]]; then
    # Reuse what is cached (works offline); newest version first.
    kernel_dir="$(ls -1dv "$CACHE_DIR"/kernel-*/ 2>/dev/null | while read -r d; do
      if kernel_complete "${d%/}"; then echo "${d%/}"; fi
    done | tail -n 1 || true)"
    if [[ -n $kernel_dir ]]; then
      echo "$kernel_dir"
      return 0
    fi
  fi

  if [[ -n $deb ]]; then
    [[ -f $deb ]] || die 2 "TENDRIL_CAN_VM_KERNEL_DEB is not a file: $deb"
    require_commands dpkg-deb
    package="$(dpkg-deb --field "$deb" Package)"
  elif [[ -z $package ]]; then
    require_commands apt-cache
    package="$(apt-cache depends linux-image-amd64 2>/dev/null |
      sed -n 's/^ *Depends: \(linux-image-[0-9].*\)$/\1/p' | head -n 1)"
    [[ -n $package ]] ||
      die 2 "cannot resolve linux-image-amd64 to a kernel package (run apt-get update, or set TENDRIL_CAN_VM_KERNEL_DEB)"
  fi

  kernel_dir="$CACHE_DIR/kernel-$package"
  if kernel_complete "$kernel_dir"; then
    echo "$kernel_dir"
    return 0
  fi

  require_commands dpkg-deb
  local work="$CACHE_DIR/tmp-unpack"
  rm -rf "$work" "$kernel_dir" "$kernel_dir.new"
  mkdir -p "$work"
  if [[ -z $deb ]]; then
    require_commands apt-get
    log "downloading $package with apt-get download (once; cached in $CACHE_DIR)"
    # Sandbox user = us: apt's _apt user cannot write into a private cache dir.
    (cd "$work" && apt-get download -q -o APT::Sandbox::User="$(id -un)" "$package" </dev/null >&2) ||
      die 2 "apt-get download $package failed (run apt-get update, or set TENDRIL_CAN_VM_KERNEL_DEB)"
    deb="$(ls "$work"/*.deb)"
  fi
  log "unpacking $(basename "$deb")"
  dpkg-deb -x "$deb" "$work/root"

  local vmlinuz
  vmlinuz="$(ls "$work"/root/boot/vmlinuz-* 2>/dev/null | head -n 1)"
  [[ -n $vmlinuz ]] || die 125 "$deb holds no /boot/vmlinuz-*"
  local module_root
  module_root="$(ls -d "$work"/root/lib/modules/*/ 2>/dev/null | head -n 1)"
  [[ -n $module_root ]] || die 125 "$deb holds no /lib/modules/<version>"

  mkdir -p "$kernel_dir.new/modules"
  cp "$vmlinuz" "$kernel_dir.new/vmlinuz"
  resolve_modules "${module_root%/}" "$kernel_dir.new/modules"
  mv "$kernel_dir.new" "$kernel_dir"
  echo "${WANTED_MODULES[*]}" >"$kernel_dir/.complete"
  rm -rf "$work"
  echo "$kernel_dir"
}

# Copies the wanted modules and their dependencies (uncompressed) to $2 and
# writes $2/load.order, dependencies first. The package has no modules.dep
# (depmod runs at install time), so dependencies come from each module's
# .modinfo "depends=" string.
resolve_modules() {
  local module_root="$1" out="$2"
  declare -A path_of=() done_=()
  local file name
  while IFS= read -r file; do
    name="$(basename "$file")"
    name="${name%%.ko*}"
    path_of[${name//-/_}]="$file"
  done < <(find "$module_root/kernel" -name '*.ko' -o -name '*.ko.xz' -o -name '*.ko.zst' -o -name '*.ko.gz')

  declare -A builtin=()
  if [[ -f $module_root/modules.builtin ]]; then
    while IFS= read -r file; do
      name="$(basename "$file" .ko)"
      builtin[${name//-/_}]=1
    done <"$module_root/modules.builtin"
  fi

  : >"$out/load.order"
  add_module() {
    local module="${1//-/_}" src dest deps dep
    [[ -z ${done_[$module]:-} ]] || return 0
    done_[$module]=1
    [[ -z ${builtin[$module]:-} ]] || return 0
    src="${path_of[$module]:-}"
    [[ -n $src ]] || die 125 "kernel module $module is neither built in nor in the package"
    dest="$out/$(basename "${src%%.ko*}").ko"
    case "$src" in
      *.ko) cp "$src" "$dest" ;;
      *.xz) require_commands xz && xz -dc "$src" >"$dest" ;;
      *.zst) require_commands zstd && zstd -qdc "$src" >"$dest" ;;
      *.gz) gzip -dc "$src" >"$dest" ;;
    esac
    deps="$(tr '\0' '\n' <"$dest" | sed -n 's/^depends=//p' | head -n 1)"
    for dep in ${deps//,/ }; do
      add_module "$dep"
    done
    basename "$dest" >>"$out/load.order"
  }
  local wanted
  for wanted in "${WANTED_MODULES[@]}"; do
    add_module "$wanted"
  done
}

# Prints the path of the base initramfs (busybox, init.sh, modules), rebuilt
# whenever one of its inputs changes.
prepare_initramfs() {
  local kernel_dir="$1"
  local key
  key="$( (sha256sum "$INIT_SCRIPT" "$BUSYBOX" "$kernel_dir"/modules/* | cut -d' ' -f1) | sha256sum | cut -c1-16)"
  local image="$CACHE_DIR/initramfs-$key.cpio"
  if [[ ! -f $image ]]; then
    local staging="$CACHE_DIR/tmp-initramfs"
    rm -rf "$staging"
    mkdir -p "$staging"/{bin,sbin,dev,proc,sys,host,job,modules}
    cp "$BUSYBOX" "$staging/bin/busybox"
    cp "$INIT_SCRIPT" "$staging/init"
    chmod 755 "$staging/init" "$staging/bin/busybox"
    cp "$kernel_dir"/modules/* "$staging/modules/"
    (cd "$staging" && find . -mindepth 1 | LC_ALL=C sort | cpio --quiet -o -H newc -R 0:0) >"$image.new"
    mv "$image.new" "$image"
    rm -rf "$staging"
    # Older images are of no further use.
    find "$CACHE_DIR" -maxdepth 1 -name 'initramfs-*.cpio' ! -name "$(basename "$image")" -delete
  fi
  echo "$image"
}

# Booting the uncompressed kernel through its PVH entry point skips SeaBIOS's
# real-mode setup and the in-guest xz decompression, which under TCG took
# ~6 s of a ~15 s run. Writes $2 and succeeds only for an ELF with a PVH note.
extract_pvh_vmlinux() {
  local vmlinuz="$1" out="$2" pair tool magic offset
  for pair in 'xz:\xfd7zXZ\x00' 'zstd:\x28\xb5\x2f\xfd' 'gzip:\x1f\x8b\x08'; do
    tool="${pair%%:*}"
    magic="${pair#*:}"
    command -v "$tool" >/dev/null 2>&1 || continue
    for offset in $(LC_ALL=C grep -obUaP "$magic" "$vmlinuz" 2>/dev/null | cut -d: -f1 | head -n 3); do
      # The payload is followed by more bzImage bytes, so the tool complains; the ELF check decides.
      tail -c "+$((offset + 1))" "$vmlinuz" | "$tool" -dcq >"$out.new" 2>/dev/null || true
      # ELF magic, and the Xen ELF note XEN_ELFNOTE_PHYS32_ENTRY (type 18) that qemu needs for PVH.
      if [[ $(head -c 4 "$out.new" | tr -d '\0') == $'\x7fELF' ]] &&
        LC_ALL=C grep -qaP '\x04\x00\x00\x00[\x04\x08]\x00\x00\x00\x12\x00\x00\x00Xen\x00' "$out.new"; then
        mv "$out.new" "$out"
        return 0
      fi
    done
  done
  rm -f "$out.new"
  return 1
}

KERNEL_DIR="$(prepare_kernel)"
if [[ ! -f $KERNEL_DIR/vmlinux && ! -f $KERNEL_DIR/.no-pvh ]]; then
  extract_pvh_vmlinux "$KERNEL_DIR/vmlinuz" "$KERNEL_DIR/vmlinux" || touch "$KERNEL_DIR/.no-pvh"
fi
KERNEL_IMAGE="$KERNEL_DIR/vmlinuz"
if [[ -f $KERNEL_DIR/vmlinux && ${TENDRIL_CAN_VM_BOOT:-pvh} == pvh ]]; then
  KERNEL_IMAGE="$KERNEL_DIR/vmlinux"
fi
BASE_INITRAMFS="$(prepare_initramfs "$KERNEL_DIR")"
# Run directories of runs that were killed outright (SIGKILL) are left behind.
find "$CACHE_DIR" -maxdepth 1 -name 'run.*' -mmin +720 -exec rm -rf {} + 2>/dev/null || true
flock -u 9

# ---------------------------------------------------------------- run -------

RUN_DIR="$(mktemp -d "$CACHE_DIR/run.XXXXXX")"
QEMU_PID=""
FILTER_PID=""
# shellcheck disable=SC2317 # called by the EXIT trap
cleanup() {
  [[ -z $QEMU_PID ]] || kill "$QEMU_PID" 2>/dev/null || true
  [[ -z $FILTER_PID ]] || kill "$FILTER_PID" 2>/dev/null || true
  if [[ ${TENDRIL_CAN_VM_KEEP_LOG:-0} == 1 ]]; then
    log "console log kept in $RUN_DIR/console.log"
  else
    rm -rf "$RUN_DIR"
  fi
}
trap cleanup EXIT
trap 'exit 143' TERM
trap 'exit 130' INT

# Single-quotes a word for /bin/sh.
sh_quote() { printf "'%s'" "${1//\'/\'\\\'\'}"; }

# The job: same working directory (if the VM can see it), a clean environment
# plus GTEST_*/TENDRIL_* from ours, then the command.
mkdir -p "$RUN_DIR/job/job"
{
  echo 'export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin'
  echo 'export HOME=/tmp LANG=C.UTF-8 TERM=dumb'
  # Tells tests they are in the VM, where a missing vcan0 is a failure, not a skip.
  echo 'export TENDRIL_CAN_VM=1'
  while IFS= read -r name; do
    echo "export $name=$(sh_quote "${!name}")"
  done < <(compgen -e | grep -E '^(GTEST|TENDRIL)_' || true)
  echo "cd $(sh_quote "$PWD") 2>/dev/null || cd /"
  printf 'exec'
  for arg in "$@"; do
    printf ' %s' "$(sh_quote "$arg")"
  done
  printf '\n'
} >"$RUN_DIR/job/job/job.sh"
printf '%s' "$VCAN_CONF" >"$RUN_DIR/job/job/vcan.conf"
printf '%s' "$KEEP_CONF" >"$RUN_DIR/job/job/keep.conf"
# The kernel unpacks concatenated archives in turn: base image + this job.
(cd "$RUN_DIR/job" && find job | LC_ALL=C sort | cpio --quiet -o -H newc -R 0:0) >"$RUN_DIR/job.cpio"
cat "$BASE_INITRAMFS" "$RUN_DIR/job.cpio" >"$RUN_DIR/initramfs.cpio"

mkfifo "$RUN_DIR/console"
STARTED_NS="$(date +%s%N)"
timeout --kill-after=10 "$TIMEOUT_S" \
  qemu-system-x86_64 \
  -accel "$ACCEL" -cpu max -smp 1 -m "$MEMORY" \
  -machine pc -nodefaults -no-user-config -display none -no-reboot -nic none \
  -kernel "$KERNEL_IMAGE" -initrd "$RUN_DIR/initramfs.cpio" \
  -append "console=ttyS0 loglevel=3 panic=-1 random.trust_cpu=on ${TENDRIL_CAN_VM_APPEND:-}" \
  -chardev stdio,id=console,signal=off -serial chardev:console -monitor none \
  -virtfs local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap \
  </dev/null >"$RUN_DIR/console" 2>"$RUN_DIR/qemu.stderr" &
QEMU_PID=$!

# Copies the command's output (between the markers) to stdout as it comes,
# everything to console.log, and the outcome to outcome.
awk -v log_file="$RUN_DIR/console.log" -v outcome_file="$RUN_DIR/outcome" '
  function flush_blank_lines() { while (blank > 0) { print ""; blank-- } }
  { sub(/\r$/, ""); print > log_file; fflush(log_file) }
  state == 0 && /@@TENDRIL_CAN_VM_BEGIN@@/ { state = 1; next }
  /@@TENDRIL_CAN_VM_SETUP_FAILED: .*@@/ {
    match($0, /@@TENDRIL_CAN_VM_SETUP_FAILED: .*@@/)
    print "setup " substr($0, RSTART + 31, RLENGTH - 33) > outcome_file
    state = 2; next
  }
  state == 1 && match($0, /@@TENDRIL_CAN_VM_EXIT=[0-9]+@@$/) {
    status = substr($0, RSTART + 22, RLENGTH - 24)
    text = substr($0, 1, RSTART - 1)
    # Drop the empty line made by the newline printed before the marker.
    if (text == "" && blank > 0) blank--
    flush_blank_lines()
    if (text != "") print text
    fflush()
    print "exit " status > outcome_file
    state = 2; next
  }
  state == 1 {
    if ($0 == "") { blank++; next }
    flush_blank_lines(); print; fflush()
  }
' <"$RUN_DIR/console" &
FILTER_PID=$!

qemu_status=0
wait "$QEMU_PID" || qemu_status=$?
QEMU_PID=""
wait "$FILTER_PID" || true
FILTER_PID=""
elapsed_ms=$((($(date +%s%N) - STARTED_NS) / 1000000))

show_console_tail() {
  if [[ -s $RUN_DIR/console.log ]]; then
    log "last lines of the VM console:"
    tail -n 40 "$RUN_DIR/console.log" >&2
  else
    log "the VM console stayed silent (the kernel logs only errors)"
  fi
  if [[ -s $RUN_DIR/qemu.stderr ]]; then
    log "qemu said:"
    cat "$RUN_DIR/qemu.stderr" >&2
  fi
}

outcome="$(cat "$RUN_DIR/outcome" 2>/dev/null || true)"
case "$outcome" in
  exit\ *)
    status="${outcome#exit }"
    ready="$(sed -n 's/^tendril-can-vm: guest ready after \([0-9.]*\) s.*/\1/p' "$RUN_DIR/console.log" | head -n 1)"
    log "command exited with status $status (qemu start to power-off ${elapsed_ms} ms; guest ready after ${ready:-?} s)"
    exit "$status"
    ;;
  setup\ *)
    show_console_tail
    die 125 "the VM could not run the command: ${outcome#setup }"
    ;;
esac
show_console_tail
if [[ $qemu_status -eq 124 || $qemu_status -eq 137 ]]; then
  die 124 "timed out after ${TIMEOUT_S} s (TENDRIL_CAN_VM_TIMEOUT); qemu was killed"
fi
die 125 "the VM stopped (qemu status $qemu_status) without reporting the command's exit status"
