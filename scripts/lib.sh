# Shared helpers for scripts/*: sourced, not run.
# ROOT: the repository; VENV: its virtualenv; PY: the venv's python.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${INS_HIL_VENV:-$ROOT/.venv}"
PY="$VENV/bin/python"

log() { printf '\033[1m[ins-hil]\033[0m %s\n' "$*" >&2; }

# ensure_apt PKG...: install missing Debian packages (apt-get update once per run).
ensure_apt() {
  local missing=()
  for p in "$@"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  [ ${#missing[@]} -eq 0 ] && return 0
  local SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null 2>&1 || { log "need Debian packages: ${missing[*]} (run as root or install them)"; return 1; }
    SUDO="sudo"
  fi
  if [ -z "${_INS_HIL_APT_UPDATED:-}" ]; then
    log "apt-get update"
    $SUDO apt-get update -qq >/dev/null || { log "apt-get update failed"; return 1; }
    export _INS_HIL_APT_UPDATED=1
  fi
  log "installing Debian packages: ${missing[*]}"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
    || { log "apt-get install ${missing[*]} failed"; return 1; }
}

# ensure_venv: create .venv and (re)install the package with its dev extras
# whenever pyproject.toml / setup.py / the C sources change. A venv whose
# python does not run (an interrupted creation) is made anew; an install that
# failed or was interrupted leaves no stamp, so the next call installs again.
# Every failure prints one line naming what failed and the log to read.
ensure_venv() {
  local py=${PYTHON:-python3}
  if ! "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    log "Python >= 3.11 is required (found: $("$py" --version 2>&1))"; return 1
  fi
  if [ -e "$VENV" ] && ! "$PY" -c 'import pip' >/dev/null 2>&1; then
    log "virtualenv $VENV is incomplete (an interrupted creation): making it anew"
    rm -rf "$VENV"
  fi
  if [ ! -x "$PY" ]; then
    log "creating virtualenv $VENV"
    "$py" -m venv "$VENV" >/dev/null 2>&1 || { ensure_apt python3-venv && rm -rf "$VENV" && "$py" -m venv "$VENV"; } \
      || { log "could not create the virtualenv $VENV with $py"; return 1; }
  fi
  local stamp="$VENV/.ins_hil_stamp" want
  want=$(cat "$ROOT/pyproject.toml" "$ROOT"/setup.py "$ROOT"/firmware_ref/cffi_build.py "$ROOT"/firmware_ref/src/*.[ch] "$ROOT"/firmware_ref/src/generated/*.h "$ROOT"/firmware_ref/include/*.h 2>/dev/null | sha256sum | cut -c1-16)
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    rm -f "$stamp"
    local plog="$VENV/pip-install.log"
    log "installing ins_hil and its dependencies into $VENV (a few minutes the first time; log: $plog)"
    if ! "$PY" -m pip install -q --disable-pip-version-check -e "$ROOT[dev]" >"$plog" 2>&1; then
      log "pip install failed: read $plog (the next run installs again)"; return 1
    fi
    echo "$want" > "$stamp"
  fi
}
