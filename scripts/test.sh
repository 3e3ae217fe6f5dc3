#!/usr/bin/env bash
# The README's test command: installs what the tests need, then runs the whole suite
# (unit, integration, slow and e2e tests), then ruff (lint and format) and scripts/typecheck.sh (mypy -p bipedtele).
set -uo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test || exit $?
.venv/bin/python -m pytest --durations=40 "$@"  # the 40 slowest tests are listed (suite budget: under 30 min)
rc=$?
if [[ $rc -eq 5 ]]; then
    echo "test.sh: pytest collected no tests: that is a failure" >&2
    exit 1
fi
[[ $rc -ne 0 ]] && exit $rc
.venv/bin/ruff check common leader follower tests bench || exit 1
.venv/bin/ruff format --check common leader follower configs docker tests bench || exit 1
scripts/typecheck.sh || exit 1  # mypy -p bipedtele, the package as installed
