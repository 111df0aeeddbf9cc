#!/usr/bin/env bash
# Builds bench/embree/rays (Embree 3 closest-hit timing; see rays.c). Needs libembree-dev
# (Debian: apt-get install -y libembree-dev). Embree is never a dependency of Opal.
# Usage: bash bench/embree/build.sh   (writes bench/embree/rays)
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -e /usr/include/embree3/rtcore.h ]; then
  echo "building the Embree harness needs libembree-dev (apt-get install -y libembree-dev)" >&2
  exit 1
fi
cc -O2 -std=c11 -Wall -Wextra -o rays rays.c -lembree3 -lpthread -lm
