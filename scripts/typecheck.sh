#!/usr/bin/env bash
# Type-check bipedtele as the installed package: `mypy -p bipedtele`, every internal import
# resolved (a missing one is an error, not Any; pyproject.toml lists the few third-party
# packages without types). The repository keeps the product's folders (common/, leader/,
# follower/, configs/: pyproject's package-dir); the editable install maps them through an
# import hook that mypy cannot follow, so the package is laid out here as links, the way the
# wheel installs it, and mypy reads it from there; its messages name the repository's files.
# TYPECHECK_PLANT=FILE adds FILE as the module bipedtele._planted, TYPECHECK_STAGE=DIR lays the
# package out there (tests/unit/test_checks.py plants errors to show that this check fails on
# them). Exit status: mypy's.
set -uo pipefail
cd "$(dirname "$0")/.."
root=$PWD
# a fixed place, so that mypy's cache (keyed by path) serves the next run
stage=${TYPECHECK_STAGE:-$root/.mypy_cache/stage}
rm -rf "$stage"
mkdir -p "$stage/bipedtele"
for entry in common/*; do
    case "$entry" in */__pycache__) continue ;; esac
    ln -s "$root/$entry" "$stage/bipedtele/"
done
for part in leader follower configs studies; do
    ln -s "$root/$part" "$stage/bipedtele/$part"
done
if [[ -n "${TYPECHECK_PLANT:-}" ]]; then
    cp "$TYPECHECK_PLANT" "$stage/bipedtele/_planted.py"
fi
rel=${stage#"$root"/}  # mypy names files under the working folder relative to it
MYPYPATH="$stage" .venv/bin/mypy -p bipedtele "$@" 2>&1 |
    sed -e "s#^\($stage\|$rel\)/bipedtele/\(leader\|follower\|configs\|studies\)/#\2/#" \
        -e "s#^\($stage\|$rel\)/bipedtele/#common/#"
exit "${PIPESTATUS[0]}"
