#!/usr/bin/env bash
# Incoherent closest-hit rays, Opal vs Embree 3, on the same ray files in one run:
# the 1 M-triangle displaced sphere (2^20 rays) and the Cornell box (2^21 rays) of
# `crates/opal/examples/accel_compare.rs`. Opal's `accel_rays` example writes the files and
# times Opal's structure (rayon, THREADS threads); bench/embree/rays times Embree
# (RTC_BUILD_QUALITY_MEDIUM, rtcIntersect1 on THREADS pthreads). Each side: median build time
# of min(REPEATS, 5) builds, median rays/s of REPEATS timed passes after a warm-up pass, and
# the checksum (hit count, sum of hit t). Prints both and the ratio Opal / Embree, by wall time
# and per CPU-second of each process (the latter is robust to other jobs on a shared machine).
# Needs libembree-dev (Debian: apt-get install -y libembree-dev); Embree is only used here.
# Usage: bash bench/accel_vs_embree.sh [REPEATS=7] [THREADS=2]
set -euo pipefail
cd "$(dirname "$0")/.."
REPEATS="${1:-7}"
THREADS="${2:-2}"
if [ ! -e /usr/include/embree3/rtcore.h ]; then
  (apt-get update -qq && apt-get install -y -q libembree-dev >/dev/null) || { echo "needs libembree-dev" >&2; exit 1; }
fi
bash bench/embree/build.sh
cargo build --release -q -p opal --example accel_rays
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
# Per workload: Opal (writes the ray file), then Embree on that file, back to back.
for label in sphere1m cbox; do
  echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
  target/release/examples/accel_rays "$WORK" "$THREADS" "$REPEATS" "$label" | tee -a "$WORK/opal.txt"
  bench/embree/rays "$WORK/$label.rays" "$label" "$THREADS" "$REPEATS" | tee -a "$WORK/embree.txt"
done
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "$WORK/opal.txt" "$WORK/embree.txt" <<'PY'
import sys
res = {}
for f in sys.argv[1:]:
    for line in open(f):
        if line.startswith("RESULT "):
            _, who, label, *kv = line.split()
            res[(who, label)] = dict(x.split("=", 1) for x in kv)
for label in ["sphere1m", "cbox"]:
    o, e = res[("opal", label)], res[("embree", label)]
    r = lambda k: float(o[k]) / float(e[k])
    print(f"{label}: {o['tris']} triangles, {o['rays']} rays, {o['threads']} threads, medians of {o['repeats']}")
    print(f"  build            opal {float(o['build_ms']):9.3f} ms   embree {float(e['build_ms']):9.3f} ms")
    print(f"  closest hit      opal {float(o['mrays_s']):9.3f} M/s  embree {float(e['mrays_s']):9.3f} M/s  "
          f"opal/embree {r('mrays_s'):.2f}x   (wall)")
    print(f"  per CPU-second   opal {float(o['cpu_mrays_s']):9.3f} M    embree {float(e['cpu_mrays_s']):9.3f} M    "
          f"opal/embree {r('cpu_mrays_s'):.2f}x")
    print(f"  checksum         hits {o['hits']} / {e['hits']}, sum t {float(o['tsum']):.3f} / {float(e['tsum']):.3f}")
PY
