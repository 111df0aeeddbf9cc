#!/usr/bin/env python3
"""Loads the scene.xml written by `opal delight` in Mitsuba 3, renders its sensors and compares
each render with Opal's re-render of the same view (rerender/<sensor id>.exr).

Usage: check_delight_scene_in_mitsuba.py OUTDIR [--spp N] [--variant scalar_rgb|llvm_ad_rgb]
Needs `pip install mitsuba` (3.x). Prints, per view, the mean RGB of both renders and their
relative difference, and the z-score of the difference of the means (both renders are Monte
Carlo estimates: the test is paired, the standard error of the mean difference comes from the
per-pixel differences, in which the image content cancels).
Exit 0 when every view's |z| ≤ 4 (and the scene loaded), 1 otherwise.
"""
import argparse
import pathlib
import sys

import mitsuba as mi
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("outdir", type=pathlib.Path)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variant", default="scalar_rgb")
    a = ap.parse_args()
    mi.set_variant(a.variant)
    scene = mi.load_file(str(a.outdir / "scene.xml"))
    ok = True
    for i, sensor in enumerate(scene.sensors()):
        sid = sensor.id()
        ref = a.outdir / "rerender" / f"{sid}.exr"
        if not ref.exists():
            img = np.array(mi.render(scene, sensor=i, spp=a.spp, seed=i))
            print(f"{sid}: rendered {img.shape}, no Opal re-render to compare")
            continue
        opal = np.array(mi.Bitmap(str(ref)))[:, :, :3]
        h, w = opal.shape[:2]
        # the re-renders have the views' size (transforms.json), which may differ from the
        # scene's film: render the same camera at that size
        p = mi.traverse(sensor)
        cam = mi.load_dict({
            "type": "perspective",
            "fov": float(p["x_fov"][0]) if hasattr(p["x_fov"], "__len__") else float(p["x_fov"]),
            "fov_axis": "x",
            "to_world": sensor.world_transform(),
            "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
        })
        img = np.array(mi.render(scene, sensor=cam, spp=a.spp, seed=i))[:, :, :3]
        m1, m2 = img.reshape(-1, 3).mean(axis=0), opal.reshape(-1, 3).mean(axis=0)
        # paired test: the image content cancels in the per-pixel difference, what remains is
        # the Monte-Carlo noise of both renders (independent between pixels)
        d = (img - opal).reshape(-1, 3)
        z = d.mean(axis=0) / (d.std(axis=0, ddof=1) / np.sqrt(len(d)) + 1e-30)
        rel = m1 / np.maximum(m2, 1e-30) - 1.0
        print(f"{sid}: mitsuba {np.round(m1, 5)} opal {np.round(m2, 5)} rel {np.round(100 * rel, 2)} % z {np.round(z, 2)}")
        ok &= bool(np.all(np.abs(z) <= 4.0))
    print("OK" if ok else "MISMATCH")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
