#!/usr/bin/env bash
# Type-check bipedtele as the installed package: `mypy -p bipedtele`, with every internal
# import resolved (issue 22). The repository keeps the product's folders (common/, leader/,
# follower/, configs/: pyproject's package-dir); the editable install maps them through an
# import hook that mypy cannot follow, so the package is laid out here as links, the way
# the wheel installs it, and mypy reads it from there. Exit status: mypy's.
set -uo pipefail
cd "$(dirname "$0")/.."
root=$PWD
stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
mkdir "$stage/bipedtele"
for entry in common/*; do
    case "$entry" in */__pycache__) continue ;; esac
    ln -s "$root/$entry" "$stage/bipedtele/"
done
for part in leader follower configs; do
    ln -s "$root/$part" "$stage/bipedtele/$part"
done
MYPYPATH="$stage" .venv/bin/mypy -p bipedtele "$@"
