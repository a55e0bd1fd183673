#!/usr/bin/env bash
# The vcan tests (`pytest -m vcan`, tests/vcan/) on real SocketCAN.
#
#   tests/vcan/run-in-vm.sh            from anywhere; needs the project's .venv
#
# Where this kernel has SocketCAN and vcan0 exists (or can be created: root),
# the tests run directly. Otherwise (these development and CI machines: no
# CONFIG_CAN) the script boots Debian's kernel under QEMU's software emulation
# with virtme-ng, sharing this machine's file system read-only, creates vcan0
# inside and runs the tests there. It installs what it needs: the Debian
# packages qemu-system-x86, linux-image-amd64 and busybox-static (apt-get, as
# root) and virtme-ng (pip, into the project's .venv); both steps are skipped
# when already done.
#
# Results, in .vcan-results/ (VCAN_RESULTS overrides): run.log (everything
# printed here, the VM's output included), junit.xml, exit-code, and from the
# VM the tests' own files (daemon and emulator logs, ground truth, traces) in
# pytest-of-*/. The exit status is the tests' (pytest's; 5, nothing collected,
# counts as a failure); 1 if the VM reports none (crash, time limit).
#
# Environment: VCAN_RESULTS (results directory), VCAN_VM_TIMEOUT_S (the VM's
# time limit, default 900), VCAN_VM_MEMORY (default 3G), VCAN_FORCE_VM=1 (boot
# the VM even where SocketCAN works here), VCAN_PYTEST_ARGS (more pytest
# arguments, as shell words: "-k 'filters or sigkill'").
set -uo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
VENV=$ROOT/.venv
PY=$VENV/bin/python
RESULTS=${VCAN_RESULTS:-$ROOT/.vcan-results}
TIMEOUT_S=${VCAN_VM_TIMEOUT_S:-900}
MEMORY=${VCAN_VM_MEMORY:-3G}
CHANNEL=vcan0

say() { echo "vcan: $*"; }
# shellcheck source=tests/vm.sh
. "$ROOT/tests/vm.sh"

pytest_args() {  # one per line; the same selection on the host and in the VM
    local extra=()
    eval "extra=(${VCAN_PYTEST_ARGS:-})" || die "VCAN_PYTEST_ARGS: not shell words"
    printf "%s\n" -m vcan -v -rA -p no:cacheprovider -p no:hypothesispytest --durations=0 \
        "--junitxml=$RESULTS/junit.xml" \
        ${extra[@]+"${extra[@]}"} tests/vcan
}

socketcan_here() {
    "$PY" - <<'EOF' 2>/dev/null
import socket
socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
EOF
}

vcan_here() {  # vcan0 exists, or root creates it (and deletes it again at exit)
    ip link show "$CHANNEL" >/dev/null 2>&1 && return 0
    [ "$(id -u)" -eq 0 ] || return 1
    modprobe vcan 2>/dev/null
    ip link add dev "$CHANNEL" type vcan 2>/dev/null || return 1
    trap 'ip link del "$CHANNEL" 2>/dev/null' EXIT
    ip link set up "$CHANNEL"
}

run_here() {
    say "SocketCAN works on this kernel: running the tests here, on $CHANNEL"
    ip -details link show "$CHANNEL"
    cd "$ROOT" || return 1
    local args
    mapfile -t args < <(pytest_args)
    PYTHONUNBUFFERED=1 "$PY" -m pytest "${args[@]}"
}

run_in_vm() {
    local kernel started vng_status
    install_packages
    install_virtme_ng
    kernel=$(guest_kernel) || die "no kernel in /boot with the vcan module (linux-image-amd64)"
    say "booting $kernel under software emulation (no KVM), $(nproc) CPUs, $MEMORY," \
        "time limit ${TIMEOUT_S} s"
    pytest_args >"$RESULTS/pytest-args"
    started=$(now)
    # A second, read-only 9p export of / that the guest mounts with caching (in-vm.sh):
    # virtme-ng's own root is uncached, ~4 ms per stat under emulation.
    # thread=multi: one host thread per virtual CPU. QEMU 7.2 (Debian 12) ran this guest's
    # software emulation on one thread by default, and the bench's daemon and emulator took
    # turns on one host core: ticks every 29 ms for 20 ms, the emulator's answers a period
    # late, F_hat at 81-110 N in the lane (true force 10 N) and a force-limit stop. With
    # thread=multi the emulator's physics took 9.7 ms per 20 ms period (16.7 ms before).
    # The service VM (tests/service) keeps the default: with thread=multi its weight check
    # measured 12.8 N for 19.6 N in 3 of its 7 tests (a 1 kHz daemon and emulator that no
    # longer take turns on one thread).
    PATH=$VENV/bin:$PATH timeout -k 30 "$TIMEOUT_S" vng --run "$kernel" --disable-kvm \
        --user root --cpus "$(nproc)" --memory "$MEMORY" --rwdir "$RESULTS" \
        "--qemu-opts=-accel tcg,thread=multi -fsdev local,id=rakehost,path=/,security_model=none,readonly=on,multidevs=remap -device virtio-9p-pci,fsdev=rakehost,mount_tag=rakehost" \
        --exec "$(printf '%q %q' "$ROOT/tests/vcan/in-vm.sh" "$RESULTS")" </dev/null
    vng_status=$?
    vm_status "$vng_status" "$started"
}

main() {
    local status
    [ -x "$PY" ] || die "no $PY: create the project's venv first (see the README)"
    say "results in $RESULTS"
    if [ "${VCAN_FORCE_VM:-0}" != 1 ] && socketcan_here && vcan_here; then
        run_here
        status=$?
    else
        say "no SocketCAN with $CHANNEL on this machine: running the tests in a VM"
        run_in_vm
        status=$?
    fi
    verdict "$status" vcan
}

rm -rf "$RESULTS"
mkdir -p "$RESULTS" || die "cannot create $RESULTS"
main 2>&1 | tee "$RESULTS/run.log"
exit "${PIPESTATUS[0]}"
