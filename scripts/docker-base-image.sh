#!/usr/bin/env bash
# Makes a Debian bookworm base image locally, for machines that reach Debian's package
# mirror but no image registry (an offline lab, this project's CI):
#   scripts/docker-base-image.sh [IMAGE]        default IMAGE: bipedtele-base:bookworm
# then build with:  docker build --build-arg BASE_IMAGE=IMAGE -f docker/Dockerfile .
# debootstrap (minbase) writes a root file system, `docker import` turns it into an image.
# Idempotent: does nothing when IMAGE exists. Needs root, debootstrap and a running engine.
# Mirror: $DEBIAN_MIRROR, else the first .../debian URI of this machine's apt sources,
# else http://deb.debian.org/debian.
set -euo pipefail

image=${1:-bipedtele-base:bookworm}
docker=${DOCKER:-docker}

if "$docker" image inspect "$image" >/dev/null 2>&1; then
    echo "docker-base-image: $image exists"
    exit 0
fi
command -v debootstrap >/dev/null 2>&1 || { echo "docker-base-image: debootstrap is missing (scripts/bootstrap.sh --test installs it)" >&2; exit 2; }
[[ $(id -u) -eq 0 ]] || { echo "docker-base-image: debootstrap needs root" >&2; exit 2; }

mirror=${DEBIAN_MIRROR:-}
if [[ -z $mirror ]]; then
    mirror=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.sources /etc/apt/sources.list.d/*.list 2>/dev/null \
        | grep -oE 'https?://[^ ]+/debian/?( |$)' | head -n 1 | tr -d ' ' || true)
fi
mirror=${mirror:-http://deb.debian.org/debian}

root=$(mktemp -d /tmp/bipedtele-rootfs.XXXXXX)
trap 'rm -rf "$root"' EXIT
echo "docker-base-image: debootstrap bookworm from $mirror"
debootstrap --variant=minbase bookworm "$root" "$mirror" >"$root.log" 2>&1 \
    || { tail -n 20 "$root.log" >&2; rm -f "$root.log"; exit 1; }
rm -f "$root.log"
# Like the official slim image: no apt lists, caches or docs in the layer.
rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/*.bin "$root"/var/cache/apt/archives/*.deb \
       "$root"/usr/share/doc/* "$root"/usr/share/man/*
tar -C "$root" -c . | "$docker" import \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'CMD ["bash"]' - "$image" >/dev/null
echo "docker-base-image: made $image"
