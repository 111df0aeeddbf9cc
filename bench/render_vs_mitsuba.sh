#!/usr/bin/env bash
# Times the same render with Opal and Mitsuba 3 in one run and prints samples/s and the ratio:
# Cornell box (tests/data/cbox, view 0) at 512x512, 64 spp, max depth 8, box filter.
# Each renderer: one warm-up render, then REPEATS timed renders; the median is reported.
# Mitsuba comes from PyPI (`mitsuba` in bench/.venv). The llvm_ad_rgb variant needs a libLLVM
# >= 16 (Debian: libllvm19); without it only scalar_rgb runs.
# Usage: bash bench/render_vs_mitsuba.sh [REPEATS]
set -euo pipefail
cd "$(dirname "$0")/.."
REPEATS="${1:-3}"
VENV=bench/.venv
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q mitsuba==3.9.1 drjit==1.5.0 numpy
fi
if ! ls /usr/lib/x86_64-linux-gnu/ 2>/dev/null | grep -Eq '^libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'; then
  (apt-get update -qq && apt-get install -y -q libllvm19 >/dev/null) || echo "warning: no libLLVM >= 16: llvm variants will fail" >&2
fi
cargo build --release -q -p opal-cli
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
cp -r crates/opal/tests/data/cbox "$WORK/cbox"
# 512x512 film for every sensor
sed -i 's/name="width" value="256"/name="width" value="512"/; s/name="height" value="256"/name="height" value="512"/' "$WORK/cbox/scene.xml"
OPAL=target/release/opal
"$OPAL" render "$WORK/cbox/scene.xml" -o "$WORK/warm.exr" --spp 64 --max-depth 8 --quiet >/dev/null 2>&1
opal_times=()
for i in $(seq "$REPEATS"); do
  t=$("$OPAL" render "$WORK/cbox/scene.xml" -o "$WORK/o.exr" --spp 64 --max-depth 8 --seed "$i" --json --quiet \
      | "$VENV/bin/python" -c 'import json,sys; print(json.load(sys.stdin)["seconds"])')
  opal_times+=("$t")
done
"$VENV/bin/python" - "$WORK/cbox/scene.xml" "$REPEATS" "${opal_times[@]}" <<'PY'
import statistics, subprocess, sys, json, time
scene, repeats, opal = sys.argv[1], int(sys.argv[2]), [float(x) for x in sys.argv[3:]]
samples = 512 * 512 * 64
child = r'''
import sys, time, statistics, json
import mitsuba as mi
mi.set_variant(sys.argv[1])
import drjit as dr, numpy as np
scene = mi.load_file(sys.argv[2])
integ = mi.load_dict({"type": "path", "max_depth": 8})
def one(seed):
    t0 = time.perf_counter()
    img = mi.render(scene, spp=64, seed=seed, integrator=integ, sensor=0)
    np.array(img); dr.sync_thread()
    return time.perf_counter() - t0
one(0)
print(json.dumps([one(s + 1) for s in range(int(sys.argv[3]))]))
'''
res = {"opal": statistics.median(opal)}
for v in ["llvm_ad_rgb", "scalar_rgb"]:
    try:
        out = subprocess.run([sys.executable, "-c", child, v, scene, str(repeats)], capture_output=True, text=True, timeout=3600)
        res["mitsuba_" + v] = statistics.median(json.loads(out.stdout.strip().splitlines()[-1]))
    except Exception as e:
        print(f"mitsuba {v}: failed ({e}; {out.stderr[-300:] if 'out' in dir() else ''})", file=sys.stderr)
print(f"Cornell box 512x512, 64 spp, max depth 8, medians of {repeats} runs")
for k, t in res.items():
    print(f"  {k:22s} {t:8.2f} s  {samples / t / 1e6:7.2f} M samples/s")
for k, t in res.items():
    if k != "opal":
        print(f"  ratio opal / {k}: {t / res['opal']:.2f}x")
PY
