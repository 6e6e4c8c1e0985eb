#!/usr/bin/env bash
# Stage: the Debian mosquitto broker for the MQTT interoperability tests
# (tests/test_interop_mqtt.py starts its own broker on a free loopback port; no service is started here).
set -euo pipefail
source "$(dirname "$0")/../lib.sh"
ensure_apt mosquitto
command -v mosquitto >/dev/null 2>&1 || [ -x /usr/sbin/mosquitto ] || { log "mosquitto not found after install"; exit 1; }
log "mosquitto: $( (/usr/sbin/mosquitto -h 2>&1 || true) | head -1)"
