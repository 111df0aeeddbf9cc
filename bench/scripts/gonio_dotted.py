#!/usr/bin/env python3
"""Independent goniophotometer curves of a plate with a DOTTED face, made with Mitsuba 3.

The dotted face is Mitsuba's `blendbsdf` with `weight` = coverage f of a polished `dielectric`
(the land, weight 1 - f) and a `roughdielectric` (the dots, weight f): an area mixture, sampled
through Mitsuba's Python API in importance (power) transport. Everything else — the plate loop
(all internal reflections, exact unpolarised Fresnel on the polished face), the beam, the 1°
detectors in the plane of incidence, the CSV columns — is the shared reference simulator
`<shared>/reference/mitsuba/scripts/gonio_plate.py`, imported as a module (its `simulate` and
`Tally`), so the only new physics here is Mitsuba's blend of two Mitsuba BSDFs.

Output (per case and entry): `<out>/dotted_<dist>_a<alpha>_f<coverage>_<entry>.csv` with the
columns of the reference data (`incidence_deg,side,detector_deg,value,value_stderr,
value_first_interaction,bsdf,n_hits`), which `opal fit-ndf --measured` reads, and
`<out>/stats.csv` (R, T, lost per incidence).

With `--layout hemisphere` the detectors (same 1° radius) cover the hemisphere of each side
on a polar × azimuth grid (`--polar-step`, `--azimuth-step`; the pole is one detector) and the
CSV gains `detector_azimuth_deg` (azimuth from the plane of incidence, 0 = the specular /
undeviated side; `detector_deg` is then the polar angle), the hemisphere format of
docs/formats.md; the files are named `..._<entry>_hemi.csv`. The tally is `HemiTally` below
(the plate loop is still the shared simulator's).

Usage (from the repository root; bench/.venv has Mitsuba 3.9.1):
  bench/.venv/bin/python bench/scripts/gonio_dotted.py --cases ggx:0.3:0.35 \
      --entries smooth,rough --photons 2e6 --ior 1.52 --thickness-mm 3 --out /tmp/dotted
  --scripts DIR: where gonio_plate.py lives (default ../shared/reference/mitsuba/scripts
  (or ../../shared for a worktree) relative to the repository root, or $OPAL_SHARED/reference/mitsuba/scripts).
"""
import argparse
import csv
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class DottedFace:
    """Mitsuba blendbsdf(dielectric, roughdielectric; weight = coverage) in the face's local
    frame (+z = air side, glass on -z), with the `sample(wi_local, rng)` interface of
    gonio_plate.RoughFace: returns (wo_local, weight)."""

    def __init__(self, gp, distribution, alpha, coverage):
        import mitsuba as mi
        self.mi = mi
        ior = dict(int_ior=gp.N_PLATE, ext_ior=gp.N_AIR)
        self.bsdf = mi.load_dict({
            "type": "blendbsdf",
            "weight": coverage,
            "land": {"type": "dielectric", **ior},
            "dots": {"type": "roughdielectric", "distribution": distribution, "alpha": alpha,
                     "sample_visible": True, **ior},
        })
        self.ctx = mi.BSDFContext(mi.TransportMode.Importance)

    def sample(self, wi_local, rng):
        mi = self.mi
        n = wi_local.shape[0]
        wi = wi_local.astype(np.float32)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(mi.Float(wi[:, 0]), mi.Float(wi[:, 1]), mi.Float(wi[:, 2]))
        s = rng.random((n, 3), dtype=np.float32)
        bs, w = self.bsdf.sample(self.ctx, si, mi.Float(s[:, 0]), mi.Point2f(mi.Float(s[:, 1]), mi.Float(s[:, 2])))
        wo = np.stack([np.array(bs.wo.x), np.array(bs.wo.y), np.array(bs.wo.z)], -1).astype(np.float64)
        weight = np.array(w[0] if hasattr(w, "__getitem__") else w, dtype=np.float64).reshape(-1)
        return wo, weight


def hemi_tally_class(gp, polar_step, azimuth_step):
    """A gonio_plate.Tally whose detectors cover the hemisphere: polar 0, step, ... < 90° (the
    pole one detector) × azimuth 0, step, ... < 360°, angular radius gp.DET_RADIUS_DEG, axis
    (sin t cos a, sin t sin a, ±cos t) as Opal's `DetectorGrid::Hemisphere`."""
    polar = np.arange(0.0, 90.0 - 1e-9, polar_step)
    azim = np.arange(0.0, 360.0 - 1e-9, azimuth_step)
    dets = [(0.0, 0.0)] + [(t, a) for t in polar[1:] for a in azim]
    axes = np.array([[math.sin(math.radians(t)) * math.cos(math.radians(a)),
                      math.sin(math.radians(t)) * math.sin(math.radians(a)),
                      math.cos(math.radians(t))] for t, a in dets])
    r = gp.DET_RADIUS_DEG
    # per polar row: the azimuth offsets a hit can reach (wide near the pole)
    def reach(t):
        s_min = math.sin(math.radians(max(t - r, 1e-6)))
        half = 90.0 if s_min <= math.sin(math.radians(r)) else math.degrees(math.asin(math.sin(math.radians(r)) / s_min))
        return min(int(math.ceil(half / azimuth_step)) + 1, len(azim) // 2 + 1)

    class HemiTally(gp.Tally):
        DETS = dets

        def __init__(self):
            super().__init__()
            nd = len(dets)
            self.sum = {s: np.zeros(nd) for s in "RT"}
            self.sum2 = {s: np.zeros(nd) for s in "RT"}
            self.cnt = {s: np.zeros(nd, dtype=np.int64) for s in "RT"}
            self.sum_first = {s: np.zeros(nd) for s in "RT"}
            self.sum2_first = {s: np.zeros(nd) for s in "RT"}
            self.sum_bsdf = {s: np.zeros(nd) for s in "RT"}

        def add_exits(self, side, d, w, order, path):
            if d.shape[0] == 0:
                return
            self.total[side] += w.sum()
            cz = np.abs(d[:, 2])
            th = np.degrees(np.arccos(np.clip(cz, 0.0, 1.0)))
            ph = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 360.0
            local = np.stack([d[:, 0], d[:, 1], cz], -1)  # side T mirrored onto +z
            cos_r = math.cos(math.radians(r))

            def tally(idx, hit):
                ii, wh = idx[hit], w[hit]
                np.add.at(self.sum[side], ii, wh)
                np.add.at(self.sum2[side], ii, wh * wh)
                np.add.at(self.cnt[side], ii, 1)
                np.add.at(self.sum_bsdf[side], ii, wh / np.maximum(cz[hit], 1e-6))
                first = order[hit] == 1
                np.add.at(self.sum_first[side], ii[first], wh[first])
                np.add.at(self.sum2_first[side], ii[first], wh[first] ** 2)

            tally(np.zeros(len(w), dtype=np.int64), local @ axes[0] >= cos_r)
            k0 = np.rint(th / polar_step).astype(int)
            for dk in (-1, 0, 1):
                k = k0 + dk
                for row in np.unique(k[(k >= 1) & (k < len(polar))]):
                    sel = np.nonzero(k == row)[0]
                    j0 = np.rint(ph[sel] / azimuth_step).astype(int)
                    K = reach(polar[row])
                    # every azimuth of the row once (near the pole), else the reachable offsets
                    if 2 * K + 1 >= len(azim):
                        cols = [np.full(len(sel), j) for j in range(len(azim))]
                    else:
                        cols = [(j0 + dj) % len(azim) for dj in range(-K, K + 1)]
                    for j in cols:
                        idx = 1 + (row - 1) * len(azim) + j
                        hit = np.zeros(len(w), dtype=bool)
                        hit[sel] = np.einsum("ij,ij->i", local[sel], axes[idx]) >= cos_r
                        full = np.zeros(len(w), dtype=np.int64)
                        full[sel] = idx
                        tally(full, hit)

    return HemiTally


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="ggx:0.3:0.35",
                    help="dist:alpha:coverage,... (dots' NDF, roughness, covered fraction)")
    ap.add_argument("--entries", default="smooth,rough", help="smooth = polished face lit, rough = dotted face lit")
    ap.add_argument("--photons", type=float, default=2e6, help="photons per incidence angle")
    ap.add_argument("--chunk", type=float, default=1e6)
    ap.add_argument("--incidences", default="0,15,30,45,60,75")
    ap.add_argument("--divergence", type=float, default=0.5)
    ap.add_argument("--ior", type=float, default=1.52)
    ap.add_argument("--thickness-mm", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=2027)
    ap.add_argument("--variant", default="llvm_ad_rgb,scalar_rgb")
    ap.add_argument("--scripts", default=None)
    ap.add_argument("--out", default="/tmp/opal-dotted")
    ap.add_argument("--layout", default="plane", choices=["plane", "hemisphere"])
    ap.add_argument("--polar-step", type=float, default=2.0, help="hemisphere layout: polar step (deg)")
    ap.add_argument("--azimuth-step", type=float, default=10.0, help="hemisphere layout: azimuth step (deg)")
    a = ap.parse_args()
    shared = os.environ.get("OPAL_SHARED") or next(
        (d for d in (os.path.join(os.path.dirname(ROOT), "shared"), os.path.join(os.path.dirname(os.path.dirname(ROOT)), "shared"))
         if os.path.isdir(d)), "shared")
    scripts = a.scripts or os.path.join(shared, "reference", "mitsuba", "scripts")
    sys.path.insert(0, scripts)
    import gonio_plate as gp  # noqa: E402  (the shared reference simulator)
    import common  # noqa: E402
    gp.N_PLATE = a.ior
    gp.THICKNESS_MM = a.thickness_mm
    variant = common.set_variant(a.variant.split(","))
    import mitsuba as mi
    print(f"variant {variant}, mitsuba {mi.__version__}", flush=True)
    os.makedirs(a.out, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    N, chunk = int(a.photons), int(a.chunk)
    incid = [float(x) for x in a.incidences.split(",")]
    stats = []
    hemi = a.layout == "hemisphere"
    Tally = hemi_tally_class(gp, a.polar_step, a.azimuth_step) if hemi else gp.Tally
    for c in a.cases.split(","):
        dist, alpha, cov = c.split(":")
        face = DottedFace(gp, dist, float(alpha), float(cov))
        for entry in a.entries.split(","):
            tag = f"dotted_{dist}_a{alpha}_f{cov}_{entry}" + ("_hemi" if hemi else "")
            rows = []
            for th in incid:
                t0 = time.time()
                tally = Tally()
                done = 0
                while done < N:
                    m = min(chunk, N - done)
                    gp.simulate(th, m, entry, face, a.divergence, rng, tally)
                    done += m
                norm = 1.0 / (tally.n * gp.OMEGA_DET)
                for side in "RT":
                    s1 = tally.sum[side]
                    var = np.maximum(tally.sum2[side] / tally.n - (s1 / tally.n) ** 2, 0) / tally.n
                    se = np.sqrt(var) / gp.OMEGA_DET
                    angles = Tally.DETS if hemi else [(k, None) for k in gp.DET_DEG]
                    for j, (k, az) in enumerate(angles):
                        row = dict(incidence_deg=int(th) if th == int(th) else th, side=side,
                                   detector_deg=float(k) if hemi else int(k), value=s1[j] * norm,
                                   value_stderr=se[j],
                                   value_first_interaction=tally.sum_first[side][j] * norm,
                                   bsdf=tally.sum_bsdf[side][j] * norm, n_hits=int(tally.cnt[side][j]))
                        if hemi:
                            row["detector_azimuth_deg"] = float(az)
                        rows.append(row)
                Rt, Tt = tally.total["R"] / tally.n, tally.total["T"] / tally.n
                lost = tally.lost_microfacet / tally.n
                dt = time.time() - t0
                stats.append(dict(case=tag, incidence_deg=th, n=tally.n, R=Rt, T=Tt, lost=lost, seconds=round(dt, 1)))
                print(f"{tag} inc {th:4.0f}: R={Rt:.5f} T={Tt:.5f} lost={lost:.5f} {dt:.1f}s", flush=True)
            with open(os.path.join(a.out, f"{tag}.csv"), "w", newline="") as f:
                wr = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
                wr.writeheader()
                for r in rows:
                    wr.writerow({k: (f"{v:.8g}" if isinstance(v, float) else v) for k, v in r.items()})
    with open(os.path.join(a.out, "stats.csv"), "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(stats[0].keys()))
        wr.writeheader()
        wr.writerows(stats)


if __name__ == "__main__":
    main()
