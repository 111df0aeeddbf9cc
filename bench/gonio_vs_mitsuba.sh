#!/usr/bin/env bash
# Times the same goniophotometer work with Opal (release build) and with the Mitsuba 3 reference
# simulator (<shared>/reference/mitsuba/scripts/gonio_plate.py, imported as a module: its
# simulate() loop, without its validation and plotting) in one run, and prints photons/s, photons
# per CPU-second and the Opal/Mitsuba ratios (medians of REPEATS runs each).
# Work per measurement: one plate (rough face CASE, ENTRY face lit), incidences 0–75° every 15°,
# PHOTONS photons per incidence, 0.5° beam divergence, 179 + 179 detectors of 1°, n = 1.49,
# single scattering with Mitsuba's G1 (`--scattering single-mitsuba`).
# The machine may be shared: the load average before and after is printed, and the per-CPU-second
# rates (user + sys of the whole process, all threads) are the robust comparison.
# Usage: bash bench/gonio_vs_mitsuba.sh [PHOTONS] [REPEATS]
#   env: CASES="ggx:0.15 ggx:0.35 beckmann:0.25", ENTRIES="smooth rough",
#        SHARED=<shared dir> (default ../shared), VENV (default bench/.venv),
#        OPAL_PROFILE=dev to reuse the test build (opt-level 3 with debug assertions).
set -euo pipefail
cd "$(dirname "$0")/.."
PHOTONS="${1:-1000000}"
REPEATS="${2:-3}"
CASES="${CASES:-ggx:0.15 ggx:0.35 beckmann:0.25}"
ENTRIES="${ENTRIES:-smooth rough}"
SHARED="${SHARED:-../shared}"
SCRIPTS="$SHARED/reference/mitsuba/scripts"
VENV="${VENV:-bench/.venv}"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q mitsuba==3.9.1 drjit==1.5.0 numpy
fi
# the llvm_ad_rgb variant (as for the reference data) needs a libLLVM >= 16 (Debian: libllvm19)
if ! ls /usr/lib/x86_64-linux-gnu/ 2>/dev/null | grep -Eq '^libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])'; then
  (apt-get update -qq && apt-get install -y -q libllvm19 >/dev/null) || echo "warning: no libLLVM >= 16: Mitsuba falls back to scalar_rgb" >&2
fi
[ -f "$SCRIPTS/gonio_plate.py" ] || { echo "no $SCRIPTS/gonio_plate.py (set SHARED)" >&2; exit 1; }
PROFILE="${OPAL_PROFILE:-release}"
if [ "$PROFILE" = release ]; then cargo build --release -q -p opal-cli; OPAL=target/release/opal
else cargo build -q -p opal-cli; OPAL=target/debug/opal; fi
"$VENV/bin/python" - "$OPAL" "$SCRIPTS" "$PHOTONS" "$REPEATS" "$CASES" "$ENTRIES" <<'PY'
import json, os, resource, statistics, subprocess, sys, tempfile, time
opal, scripts, n, repeats, cases, entries = sys.argv[1], sys.argv[2], int(float(sys.argv[3])), int(sys.argv[4]), sys.argv[5].split(), sys.argv[6].split()
inc = [0, 15, 30, 45, 60, 75]
total = n * len(inc)
child = r'''
import json, sys, time
sys.path.insert(0, sys.argv[1])
import common, gonio_plate as gp
print(common.set_variant(["llvm_ad_rgb", "scalar_rgb"]), file=sys.stderr)
import numpy as np
dist, alpha = sys.argv[2].split(":")
entry, n, repeats = sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
rough = gp.RoughFace(dist, float(alpha))
rng = np.random.default_rng(12345)
gp.simulate(45.0, 200000, entry, rough, 0.5, rng, gp.Tally())  # warm-up: JIT compilation
out = []
for _ in range(repeats):
    t0, c0 = time.perf_counter(), time.process_time()
    for th in [0, 15, 30, 45, 60, 75]:
        tally, done = gp.Tally(), 0
        while done < n:
            m = min(2000000, n - done)
            gp.simulate(float(th), m, entry, rough, 0.5, rng, tally)
            done += m
    out.append((time.perf_counter() - t0, time.process_time() - c0))
print(json.dumps(out))
'''
load0 = os.getloadavg()
print(f"load average before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f} ({os.cpu_count()} CPUs)")
print(f"{total/1e6:g} M photons per run ({n} per incidence x 6), {repeats} repeats, medians; "
      "rates in M photons/s (wall) and M photons per CPU-second")
hdr = f"{'case':<15} {'entry':<6} | {'opal wall':>9} {'opal cpu':>9} | {'mts wall':>9} {'mts cpu':>9} | {'ratio wall':>10} {'ratio cpu':>9}"
print(hdr)
print("-" * len(hdr))
rows = []
with tempfile.TemporaryDirectory() as tmp:
    for case in cases:
        for entry in entries:
            ow, oc = [], []
            for r in range(repeats):
                ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                subprocess.run([opal, "gonio", "simulate", "-o", os.path.join(tmp, "o.csv"), "--photons", str(n),
                                "--ndf", case, "--entry", entry, "--scattering", "single-mitsuba",
                                "--seed", str(r + 1), "--quiet"], check=True, stdout=subprocess.DEVNULL)
                ow.append(time.perf_counter() - t0)
                ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                oc.append(ru1.ru_utime - ru0.ru_utime + ru1.ru_stime - ru0.ru_stime)
            p = subprocess.run([sys.executable, "-c", child, scripts, case, entry, str(n), str(repeats)],
                               capture_output=True, text=True)
            if p.returncode != 0:
                print(p.stderr[-2000:], file=sys.stderr)
                sys.exit(1)
            m = json.loads(p.stdout.strip().splitlines()[-1])
            mw, mc = [x[0] for x in m], [x[1] for x in m]
            r = dict(case=case, entry=entry, opal_wall=total / statistics.median(ow) / 1e6,
                     opal_cpu=total / statistics.median(oc) / 1e6, mts_wall=total / statistics.median(mw) / 1e6,
                     mts_cpu=total / statistics.median(mc) / 1e6)
            r["ratio_wall"], r["ratio_cpu"] = r["opal_wall"] / r["mts_wall"], r["opal_cpu"] / r["mts_cpu"]
            rows.append(r)
            print(f"{case:<15} {entry:<6} | {r['opal_wall']:9.2f} {r['opal_cpu']:9.2f} | {r['mts_wall']:9.2f} "
                  f"{r['mts_cpu']:9.2f} | {r['ratio_wall']:9.1f}x {r['ratio_cpu']:8.1f}x", flush=True)
load1 = os.getloadavg()
print(f"load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
print(json.dumps(dict(photons_per_incidence=n, repeats=repeats, load_before=load0, load_after=load1, rows=rows)))
PY
