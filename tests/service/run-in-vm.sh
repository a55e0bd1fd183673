#!/usr/bin/env bash
# The services under a real systemd (`pytest -m service`, tests/service/): a VM whose
# PID 1 is systemd installs the project as docs/installation.md says and runs
# rakectl-emulator.service and rakectl.service on vcan0.
#
#   tests/service/run-in-vm.sh         as root; needs the project's .venv
#
# The VM boots Debian's kernel under QEMU's software emulation with virtme-ng's
# --systemd, on a copy-on-write view of this machine's file system: an overlay whose
# lower layer is / (read-only) and whose upper layer is a scratch directory, so
# what the installation writes (/opt/rakectl, /etc/rakectl, users, units) lands
# there and never on this machine. tests/service/hil-init, the VM's /sbin/init in that
# view, mounts it a second time with caching (9p without it costs ~4 ms per stat
# under emulation) and starts systemd on it. rakectl-hil.service, after
# multi-user.target, runs the tests and powers the VM off.
#
# The VM has no network: the installation's pip takes the wheels built here first
# (rakectl's and its dependencies', PIP_NO_INDEX with PIP_FIND_LINKS).
#
# Results, in .service-results/ (SERVICE_RESULTS overrides): run.log (everything
# printed here, the VM's console included), junit.xml, exit-code, and from the VM
# the services' journal (journal-*.json) and the installation's output.
# The exit status is the tests' (pytest's; 5, nothing collected, counts as a
# failure); 1 if the VM reports none (crash, time limit).
#
# Environment: SERVICE_RESULTS, SERVICE_VM_TIMEOUT_S (default 1200),
# SERVICE_VM_MEMORY (default 3G).
set -uo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
VENV=$ROOT/.venv
PY=$VENV/bin/python
RESULTS=${SERVICE_RESULTS:-$ROOT/.service-results}
TIMEOUT_S=${SERVICE_VM_TIMEOUT_S:-1200}
MEMORY=${SERVICE_VM_MEMORY:-3G}
# Services of this machine that start in the VM for nothing (masked there, not here).
MASKED=(postgresql.service postgresql@.service)

say() { echo "service: $*"; }
# shellcheck source=tests/vm.sh
. "$ROOT/tests/vm.sh"

SCRATCH=""
cleanup() {
    [ -n "$SCRATCH" ] || return 0
    if mountpoint -q "$SCRATCH/root"; then  # busy for a moment after a killed qemu
        umount "$SCRATCH/root" 2>/dev/null || { sleep 2; umount "$SCRATCH/root"; } \
            || umount -l "$SCRATCH/root"
    fi
    rm -rf --one-file-system "$SCRATCH"  # never through the overlay of /
}

build_wheels() {  # rakectl's wheel and its dependencies', for the VM's offline pip
    say "building the wheels the installation takes (pip wheel)"
    "$VENV/bin/pip" wheel -q --wheel-dir "$SCRATCH/wheels" "$ROOT" \
        >"$RESULTS/pip-wheel.log" 2>&1 \
        || { tail -20 "$RESULTS/pip-wheel.log"; die "pip wheel failed; see $RESULTS/pip-wheel.log"; }
    ls "$SCRATCH"/wheels/rakectl-*.whl >/dev/null 2>&1 || die "pip wheel made no rakectl wheel"
}

guest_view() {  # the overlay the VM boots on, and what the VM finds in it
    local root=$SCRATCH/root unit
    mkdir -p "$SCRATCH/upper" "$SCRATCH/work" "$root"
    mount -t overlay overlay \
        -o "lowerdir=/,upperdir=$SCRATCH/upper,workdir=$SCRATCH/work" "$root" \
        || die "cannot mount the overlay (root and overlayfs needed)"
    install -m 0755 "$ROOT/tests/service/hil-init" "$root/sbin/init.hil"
    ln -sf init.hil "$root/sbin/init"
    : >"$root/etc/fstab"  # this machine's own file systems are not the VM's
    # systemd-tmpfiles empties /tmp at boot (tmp.conf: D /tmp): a checkout under /tmp
    # vanished from the VM's view (the host's files stay: the overlay takes the removal)
    mkdir -p "$root/etc/tmpfiles.d"
    ln -sf /dev/null "$root/etc/tmpfiles.d/tmp.conf"
    # WatchdogSec 5 s instead of 1 s: emulated ~50x slower, the loop once stalled for
    # over 1 s as an excavation started and was killed mid-flow (what the drop-in does
    # not change: a stalled loop is still killed and restarted, test 4)
    mkdir -p "$root/etc/systemd/system/rakectl.service.d"
    printf '[Service]\nWatchdogSec=5s\n' >"$root/etc/systemd/system/rakectl.service.d/hil.conf"
    unit=$root/etc/systemd/system/rakectl-hil.service
    cat >"$unit" <<EOF
[Unit]
Description=rakectl service tests (tests/service), then power off
After=multi-user.target

[Service]
Type=oneshot
StandardOutput=journal+console
StandardError=journal+console
Environment=RAKECTL_SERVICE_VM=1 SERVICE_RESULTS=$RESULTS SERVICE_WHEELS=$SCRATCH/wheels
Environment=PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1 LANG=C.UTF-8 HOME=/root
# TMPDIR on a tmpfs: 9p cannot fstat a file once unlinked (pytest's capture does)
RuntimeDirectory=hil-tmp
Environment=TMPDIR=/run/hil-tmp
# cd, not WorkingDirectory: without the checkout the unit must still power off
ExecStart=/bin/sh -c 'cd $ROOT || exit 1; $PY -m pytest -m service -v -rA \\
    -p no:cacheprovider -p no:hypothesispytest --durations=0 \\
    --junitxml=$RESULTS/junit.xml tests/service; echo \$\$? >$RESULTS/exit-code; sync'
ExecStopPost=/bin/systemctl poweroff --no-block
TimeoutStartSec=infinity
EOF
    mkdir -p "$root/etc/systemd/system/multi-user.target.wants"
    ln -sf ../rakectl-hil.service "$root/etc/systemd/system/multi-user.target.wants/"
    for unit in "${MASKED[@]}"; do ln -sf /dev/null "$root/etc/systemd/system/$unit"; done
    mkdir -p "$root$RESULTS"
}

run_in_vm() {
    local kernel started vng_status
    install_packages
    install_virtme_ng
    kernel=$(guest_kernel) || die "no kernel in /boot with the vcan module (linux-image-amd64)"
    SCRATCH=$(mktemp -d /var/tmp/rakectl-service.XXXXXX) || die "no scratch directory"
    trap cleanup EXIT
    build_wheels
    guest_view
    say "booting $kernel with systemd as init under software emulation (no KVM)," \
        "$(nproc) CPUs, $MEMORY, time limit ${TIMEOUT_S} s"
    started=$(now)
    PATH=$VENV/bin:$PATH timeout -k 30 "$TIMEOUT_S" vng --run "$kernel" --disable-kvm \
        --systemd --root "$SCRATCH/root" --cpus "$(nproc)" --memory "$MEMORY" \
        "--qemu-opts=-fsdev local,id=hilroot,path=$SCRATCH/root,security_model=none,multidevs=remap -device virtio-9p-pci,fsdev=hilroot,mount_tag=hilroot" \
        </dev/null
    vng_status=$?
    # what the VM wrote is in the overlay's upper layer, at the same paths
    cp -a "$SCRATCH/upper$RESULTS/." "$RESULTS/" 2>/dev/null
    vm_status "$vng_status" "$started"
}

main() {
    local status
    [ -x "$PY" ] || die "no $PY: create the project's venv first (see the README)"
    [ "$(id -u)" -eq 0 ] || die "run as root: the VM's view of this machine is an overlay mount"
    say "results in $RESULTS"
    run_in_vm
    status=$?
    verdict "$status" service
}

rm -rf "$RESULTS"
mkdir -p "$RESULTS" || { echo "service: error: cannot create $RESULTS" >&2; exit 1; }
main 2>&1 | tee "$RESULTS/run.log"
exit "${PIPESTATUS[0]}"
