#!/usr/bin/env bash
# C reference core (firmware_ref/): strict build (C99, -Wall -Wextra -Wpedantic -Werror
# -Wconversion) in the double and the float configuration, the C unit tests in both,
# the tests again under AddressSanitizer + UndefinedBehaviorSanitizer, and under
# valgrind memcheck (any error fails the stage).
set -euo pipefail
source "$(dirname "$0")/../lib.sh"
ensure_apt make gcc libc6-dev valgrind
cd "$ROOT/firmware_ref"
make -s clean
log "firmware_ref: build (double + float, warnings are errors)"
make -s -j2 all
log "firmware_ref: C unit tests (double, float)"
make -s test
log "firmware_ref: C unit tests under ASan + UBSan"
make -s sanitize
log "firmware_ref: C unit tests under valgrind memcheck"
make -s valgrind
log "firmware_ref: log tool under valgrind memcheck"
# a short serial-frame log through the bench tool: exercises the frame decoder and the core
"$PY" - <<'PY' > build/frames.bin
import sys
import numpy as np
from ins_hil.drivers.serial_frame import encode
from ins_hil.types import ImuSample
out = bytearray()
for k in range(2000):
    out += encode(ImuSample(t=0.005 * (k + 1), dt=0.005, dtheta=np.array([1e-4, -2e-4, 3e-4]),
                            dvel=np.array([0.0, 0.0, -9.81 * 0.005]), seq=k))
    if k == 100:
        out += b"\xa5\x5a\x01junk"
sys.stdout.buffer.write(bytes(out))
PY
valgrind --tool=memcheck --error-exitcode=3 -q build/double/ins_ref_log --filter --lat 50 --lon 30 build/frames.bin > build/frames.csv
test "$(wc -l < build/frames.csv)" -eq 2001
