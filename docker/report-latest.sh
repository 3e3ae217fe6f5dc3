#!/bin/sh
# bipedtele-report-latest [FOLDER]: Table 2 of the newest leader recording in FOLDER
# (default /data/runs, the compose `runs` volume), also written next to it as
# <recording>.report.json. The compose `report` service runs it once the leader is done.
set -eu
dir=${1:-/data/runs}
latest=$(ls -t "$dir"/leader-*.mcap 2>/dev/null | head -n 1 || true)
if [ -z "$latest" ]; then
    echo "bipedtele-report-latest: no leader recording (leader-*.mcap) in $dir" >&2
    exit 1
fi
exec bipedtele report "$latest" --json "${latest%.mcap}.report.json"
