#!/usr/bin/env bash
# Make the key of end-to-end message authentication (network.message_key_file).
#
#   make-message-key.sh FILE
#
# Writes 32 random bytes as 64 hex characters to FILE (a new file, mode 0600). Copy the
# same file to the robot host and the operator host (keeping its mode: scp -p); never to
# the router. `bipedtele setup message-key FILE` does the same from an installed package.
set -euo pipefail
if [[ $# -ne 1 ]]; then
    echo "usage: make-message-key.sh FILE" >&2
    exit 2
fi
file=$1
command -v openssl >/dev/null || { echo "make-message-key: openssl is required (apt-get install openssl)" >&2; exit 2; }
if [[ -e $file ]]; then
    echo "make-message-key: $file exists; allowed: a new file (a key is never overwritten)" >&2
    exit 2
fi
umask 077
mkdir -p "$(dirname "$file")"
( set -o noclobber; openssl rand -hex 32 > "$file" )
chmod 600 "$file"
echo "make-message-key: wrote $file (mode 0600): copy it to the robot and operator hosts only"
