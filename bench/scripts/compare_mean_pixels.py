"""Renders one scene with Opal and Mitsuba 3 at the same settings and compares mean pixel values.

Checks that both renderers see the same scene (geometry, UVs, textures, materials, light): the
per-channel means of the two images over the whole frame and over a crop must agree within the
Monte Carlo noise. The standard error of a mean difference is estimated from the per-pixel
differences (pixels are independent samples): se = std(diff) / sqrt(n).

Usage (from the repository root, with the bench venv):
  bench/.venv/bin/python bench/scripts/compare_mean_pixels.py SCENE.xml [--spp 16]
      [--max-depth 16] [--opal target/release/opal] [--variant llvm_ad_rgb]
      [--crop x0 y0 x1 y1] [--save-prefix PREFIX]
"""
import argparse
import os
import subprocess
import tempfile

import mitsuba as mi
import numpy as np


def stats(name, a, b):
    d = (a - b).reshape(-1, 3)
    n = d.shape[0]
    se = d.std(axis=0) / np.sqrt(n)
    ma, mb = a.reshape(-1, 3).mean(axis=0), b.reshape(-1, 3).mean(axis=0)
    z = (ma - mb) / np.maximum(se, 1e-12)
    print(f"{name:>10s}  opal {np.array2string(ma, precision=5)}  mitsuba {np.array2string(mb, precision=5)}  "
          f"diff {np.array2string(ma - mb, precision=5)}  ({np.array2string(100 * (ma - mb) / mb, precision=2)} %)  "
          f"se {np.array2string(se, precision=5)}  z {np.array2string(z, precision=2)}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--opal", default="target/release/opal")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--crop", type=int, nargs=4, metavar=("X0", "Y0", "X1", "Y1"))
    ap.add_argument("--save-prefix", help="also write PREFIX_opal.exr and PREFIX_mitsuba.exr")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "opal.exr")
        subprocess.run([a.opal, "render", a.scene, "-o", out, "--spp", str(a.spp), "--max-depth",
                        str(a.max_depth), "--quiet"], check=True)
        mi.set_variant(a.variant)
        opal = np.array(mi.Bitmap(out))[..., :3].astype(np.float64)
    scene = mi.load_file(a.scene)
    integ = mi.load_dict({"type": "path", "max_depth": a.max_depth})
    mits = np.array(mi.render(scene, spp=a.spp, integrator=integ, sensor=0))[..., :3].astype(np.float64)
    if a.save_prefix:
        mi.Bitmap(opal.astype(np.float32)).write(a.save_prefix + "_opal.exr")
        mi.Bitmap(mits.astype(np.float32)).write(a.save_prefix + "_mitsuba.exr")
    print(f"{a.scene}: {opal.shape[1]}x{opal.shape[0]}, {a.spp} spp, max depth {a.max_depth}, "
          f"Mitsuba {a.variant}")
    stats("frame", opal, mits)
    if a.crop:
        x0, y0, x1, y1 = a.crop
        stats("crop", opal[y0:y1, x0:x1], mits[y0:y1, x0:x1])


if __name__ == "__main__":
    main()
