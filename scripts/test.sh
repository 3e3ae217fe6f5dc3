#!/usr/bin/env bash
# The README's test command: installs what the tests need, then runs the whole suite
# (unit, integration, slow and e2e tests), then ruff (lint and format) and scripts/typecheck.sh (mypy -p bipedtele).
#
# With arguments, they go to one pytest run as they are. Without, the suite runs in two
# steps so that it fits its budget (under 30 min on 2 cores): first the end-to-end and
# integration tests (they keep time), then the unit tests (two pytest runs side by side, every
# other file each); the CPU-bound deterministic tests
# (marker `compute`: simulated time, no timing) run from the start in a second pytest at the
# lowest CPU and I/O priority beside them. Each step lists its slowest tests. pytest's exit code 5
# (no tests collected) is a failure. The compute step also builds the documentation site
# strict (tests/unit/test_docs_site.py) and runs the operator's side on a second Python
# (tests/unit/test_python_versions.py: one skip line where none is found; in CI a failure).
set -uo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test || exit $?

check_rc() {  # $1: pytest's exit code, $2: what ran
    if [[ $1 -eq 5 ]]; then
        echo "test.sh: pytest collected no tests ($2): that is a failure" >&2
        return 1
    fi
    return "$1"
}

if [[ $# -gt 0 ]]; then
    .venv/bin/python -m pytest --durations=40 "$@"
    check_rc $? "$*" || exit $?
else
    start=$(date +%s)
    log=$(mktemp)
    # The CPU-bound deterministic tests take what the timed ones leave: lowest CPU and I/O
    # priority, so a timed process (nice 0) gets its core whenever it wants it.
    nice -n 19 ionice -c 3 .venv/bin/python -m pytest --durations=10 -m compute -p no:cacheprovider \
        tests/unit tests/integration >"$log" 2>&1 &
    compute=$!
    .venv/bin/python -m pytest --durations=25 -m "not compute" tests/e2e tests/integration
    e2e_rc=$?
    if [[ $e2e_rc -ne 0 && $e2e_rc -ne 5 ]]; then kill "$compute" 2>/dev/null; fi
    check_rc $e2e_rc "e2e and integration" || { wait "$compute"; cat "$log"; rm -f "$log"; exit 1; }
    # the unit tests in two halves side by side (every other file): one per core
    mapfile -t units < <(find tests/unit -name "test_*.py" | sort)
    half=()
    for i in "${!units[@]}"; do (( i % 2 )) && half+=("${units[i]}"); done
    others=()
    for i in "${!units[@]}"; do (( i % 2 )) || others+=("${units[i]}"); done
    unit_log=$(mktemp)
    .venv/bin/python -m pytest --durations=10 -m "not compute" -p no:cacheprovider "${half[@]}" >"$unit_log" 2>&1 &
    unit_half=$!
    .venv/bin/python -m pytest --durations=10 -m "not compute" "${others[@]}"
    rc=$?
    wait "$unit_half"
    half_rc=$?
    echo "---- the other half of the unit tests, run beside:"
    cat "$unit_log"
    rm -f "$unit_log"
    wait "$compute"
    compute_rc=$?
    echo "---- the tests marked compute, run beside the e2e and unit tests:"
    cat "$log"
    rm -f "$log"
    check_rc $rc "unit" || exit $?
    check_rc $half_rc "unit, the other half" || exit $?
    check_rc $compute_rc "unit, compute" || exit $?
    echo "test.sh: pytest took $(( $(date +%s) - start )) s in all (budget: under 1800 s)"
fi
.venv/bin/ruff check common leader follower studies tests bench docs/hooks || exit 1
.venv/bin/ruff format --check common leader follower studies configs docker tests bench docs/hooks || exit 1
scripts/typecheck.sh || exit 1  # mypy -p bipedtele, the package as installed
