#!/usr/bin/env bash
# cyclictest (Debian rt-tests): the soak's platform baseline (ins_hil/soak/baseline.py), used by the soak smoke test.
set -euo pipefail
source "$(dirname "$0")/../lib.sh"
ensure_apt rt-tests
command -v cyclictest >/dev/null
