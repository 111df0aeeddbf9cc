#!/usr/bin/env bash
# Speed-up of `mpirun -np 2` (one thread per rank) over one process with one thread, for
# `render`, `gonio simulate` and `delight` (docs/scale.md, docs/performance.md).
#
# Usage: bash bench/mpi_speedup.sh [PAIRS] [render|gonio|delight|all]
#   PAIRS (default 3): interleaved pairs per workload (one process, then -np 2, repeated).
#   OPAL_BIN: the binary (default target/release/opal, built with
#   `cargo build --release -p opal-cli --features mpi`; run without mpirun it is one process
#   and never initialises MPI, so both sides of a pair run the same code).
#   OPAL_SETSID=1: start the one process and each rank in its own session (`setsid -w`). On a
#   machine shared with other jobs, the kernel's autogroup scheduling gives all processes of one
#   session one CPU share, so without it a second rank in the same session gains nothing under
#   load; on a quiet machine leave it unset.
#
# Prints per pair: wall seconds and CPU seconds (user+sys of the process and its children, from
# /usr/bin/time; for mpirun the ranks are its children) of both runs, the ratio of wall times,
# and whether the outputs are the same bytes; then the median ratio per workload and the load
# average before and after. Needs openmpi-bin; runs as root with --allow-run-as-root.
set -euo pipefail
cd "$(dirname "$0")/.."
PAIRS=${1:-3}
WHICH=${2:-all}
BIN=${OPAL_BIN:-target/release/opal}
[ -x "$BIN" ] || { echo "no $BIN: cargo build --release -p opal-cli --features mpi" >&2; exit 1; }
command -v mpirun >/dev/null || { echo "mpirun not found (apt-get install openmpi-bin libopenmpi-dev)" >&2; exit 1; }
MPIRUN=(mpirun --allow-run-as-root --oversubscribe --bind-to none -np 2)
PRE=()
[ "${OPAL_SETSID:-0}" = 1 ] && PRE=(setsid -w)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
# the workloads (args_of), shared with the other MPI benchmark
source bench/mpi_workloads.sh

# runs "$@" under /usr/bin/time; prints "wall cpu"
timed() {
  /usr/bin/time -f "%e %U %S" -o "$TMP/time" "$@" >/dev/null 2>"$TMP/err" || { cat "$TMP/err" >&2; exit 1; }
  awk '{printf "%.2f %.2f\n", $1, $2 + $3}' "$TMP/time"
}

echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)  ($(nproc) cores)"
for w in render gonio delight; do
  [ "$WHICH" = all ] || [ "$WHICH" = "$w" ] || continue
  ratios=()
  for p in $(seq 1 "$PAIRS"); do
    rm -rf "$TMP/one" "$TMP/two" && mkdir -p "$TMP/one" "$TMP/two"
    read -r -a a1 <<<"$(args_of $w | sed "s#OUT#$TMP/one#g")"
    read -r -a a2 <<<"$(args_of $w | sed "s#OUT#$TMP/two#g")"
    read -r w1 c1 < <(timed "${PRE[@]}" "$BIN" "${a1[@]}")
    read -r w2 c2 < <(timed "${MPIRUN[@]}" "${PRE[@]}" "$BIN" "${a2[@]}")
    # report.json holds timings: compare every other file byte for byte
    same=yes
    while IFS= read -r f; do
      case "$f" in *report.json|*report.html) continue ;; esac
      cmp -s "$TMP/one/$f" "$TMP/two/$f" || { same="NO ($f)"; break; }
    done < <(cd "$TMP/one" && find . -type f | sort)
    r=$(awk -v a="$w1" -v b="$w2" 'BEGIN{printf "%.2f", a/b}')
    ratios+=("$r")
    printf "%-8s pair %d: one process %6.2f s (%6.2f CPU-s) | -np 2 %6.2f s (%6.2f CPU-s) | %sx | same bytes: %s | load %s\n" \
      "$w" "$p" "$w1" "$c1" "$w2" "$c2" "$r" "$same" "$(cut -d' ' -f1 /proc/loadavg)"
  done
  med=$(printf "%s\n" "${ratios[@]}" | sort -g | awk '{v[NR]=$1} END{print (NR%2) ? v[(NR+1)/2] : (v[NR/2]+v[NR/2+1])/2}')
  echo "$w: median speed-up ${med}x over $PAIRS pairs (${ratios[*]})"
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
