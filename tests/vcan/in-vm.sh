#!/bin/sh
# Inside the VM that tests/vcan/run-in-vm.sh boots (as root, virtme-ng's guest):
# create vcan0, run the vcan tests, leave the exit status in RESULTS/exit-code.
#
#   in-vm.sh RESULTS        RESULTS: the results directory, shared read-write
#
# virtme-ng's root is the host's file system over uncached 9p, where every
# stat costs ~4 ms under software emulation and starting Python with numpy and
# python-can took 25-55 s. run-in-vm.sh exports / a second time (read-only,
# tag rakehost); mounted here with caching, it serves the same files ~100x
# faster, so the tests run chrooted into it, with /proc, /sys, /dev, a tmpfs
# on /run (TMPDIR=/run/tmp) and RESULTS mounted inside.
set -u
RESULTS=$1
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
NEWROOT=/run/rakehost

finish() {
    echo "$1" >"$RESULTS/exit-code"
    echo "vm: exit status $1"
    exit "$1"
}

echo "vm: kernel $(uname -r), $(nproc) CPUs,$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)," \
    "up $(cut -d' ' -f1 /proc/uptime) s"
modprobe vcan && modprobe can_raw \
    && ip link add dev vcan0 type vcan && ip link set up vcan0 \
    || { echo "vm: cannot create vcan0"; finish 1; }
ip -details link show vcan0

cached_root() {  # the cached view at NEWROOT, with what the tests need mounted inside
    mkdir -p "$NEWROOT" && mount -t 9p \
        -o trans=virtio,version=9p2000.L,msize=512000,cache=loose,ro rakehost "$NEWROOT" \
        || return 1
    for dir in proc sys dev; do mount --rbind "/$dir" "$NEWROOT/$dir" || return 1; done
    mount -t tmpfs tmpfs "$NEWROOT/run" && mkdir -p "$NEWROOT/run/tmp" \
        && mount --bind "$RESULTS" "$NEWROOT$RESULTS"
}

# /tmp stays the host's (read-only: the project may live there); TMPDIR is a tmpfs
if cached_root; then
    run="chroot $NEWROOT" tmp=$NEWROOT/run/tmp
else
    echo "vm: no cached view of the host's files: running on virtme-ng's root (slow)"
    run="" tmp=/run/tmp
    mkdir -p "$tmp"
fi

set --  # pytest's arguments, one per line in RESULTS/pytest-args (from run-in-vm.sh)
while IFS= read -r arg; do set -- "$@" "$arg"; done <"$RESULTS/pytest-args"
echo "vm: python -m pytest $*"
$run env -i PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/root \
    LANG=C.UTF-8 TMPDIR=/run/tmp PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1 \
    sh -c 'cd "$1" && shift && exec .venv/bin/python -m pytest "$@"' sh "$ROOT" "$@"
status=$?
echo "vm: up $(cut -d' ' -f1 /proc/uptime) s"
# the tests' own files (daemon and emulator logs, ground truth, traces) for a post-mortem
(cd "$tmp" && tar -cf - --exclude='*.sock' pytest-of-*) | tar -xf - -C "$RESULTS" 2>/dev/null
finish "$status"
