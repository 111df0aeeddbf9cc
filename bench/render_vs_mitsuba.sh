#!/usr/bin/env bash
# Times the same render with Opal and Mitsuba 3 in one run and prints samples/s and the ratio.
# Scenes (second argument):
#   cbox  Cornell box (tests/data/cbox, view 0) at 512x512, 64 spp, max depth 8 (default)
#   scan  scanned-object room: the Cornell box with the tall box replaced by an 81 920-triangle
#         displaced, textured icosphere (written by the opal example `make_scan_room` into a
#         temp dir), view 0 at 256x256, 64 spp, max depth 16
#   both  cbox then scan
# Box filter. Each renderer: one warm-up render, then REPEATS timed renders, Opal's and Mitsuba
# llvm_ad_rgb's alternating (pairs in the same minutes); the medians of the wall time and of the
# CPU time are reported, and the median of the pairs' ratios (on a shared machine the per-CPU-s ratio is the
# steadier one: another tenant takes cores from one side but not the other). Mitsuba comes from PyPI (`mitsuba` in bench/.venv). The llvm_ad_rgb variant needs a
# libLLVM >= 16 (Debian: libllvm19); without it only scalar_rgb runs.
# Usage: bash bench/render_vs_mitsuba.sh [REPEATS=3] [cbox|scan|both]
set -euo pipefail
cd "$(dirname "$0")/.."
REPEATS="${1:-3}"
SCENES="${2:-cbox}"
case "$SCENES" in cbox|scan) ;; both) SCENES="cbox scan" ;; *) echo "scene must be cbox, scan or both" >&2; exit 2 ;; esac
VENV=bench/.venv
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q mitsuba==3.9.1 drjit==1.5.0 numpy
fi
if ! ls /usr/lib/x86_64-linux-gnu/ 2>/dev/null | grep -Eq '^libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'; then
  (apt-get update -qq && apt-get install -y -q libllvm19 >/dev/null) || echo "warning: no libLLVM >= 16: llvm variants will fail" >&2
fi
# OPAL_PROFILE=dev reuses the test build (opt-level 3 too, with debug assertions)
PROFILE="${OPAL_PROFILE:-release}"
if [ "$PROFILE" = release ]; then cargo build --release -q -p opal-cli; OPAL=target/release/opal
else cargo build -q -p opal-cli; OPAL=target/debug/opal; fi
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

# bench_scene LABEL SCENE_XML WIDTH HEIGHT SPP MAX_DEPTH
bench_scene() {
  local label=$1 scene=$2 w=$3 h=$4 spp=$5 depth=$6
  echo "== $label: load average before $(cut -d' ' -f1-3 /proc/loadavg)"
  "$OPAL" render "$scene" -o "$WORK/warm.exr" --spp "$spp" --max-depth "$depth" --quiet >/dev/null 2>&1
  "$VENV/bin/python" - "$label" "$scene" "$w" "$h" "$spp" "$depth" "$REPEATS" "$OPAL" "$WORK" <<'PY'
import statistics, subprocess, sys, json, resource
label, scene = sys.argv[1], sys.argv[2]
w, h, spp, depth, repeats = (int(x) for x in sys.argv[3:8])
opal_bin, work = sys.argv[8], sys.argv[9]
samples = w * h * spp
def children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime
# Opal: wall = the render's own "seconds"; CPU = the whole process (load and BVH build included)
def run_opal(i):
    c0 = children_cpu()
    out = subprocess.run([opal_bin, "render", scene, "-o", f"{work}/o.exr", "--spp", str(spp), "--max-depth",
                          str(depth), "--seed", str(i + 1), "--json", "--quiet"], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)["seconds"], children_cpu() - c0
# Mitsuba: a child process that loads the scene, renders once untimed (JIT warm-up), then renders
# once per line read from stdin and prints (wall, CPU) of the render call
child = r"""
import sys, time, json, resource
import mitsuba as mi
mi.set_variant(sys.argv[1])
import drjit as dr, numpy as np
scene = mi.load_file(sys.argv[2])
spp = int(sys.argv[3])
integ = mi.load_dict({"type": "path", "max_depth": int(sys.argv[4])})
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
def one(seed):
    t0, c0 = time.perf_counter(), cpu()
    img = mi.render(scene, spp=spp, seed=seed, integrator=integ, sensor=0)
    np.array(img); dr.sync_thread()
    return time.perf_counter() - t0, cpu() - c0
one(0)
print("ready", flush=True)
for line in sys.stdin:
    print(json.dumps(one(int(line))), flush=True)
"""
def mitsuba(variant):
    p = subprocess.Popen([sys.executable, "-c", child, variant, scene, str(spp), str(depth)],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while True:
        line = p.stdout.readline()
        if not line:
            raise RuntimeError(p.stderr.read()[-300:])
        if line.strip() == "ready":
            return p
def ask(p, seed):
    p.stdin.write(f"{seed}\n"); p.stdin.flush()
    return tuple(json.loads(p.stdout.readline()))
# llvm_ad_rgb interleaved with Opal run by run (the pairs share the same minutes of the shared
# machine); scalar_rgb after, as a second reference
res, pairs = {}, []
opal, mits = [], []
try:
    p = mitsuba("llvm_ad_rgb")
    for i in range(repeats):
        opal.append(run_opal(i))
        mits.append(ask(p, i + 1))
        pairs.append((mits[-1][0] / opal[-1][0], mits[-1][1] / opal[-1][1]))
    p.stdin.close(); p.wait()
except Exception as e:
    print(f"mitsuba llvm_ad_rgb: failed ({e})", file=sys.stderr)
    opal = opal or [run_opal(i) for i in range(repeats)]
res["opal"] = (statistics.median(r[0] for r in opal), statistics.median(r[1] for r in opal))
if mits:
    res["mitsuba_llvm_ad_rgb"] = (statistics.median(r[0] for r in mits), statistics.median(r[1] for r in mits))
try:
    p = mitsuba("scalar_rgb")
    runs = [ask(p, i + 1) for i in range(repeats)]
    p.stdin.close(); p.wait()
    res["mitsuba_scalar_rgb"] = (statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs))
except Exception as e:
    print(f"mitsuba scalar_rgb: failed ({e})", file=sys.stderr)
print(f"{label} {w}x{h}, {spp} spp, max depth {depth}, medians of {repeats} runs")
print("  (CPU-s: Opal's whole process incl. scene load and BVH build; Mitsuba's render call)")
for k, (t, c) in res.items():
    print(f"  {k:22s} {t:8.2f} s wall {samples / t / 1e6:7.2f} M samples/s   {c:8.2f} CPU-s {samples / c / 1e6:7.2f} M samples/CPU-s")
for k, (t, c) in res.items():
    if k != "opal":
        print(f"  ratio opal / {k}: {t / res['opal'][0]:.2f}x wall, {c / res['opal'][1]:.2f}x per CPU-s (ratio of medians)")
if pairs:
    print("  interleaved pairs, ratio per CPU-s: " + " ".join(f"{c:.2f}" for _, c in pairs)
          + f"; median {statistics.median(c for _, c in pairs):.2f}x (wall: median {statistics.median(w for w, _ in pairs):.2f}x)")
PY
  echo "== $label: load average after $(cut -d' ' -f1-3 /proc/loadavg)"
}

for sc in $SCENES; do
  case "$sc" in
    cbox)
      cp -r crates/opal/tests/data/cbox "$WORK/cbox"
      # 512x512 film for every sensor
      sed -i 's/name="width" value="256"/name="width" value="512"/; s/name="height" value="256"/name="height" value="512"/' "$WORK/cbox/scene.xml"
      bench_scene "Cornell box" "$WORK/cbox/scene.xml" 512 512 64 8 ;;
    scan)
      cargo run --release -q -p opal --example make_scan_room -- "$WORK/scan" >/dev/null
      bench_scene "Scanned-object room" "$WORK/scan/scene.xml" 256 256 64 16 ;;
  esac
done
