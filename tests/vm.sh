# Shared by the scripts that boot a VM for the tests (sourced, not run):
# tests/vcan/run-in-vm.sh (the vcan tests on real SocketCAN) and
# tests/service/run-in-vm.sh (the services under a real systemd).
#
# Expects ROOT, VENV and RESULTS set, and `say` defined by the caller.
# shellcheck shell=bash

VM_PACKAGES=(qemu-system-x86 linux-image-amd64 busybox-static)
VIRTME_NG=virtme-ng==1.42

die() { say "error: $*" >&2; exit 1; }
now() { date +%s; }

install_packages() {  # the Debian packages the VM needs (apt-get, as root), once
    local missing=() p started
    for p in "${VM_PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" \
            || missing+=("$p")
    done
    if [ "${#missing[@]}" -eq 0 ]; then
        say "Debian packages present: ${VM_PACKAGES[*]}"
        return 0
    fi
    [ "$(id -u)" -eq 0 ] || die "missing Debian packages: ${missing[*]}; install them as root" \
        "(apt-get install --no-install-recommends ${missing[*]}) or run this script as root"
    say "installing ${missing[*]} (apt-get)"
    started=$(now)
    # INITRD=No: virtme-ng brings its own initramfs, so the kernel package's is not built.
    export DEBIAN_FRONTEND=noninteractive INITRD=No
    if ! apt-get install -y -q --no-install-recommends "${missing[@]}" >"$RESULTS/apt.log" 2>&1
    then
        apt-get update -q >>"$RESULTS/apt.log" 2>&1
        apt-get install -y -q --no-install-recommends "${missing[@]}" >>"$RESULTS/apt.log" 2>&1 \
            || { tail -20 "$RESULTS/apt.log"; die "apt-get install failed; see $RESULTS/apt.log"; }
    fi
    say "installed in $(($(now) - started)) s"
}

install_virtme_ng() {  # virtme-ng into the project's venv (pip), once
    if [ -x "$VENV/bin/vng" ]; then
        say "virtme-ng present: $("$VENV/bin/vng" --version 2>&1 | head -1)"
        return 0
    fi
    say "installing $VIRTME_NG into $VENV (pip)"
    "$VENV/bin/pip" install -q "$VIRTME_NG" || die "pip install $VIRTME_NG failed"
}

guest_kernel() {  # the newest installed kernel whose modules include vcan
    local image version
    for image in $(ls -1 /boot/vmlinuz-* 2>/dev/null | sort -rV); do
        version=${image#/boot/vmlinuz-}
        if find "/lib/modules/$version/kernel/drivers/net/can" -name 'vcan.ko*' 2>/dev/null \
                | grep -q .; then
            echo "$image"
            return 0
        fi
    done
    return 1
}

vm_status() {  # vng's status and start time -> the tests' status left in RESULTS/exit-code
    local vng_status=$1 started=$2
    say "the VM ran for $(($(now) - started)) s (vng exit status $vng_status)"
    if [ ! -s "$RESULTS/exit-code" ]; then
        [ "$vng_status" -eq 124 ] && say "the VM hit its time limit of ${TIMEOUT_S} s"
        say "the VM did not report the tests' exit status: failing"
        return 1
    fi
    return "$(cat "$RESULTS/exit-code")"
}

verdict() {  # pytest's status and what was tested -> the step's status, recorded
    local status=$1 what=$2
    if [ "$status" -eq 5 ]; then
        say "pytest collected no $what tests: failing"
        status=1
    fi
    say "exit status $status; log $RESULTS/run.log, JUnit XML $RESULTS/junit.xml"
    echo "$status" >"$RESULTS/exit-code"
    return "$status"
}
