#!/usr/bin/env bash
# Stage: the README's first command on a fresh clone. Clones this checkout's HEAD into a temporary folder
# laid out like a user's (<tmp>/main, <tmp>/shared -> ../shared), runs `scripts/run --duration 20 --no-status`
# there from zero (its own new virtualenv; the pip cache is reused) and asserts: exit 0, at least one HEARTBEAT
# from the gateway on the ground-station port (UDP 127.0.0.1:14550, the default config's udpout), and a
# recording recordings/*.ihlog in the clone. Every failure says in one line what failed and the log to read;
# the temporary folder is kept on failure, removed on success.
# It mostly waits (an install, a 20-s run): scripts/test runs it beside the other stages and pytest; the install
# and the run hold the tests' machine lock shared, so the real-time tests that need the machine alone wait for them.
# scripts/test: background
set -uo pipefail
source "$(dirname "$0")/../lib.sh"
cd "$ROOT"
PORT=14550
SHARED_DIR="$(cd "$ROOT/.." && pwd)/shared"
[ -d "$SHARED_DIR" ] || { log "05-fresh-run: $SHARED_DIR is missing (the run reads ../shared beside the clone)"; exit 1; }
[ -x "$PY" ] || { log "05-fresh-run: $PY is missing (the listener needs pymavlink from $VENV)"; exit 1; }
command -v git >/dev/null || { log "05-fresh-run: git is missing"; exit 1; }
t0=$SECONDS
tmp=$(mktemp -d "${TMPDIR:-/tmp}/ins-hil-fresh.XXXXXX") || { log "05-fresh-run: mktemp failed"; exit 1; }
fail() { log "05-fresh-run: $* (folder kept: $tmp)"; [ -n "${gcs:-}" ] && kill "$gcs" 2>/dev/null; exit 1; }

git clone -q "$ROOT" "$tmp/main" >"$tmp/clone.log" 2>&1 || fail "git clone $ROOT failed: read $tmp/clone.log"
ln -s "$SHARED_DIR" "$tmp/shared"
log "05-fresh-run: fresh clone of $(git -C "$tmp/main" rev-parse --short HEAD) in $tmp/main (uncommitted changes are not in it)"

# the ground station: binds the port before the gateway starts; counts the HEARTBEATs sent from a socket of
# the gateway's process tree (other gateways on this machine may send to the same port)
"$PY" - "$PORT" "$tmp/run.pid" "$tmp/gcs.ready" >"$tmp/gcs.log" 2>&1 <<'PY' &
import os, socket, sys
from pymavlink.dialects.v20 import common as mavlink

port, pidfile, ready = int(sys.argv[1]), sys.argv[2], sys.argv[3]
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
try:
    s.bind(("127.0.0.1", port))
except OSError as e:
    print(f"PORT BUSY: cannot listen on UDP 127.0.0.1:{port} ({e}): another ground station or test holds it")
    sys.exit(3)
open(ready, "w").close()
s.settimeout(0.5)
mav = mavlink.MAVLink(None)
mav.robust_parsing = True


def inode_of(src_port):
    """The inode of the local UDP socket bound to 127.0.0.1/0.0.0.0:src_port (/proc/net/udp), or None."""
    for line in open("/proc/net/udp").read().splitlines()[1:]:
        f = line.split()
        if int(f[1].split(":")[1], 16) == src_port:
            return f[9]
    return None


def tree(pid):
    """pid and its descendants."""
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        out.add(p)
        try:
            for t in os.listdir(f"/proc/{p}/task"):
                todo += [int(c) for c in open(f"/proc/{p}/task/{t}/children").read().split()]
        except OSError:
            pass
    return out


def owned(pid, inode):
    for p in tree(pid):
        try:
            for fd in os.listdir(f"/proc/{p}/fd"):
                if os.readlink(f"/proc/{p}/fd/{fd}") == f"socket:[{inode}]":
                    return True
        except OSError:
            pass
    return False


ours, others, seen = 0, 0, {}
while not os.path.exists(pidfile + ".done"):
    try:
        data, (_, src) = s.recvfrom(65535)
    except TimeoutError:
        continue
    for m in mav.parse_buffer(data) or []:
        if m.get_type() != "HEARTBEAT" or m.get_srcSystem() != 42:
            continue
        if src not in seen and os.path.exists(pidfile):
            ino = inode_of(src)
            seen[src] = bool(ino) and owned(int(open(pidfile).read()), ino)
        if seen.get(src):
            ours += 1
            if ours == 1:
                print(f"first HEARTBEAT from the gateway: sysid 42, from udp port {src}", flush=True)
        else:
            others += 1
print(f"HEARTBEATS from the gateway: {ours}; from other processes: {others}")
PY
gcs=$!
for _ in $(seq 100); do [ -e "$tmp/gcs.ready" ] || ! kill -0 "$gcs" 2>/dev/null && break; sleep 0.1; done
if [ ! -e "$tmp/gcs.ready" ]; then
  grep -q "PORT BUSY" "$tmp/gcs.log" 2>/dev/null && fail "UDP 127.0.0.1:$PORT is busy (another ground station or test listens there): read $tmp/gcs.log"
  fail "the ground-station listener did not start: read $tmp/gcs.log"
fi

# the user's environment: no virtualenv of this checkout on PATH, nothing of it in the environment
path=""
IFS=: read -ra parts <<< "$PATH"
for p in "${parts[@]}"; do [ "$p" = "$VENV/bin" ] || path="${path:+$path:}$p"; done
log "05-fresh-run: scripts/run --duration 20 --no-status (new virtualenv $tmp/main/.venv; log: $tmp/run.log)"
# the install and the run hold the test run's machine lock shared (tests/conftest.py): a real-time test that needs
# the machine alone (machine_alone) waits for them as it waits for the other pytest worker's tests
lock=$("$PY" -c 'import os, tempfile; print(f"{tempfile.gettempdir()}/ins-hil-tests-{os.getuid()}.lock")')
hold=(); command -v flock >/dev/null && hold=(flock -s "$lock")
t1=$SECONDS
( cd "$tmp/main" && exec "${hold[@]}" env -u INS_HIL_VENV -u VIRTUAL_ENV -u PYTHONPATH -u PYTHONHOME PATH="$path" \
    timeout 1200 scripts/run --duration 20 --no-status ) >"$tmp/run.log" 2>&1 &
run=$!
echo "$run" > "$tmp/run.pid"
wait "$run"; rc=$?
run_s=$((SECONDS - t1))
sleep 0.6; touch "$tmp/run.pid.done"; wait "$gcs"
[ $rc -eq 0 ] || fail "scripts/run exited $rc after $run_s s$([ $rc -eq 124 ] && echo ' (timeout 1200 s)'): read $tmp/run.log"
hb=$(sed -n 's/^HEARTBEATS from the gateway: \([0-9]*\);.*/\1/p' "$tmp/gcs.log")
[ "${hb:-0}" -ge 1 ] || fail "no HEARTBEAT from the gateway on UDP 127.0.0.1:$PORT: read $tmp/gcs.log and $tmp/run.log"
rec=$(compgen -G "$tmp/main/recordings/*.ihlog" | head -1)
[ -n "$rec" ] && [ -s "$rec" ] || fail "no recording recordings/*.ihlog written in the clone: read $tmp/run.log"
log "05-fresh-run: exit 0 after $run_s s (install + 20 s run), $hb HEARTBEATs, recording $(basename "$rec") ($(stat -c %s "$rec") bytes); stage $((SECONDS - t0)) s"
rm -rf "$tmp"
