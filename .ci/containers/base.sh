#!/usr/bin/env bash
# The stand-in for the `python:3.11-slim-bookworm` image, for machines that cannot pull images
# (no container registry reachable): Debian bookworm made with debootstrap from the archive apt is
# configured with, Python 3.11 with pip and venv, `python` and `pip` on the PATH as in the real
# image, imported into podman under the real image's name so the project's Dockerfiles build
# unchanged. Not the real image: Debian's Python 3.11.2 and pip 23.0.1 instead of python.org's
# latest 3.11 built from source; the machine's CA bundle is copied in so pip reaches PyPI through
# this machine's TLS setup.
#
# The root file system is kept as a tarball in the cache folder ($1), so a new podman storage only
# re-imports it (seconds) and debootstrap (minutes) runs once per machine.
set -euo pipefail
cache="${1:?usage: base.sh CACHE_DIR}"
image=localhost/python:3.11-slim-bookworm
tarball="$cache/debian-bookworm-python3.11.tar"

if [ ! -s "$tarball" ]; then
  mirror="$(awk '/^URIs:/ {print $2; exit} /^deb / {print $2; exit}' \
    /etc/apt/sources.list.d/debian.sources /etc/apt/sources.list 2>/dev/null || true)"
  rootfs="$(mktemp -d "$cache/rootfs.XXXXXX")"
  trap 'rm -rf "$rootfs"' EXIT
  echo "base.sh: debootstrap bookworm from ${mirror:-http://deb.debian.org/debian}"
  debootstrap --variant=minbase --include=python3,python3-pip,python3-venv,python-is-python3,ca-certificates \
    bookworm "$rootfs" "${mirror:-http://deb.debian.org/debian}" >"$cache/debootstrap.log" 2>&1 \
    || { tail -20 "$cache/debootstrap.log" >&2; exit 1; }
  # pip installs into the system Python, as in the real image (whose Python is not Debian's).
  rm -f "$rootfs"/usr/lib/python3.*/EXTERNALLY-MANAGED
  cp /etc/ssl/certs/ca-certificates.crt "$rootfs/etc/ssl/certs/ca-certificates.crt"
  # apt's downloads and lists, like the slim image (a Dockerfile that needs apt runs apt-get update).
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/lib/apt/lists/*
  tar -C "$rootfs" -cf "$tarball.part" . && mv "$tarball.part" "$tarball"
fi

if ! podman image exists "$image"; then
  # PIP_CERT: the venvs some Dockerfiles make get pip from ensurepip, which reads certifi's bundle.
  podman import --quiet --change 'ENV LANG=C.UTF-8' --change 'ENV PIP_CERT=/etc/ssl/certs/ca-certificates.crt' \
    --change 'CMD ["python3"]' "$tarball" "$image" >/dev/null
fi
echo "base.sh: $image ($(podman image inspect -f '{{.Size}}' "$image" | numfmt --to=iec-i --suffix=B)) from $tarball"
