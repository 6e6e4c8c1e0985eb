#!/usr/bin/env bash
# Test stage: the CAN drivers against a real SocketCAN vcan0 (pytest -m vcan).
# Natively when the kernel has CAN, otherwise inside a QEMU guest (scripts/vcan).
# FAILS (never skips) when no vcan can be had.
set -uo pipefail
source "$(dirname "$0")/../lib.sh"
cd "$ROOT"
ensure_apt qemu-system-x86 linux-image-amd64 busybox-static cpio can-utils || { log "50-vcan: cannot install the vcan guest packages"; exit 1; }
export VCAN_VM_TIMEOUT=${VCAN_VM_TIMEOUT:-600}
# the venv lives in the shared working directory: let the guest cache its reads (imports dominate)
export VCAN_VM_CWD_CACHE=${VCAN_VM_CWD_CACHE:-loose}
# one guest for the whole vcan module; the venv's python is called directly inside
"$ROOT/scripts/vcan" "\"$PY\" -m pytest -m vcan -q -p no:cacheprovider -p no:hypothesispytest --durations=5 tests/vcan $*"
rc=$?
[ $rc -eq 0 ] || log "50-vcan: the vcan tests failed (exit $rc; 125 = no vcan could be had, 124 = guest timeout)"
exit $rc
