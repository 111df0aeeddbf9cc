#!/usr/bin/env bash
# Per-rank CPU seconds of `mpirun -np 2` (one thread per rank) against one process with one
# thread, for `render`, `gonio simulate` and `delight` (the workloads of bench/mpi_speedup.sh):
# a speed-up estimate that a loaded machine does not spoil as much as wall times do.
#
# Usage: bash bench/mpi_rank_cpu.sh [render|gonio|delight|all]
#   OPAL_BIN: the binary (default target/release/opal, built with --features mpi).
#
# Prints per workload: the one process's wall and CPU-s (user+sys from /usr/bin/time), each
# rank's wall and CPU-s (every rank runs under its own /usr/bin/time), the estimate
# T1 / max rank CPU-s, whether the outputs are the same bytes, and the load average. The
# estimate is the speed-up on two idle cores when the ranks' CPU-s are work: Open MPI polls while
# a rank waits in a collective, so on an idle machine waiting is counted as CPU-s too (the
# estimate then stays honest); on a loaded machine a waiting rank yields, its polling counts less
# and the estimate is an upper bound. For delight the communication seconds per pass
# (report.json, rank 0) are printed too.
set -euo pipefail
cd "$(dirname "$0")/.."
WHICH=${1:-all}
BIN=$(realpath "${OPAL_BIN:-target/release/opal}")
[ -x "$BIN" ] || { echo "no $BIN: cargo build --release -p opal-cli --features mpi" >&2; exit 1; }
command -v mpirun >/dev/null || { echo "mpirun not found" >&2; exit 1; }
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
# the workloads (args_of), shared with the other MPI benchmark
source bench/mpi_workloads.sh
cpu() { awk '{printf "%.2f %.2f\n", $1, $2 + $3}' "$1"; }
for w in render gonio delight; do
  [ "$WHICH" = all ] || [ "$WHICH" = "$w" ] || continue
  rm -rf "$TMP/one" "$TMP/two" && mkdir -p "$TMP/one" "$TMP/two"
  read -r -a a1 <<<"$(args_of $w | sed "s#OUT#$TMP/one#g")"
  read -r -a a2 <<<"$(args_of $w | sed "s#OUT#$TMP/two#g")"
  l0=$(cut -d' ' -f1 /proc/loadavg)
  /usr/bin/time -f "%e %U %S" -o "$TMP/t1" "$BIN" "${a1[@]}" >/dev/null
  mpirun --allow-run-as-root --oversubscribe --bind-to none -np 2 \
    sh -c '/usr/bin/time -f "%e %U %S" -o "$0.$OMPI_COMM_WORLD_RANK" "$@"' "$TMP/tr" "$BIN" "${a2[@]}" >/dev/null
  read -r w1 c1 < <(cpu "$TMP/t1")
  read -r wr0 cr0 < <(cpu "$TMP/tr.0")
  read -r wr1 cr1 < <(cpu "$TMP/tr.1")
  same=yes
  while IFS= read -r f; do
    case "$f" in *report.json|*report.html) continue ;; esac
    cmp -s "$TMP/one/$f" "$TMP/two/$f" || { same="NO ($f)"; break; }
  done < <(cd "$TMP/one" && find . -type f | sort)
  est=$(awk -v a="$c1" -v b="$cr0" -v c="$cr1" 'BEGIN{m = b > c ? b : c; printf "%.2f", a / m}')
  extra=$(awk -v a="$c1" -v b="$cr0" -v c="$cr1" 'BEGIN{printf "%+.0f", 100 * ((b + c) / a - 1)}')
  printf "%-8s one process %6.2f s %6.2f CPU-s | rank 0 %6.2f s %6.2f CPU-s | rank 1 %6.2f s %6.2f CPU-s | ranks' CPU %s %% | estimate T1/max %sx | same bytes: %s | load %s → %s\n" \
    "$w" "$w1" "$c1" "$wr0" "$cr0" "$wr1" "$cr1" "$extra" "$est" "$same" "$l0" "$(cut -d' ' -f1 /proc/loadavg)"
  if [ "$w" = delight ] && command -v python3 >/dev/null; then
    python3 - "$TMP/one/d/report.json" "$TMP/two/d/report.json" <<'PY' || true
import json, sys
for name, p in zip(("one process", "-np 2 rank 0"), sys.argv[1:]):
    r = json.load(open(p))
    w, c = r.get("timings_seconds", {}), r.get("cpu_seconds", {})
    stages = " ".join(f"{k} {w[k]:.2f}/{c.get(k, float('nan')):.2f}" for k in w)
    comm = [i.get("comm_seconds") for i in r.get("iterations", [])]
    print(f"  {name}: stage wall/CPU-s {stages}; comm_seconds per pass {comm}")
PY
  fi
done
