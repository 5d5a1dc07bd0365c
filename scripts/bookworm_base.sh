#!/bin/sh
# A Debian bookworm base image as a root file system tarball, made from
# Debian's packages (mmdebstrap, minbase variant) where no image registry is
# reachable; `podman import OUT.tar localhost/d3il-base:bookworm` then gives
# the BASE of docs/cluster/Containerfile (docs/ops.md, Container image).
# tests/container_image.rs caches OUT under ~/.cache/d3il/images, keyed by this
# file's sha256: change the suite, mirrors or packages here and it is made anew.
#   usage: scripts/bookworm_base.sh OUT.tar
set -eu
[ $# -eq 1 ] || { echo "usage: $0 OUT.tar (a root file system tarball of Debian bookworm)" >&2; exit 2; }
command -v mmdebstrap >/dev/null || { echo "$0 needs mmdebstrap (apt-get install mmdebstrap; ./dev test installs it)" >&2; exit 1; }
exec mmdebstrap --quiet --format=tar --variant=minbase --include=ca-certificates bookworm "$1" \
  "deb http://deb.debian.org/debian bookworm main" \
  "deb http://deb.debian.org/debian bookworm-updates main" \
  "deb http://deb.debian.org/debian-security bookworm-security main"
