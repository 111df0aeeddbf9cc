#!/usr/bin/env python3
"""Small independent data set for de-lighting under an environment map, rendered by Mitsuba 3.

Scene (metres, +y up): an open courtyard — a 2 × 2 floor, a back wall and a left wall (1 m
high), a rotated cuboid and a faceted UV sphere; every surface Lambertian with a constant
albedo (the test checks constant albedos within 1 %). The only light is an `envmap`: a
procedural 32 × 16 lat-long HDR map (sky gradient, a bright sun of 2 × 2 texels, a dark ground
half), rotated by `to_world`. Four pinhole views from outside the courtyard (64 × 48), which
also see the sky.

Writes into OUT: scene.xml, meshes/*.obj, env.exr, views/view_XX.exr (linear HDR radiance, box
filter) and views/view_XX_stderr.exr, transforms.json (NeRF-style, OpenGL axes), truth.json.

Usage: bench/.venv/bin/python bench/scripts/delight_env_small.py OUT [--spp 2048]
The committed copy is crates/opal-inverse/tests/data/env_small; the test that reads it is
`env_small_constant_albedos_within_1_percent` in crates/opal-inverse/tests/delight.rs.
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from room_multiview import (cuboid_mesh, find_libllvm, look_at, quad, sphere_mesh,  # noqa: E402
                            write_obj, write_scene, write_transforms)

ALBEDO = {
    "floor": [0.7, 0.62, 0.5],
    "back_wall": [0.35, 0.5, 0.65],
    "left_wall": [0.7, 0.3, 0.2],
    "box": [0.3, 0.35, 0.75],
    "sphere": [0.8, 0.3, 0.35],
}
CAMERAS = [
    ((1.6, 1.4, 1.8), (-0.2, 0.2, -0.3), 60.0, 64, 48),
    ((-0.2, 1.6, 2.0), (0.0, 0.1, -0.4), 60.0, 64, 48),
    ((1.9, 0.8, -0.2), (-0.5, 0.3, -0.2), 60.0, 64, 48),
    ((0.3, 2.2, 0.9), (0.0, 0.0, -0.2), 60.0, 64, 48),
]


def env_map(w=32, h=16):
    img = np.zeros((h, w, 3), np.float32)
    for j in range(h):
        t = j / (h - 1)
        for i in range(w):
            if t < 0.5:
                s = 1.0 - t
                img[j, i] = [0.3 * s + 0.1, 0.45 * s + 0.1, 0.8 * s + 0.15]
                img[j, i] *= 1.0 + 0.3 * np.sin(2 * np.pi * i / w)
            else:
                img[j, i] = [0.12, 0.1, 0.08]
    img[4:6, 10:12] = [40.0, 34.0, 25.0]
    return img


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=2048)
    ap.add_argument("--pass-spp", type=int, default=256)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    a = ap.parse_args()
    if a.variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi
    mi.set_variant(a.variant)
    out = a.out
    for d in ("meshes", "views"):
        (out / d).mkdir(parents=True, exist_ok=True)
    mi.Bitmap(env_map()).write(str(out / "env.exr"))
    meshes = {
        "floor": quad((-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)),
        "back_wall": quad((-1, 0, -1), (1, 0, -1), (1, 1, -1), (-1, 1, -1)),
        "left_wall": quad((-1, 0, 1), (-1, 0, -1), (-1, 1, -1), (-1, 1, 1)),
    }
    objects = []
    for name, (verts, _uvs, normals, faces) in meshes.items():
        n = write_obj(out / "meshes" / f"{name}.obj", name, verts, faces, None, normals)
        objects.append({"name": name, "obj": f"meshes/{name}.obj", "albedo_rgb": ALBEDO[name], "n_triangles": n})
    v, f = cuboid_mesh((-0.35, 0.0, -0.25), (0.4, 0.45, 0.35), 25.0)
    objects.append({"name": "box", "obj": "meshes/box.obj", "albedo_rgb": ALBEDO["box"],
                    "n_triangles": write_obj(out / "meshes/box.obj", "box", v, f)})
    v, f = sphere_mesh((0.4, 0.25, 0.1), 0.25, nphi=24, ntheta=12)
    objects.append({"name": "sphere", "obj": "meshes/sphere.obj", "albedo_rgb": ALBEDO["sphere"],
                    "n_triangles": write_obj(out / "meshes/sphere.obj", "sphere", v, f)})
    cams = []
    for k, (o, t, fov, w, h) in enumerate(CAMERAS):
        cams.append({"index": k, "origin": o, "target": t, "fov_deg": fov, "width": w, "height": h,
                     "to_world": look_at(o, t).tolist(), "image": f"views/view_{k:02d}.exr"})
    write_scene(out, objects, cams, -1)
    env = ('    <emitter type="envmap" id="sky">\n        <string name="filename" value="env.exr"/>\n'
           '        <transform name="to_world"><rotate y="1" angle="40"/></transform>\n    </emitter>\n</scene>\n')
    s = (out / "scene.xml").read_text()
    (out / "scene.xml").write_text(s.replace("</scene>\n", env))
    write_transforms(out, cams)
    scene = mi.load_file(str(out / "scene.xml"))
    passes = max(2, a.spp // a.pass_spp)
    noise = {}
    t_all = time.time()
    for k, c in enumerate(cams):
        acc = acc2 = None
        for p in range(passes):
            img = np.array(mi.render(scene, sensor=k, spp=a.pass_spp, seed=1000 * k + p), dtype=np.float64)
            acc = img if acc is None else acc + img
            acc2 = img * img if acc2 is None else acc2 + img * img
        mean = acc / passes
        se = np.sqrt(np.maximum(acc2 / passes - mean * mean, 0.0) / (passes - 1))
        mi.Bitmap(mean.astype(np.float32)).write(str(out / c["image"]))
        mi.Bitmap(se.astype(np.float16)).write(str(out / c["image"].replace(".exr", "_stderr.exr")))
        lum = mean.mean(axis=2)
        ok = lum > 1e-3
        rel = se.mean(axis=2)[ok] / lum[ok]
        noise[f"view_{k:02d}"] = {"median_rel_stderr": float(np.median(rel))}
        print(f"view {k}: median rel stderr {noise[f'view_{k:02d}']['median_rel_stderr']:.4f}", flush=True)
    truth = {"generator": "bench/scripts/delight_env_small.py (Mitsuba 3)", "mitsuba_version": mi.__version__,
             "variant": a.variant, "objects": objects, "cameras": cams,
             "sampling": {"spp": passes * a.pass_spp, "passes": passes, "pixel_filter": "box"},
             "noise": noise, "seconds": round(time.time() - t_all, 1)}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")


if __name__ == "__main__":
    main()
