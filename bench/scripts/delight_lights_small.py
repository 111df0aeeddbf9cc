#!/usr/bin/env python3
"""Small independent data set for the default-tier de-lighting test with several light types:
a closed room rendered by Mitsuba 3 with two area lights of different colours AND a point light.

Scene (metres, +y up): a closed room 2.0 × 1.2 × 2.0 (x, z ∈ [-1, 1], y ∈ [0, 1.2]); floor,
ceiling and four walls, a rotated cuboid and a faceted UV sphere (24 × 12 segments), every
surface Lambertian with a constant albedo (no textures: the test checks constant albedos within
1 %). Lights: a warm 0.5 × 0.3 ceiling panel, a cool 0.25 × 0.25 ceiling panel (both one-sided
`area` emitters on quads, 4 emitting triangles) and an isotropic `point` emitter of a third
colour, so the direct irradiance runs its per-light branch with a point light among triangle
lights. Five pinhole views inside the room (80 × 60 by default), meshes with face normals.

Writes into OUT: scene.xml (the sensors are the views; Opal loads it as is), meshes/*.obj,
views/view_XX.exr (linear HDR radiance, box filter) and views/view_XX_stderr.exr (per-pixel
standard error from the scatter of the passes), transforms.json (NeRF-style, OpenGL axes),
truth.json (albedos, lights, cameras, noise summary).

Usage: bench/.venv/bin/python bench/scripts/delight_lights_small.py OUT [--spp 4096]
       [--pass-spp 256] [--variant llvm_ad_rgb] [--scale 1.0]
The committed copy is crates/opal-inverse/tests/data/lights_small (default arguments); the test
that reads it is `delight_lights_small` in crates/opal-inverse/tests/delight.rs.
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

X, Y, Z = 1.0, 1.2, 1.0

ALBEDO = {
    "floor": [0.7, 0.62, 0.5],
    "ceiling": [0.8, 0.8, 0.78],
    "back_wall": [0.35, 0.5, 0.65],
    "front_wall": [0.6, 0.55, 0.4],
    "left_wall": [0.7, 0.3, 0.2],
    "right_wall": [0.25, 0.55, 0.3],
    "box": [0.3, 0.35, 0.75],
    "sphere": [0.8, 0.3, 0.35],
}

AREA_LIGHTS = [
    # name, centre (x, z), size (x, z), radiance RGB
    ("light_warm", (-0.4, -0.3), (0.5, 0.3), [10.0, 7.0, 4.0]),
    ("light_cool", (0.5, 0.45), (0.25, 0.25), [6.0, 10.0, 20.0]),
]
POINT_LIGHT = {"position": [0.15, 0.95, -0.55], "intensity": [1.0, 1.4, 1.1]}

# origin, target, fov_x (deg), width, height
CAMERAS = [
    ((0.85, 0.9, 0.85), (-0.4, 0.3, -0.5), 75.0, 80, 60),
    ((-0.85, 0.7, 0.85), (0.4, 0.35, -0.6), 75.0, 80, 60),
    ((0.85, 0.6, -0.85), (-0.5, 0.5, 0.6), 75.0, 80, 60),
    ((-0.85, 1.0, -0.85), (0.5, 0.3, 0.6), 75.0, 80, 60),
    ((0.0, 0.3, 0.0), (0.05, 1.2, 0.1), 90.0, 64, 64),
]


def room_meshes():
    m = {}
    m["floor"] = quad((-X, 0, Z), (X, 0, Z), (X, 0, -Z), (-X, 0, -Z))
    m["ceiling"] = quad((-X, Y, -Z), (X, Y, -Z), (X, Y, Z), (-X, Y, Z))
    m["back_wall"] = quad((-X, 0, -Z), (X, 0, -Z), (X, Y, -Z), (-X, Y, -Z))
    m["front_wall"] = quad((X, 0, Z), (-X, 0, Z), (-X, Y, Z), (X, Y, Z))
    m["left_wall"] = quad((-X, 0, Z), (-X, 0, -Z), (-X, Y, -Z), (-X, Y, Z))
    m["right_wall"] = quad((X, 0, -Z), (X, 0, Z), (X, Y, Z), (X, Y, -Z))
    return m


def light_quad(centre, size):
    (cx, cz), (sx, sz) = centre, size
    y = Y - 0.01
    return quad((cx - sx / 2, y, cz - sz / 2), (cx + sx / 2, y, cz - sz / 2),
                (cx + sx / 2, y, cz + sz / 2), (cx - sx / 2, y, cz + sz / 2))


def add_point_light(out: Path):
    """write_scene knows area emitters only: insert the point emitter before </scene>."""
    p, i = POINT_LIGHT["position"], POINT_LIGHT["intensity"]
    s = (out / "scene.xml").read_text()
    e = ('    <emitter type="point" id="point_light">\n'
         f'        <point name="position" x="{p[0]}" y="{p[1]}" z="{p[2]}"/>\n'
         f'        <rgb name="intensity" value="{i[0]} {i[1]} {i[2]}"/>\n'
         "    </emitter>\n</scene>\n")
    (out / "scene.xml").write_text(s.replace("</scene>\n", e))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--pass-spp", type=int, default=256)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--scale", type=float, default=1.0)
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
    objects = []
    for name, (verts, _uvs, normals, faces) in room_meshes().items():
        n = write_obj(out / "meshes" / f"{name}.obj", name, verts, faces, None, normals)
        objects.append({"name": name, "obj": f"meshes/{name}.obj", "albedo_rgb": ALBEDO[name], "n_triangles": n})
    v, f = cuboid_mesh((-0.35, 0.0, -0.15), (0.4, 0.45, 0.35), 25.0)
    objects.append({"name": "box", "obj": "meshes/box.obj", "albedo_rgb": ALBEDO["box"],
                    "n_triangles": write_obj(out / "meshes/box.obj", "box", v, f)})
    v, f = sphere_mesh((0.4, 0.25, 0.1), 0.25, nphi=24, ntheta=12)
    objects.append({"name": "sphere", "obj": "meshes/sphere.obj", "albedo_rgb": ALBEDO["sphere"],
                    "n_triangles": write_obj(out / "meshes/sphere.obj", "sphere", v, f)})
    for name, centre, size, rad in AREA_LIGHTS:
        verts, _uvs, normals, faces = light_quad(centre, size)
        objects.append({"name": name, "obj": f"meshes/{name}.obj", "albedo_rgb": [0.78, 0.78, 0.78],
                        "radiance_rgb": rad, "area": size[0] * size[1],
                        "n_triangles": write_obj(out / "meshes" / f"{name}.obj", name, verts, faces,
                                                 None, normals)})
    cams = []
    for k, (o, t, fov, w, h) in enumerate(CAMERAS):
        cams.append({"index": k, "origin": o, "target": t, "fov_deg": fov,
                     "width": max(8, round(w * a.scale)), "height": max(8, round(h * a.scale)),
                     "to_world": look_at(o, t).tolist(), "image": f"views/view_{k:02d}.exr"})
    write_scene(out, objects, cams, -1)
    add_point_light(out)
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
        mi.Bitmap(se.astype(np.float32)).write(str(out / c["image"].replace(".exr", "_stderr.exr")))
        lum = mean.mean(axis=2)
        ok = lum > 1e-3
        rel = se.mean(axis=2)[ok] / lum[ok]
        noise[f"view_{k:02d}"] = {"median_rel_stderr": float(np.median(rel)),
                                  "p95_rel_stderr": float(np.percentile(rel, 95))}
        print(f"view {k}: {c['width']}x{c['height']} {passes * a.pass_spp} spp, "
              f"median rel stderr {noise[f'view_{k:02d}']['median_rel_stderr']:.4f}", flush=True)
    truth = {"generator": "bench/scripts/delight_lights_small.py (Mitsuba 3)", "mitsuba_version": mi.__version__,
             "variant": a.variant, "room": {"x": [-X, X], "y": [0, Y], "z": [-Z, Z]}, "objects": objects,
             "point_light": POINT_LIGHT, "cameras": cams,
             "integrator": {"type": "path", "max_depth": -1, "rr_depth": 5, "hide_emitters": False},
             "sampling": {"spp": passes * a.pass_spp, "passes": passes, "pixel_filter": "box"},
             "noise": noise, "seconds": round(time.time() - t_all, 1)}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(out / "scene.xml")


if __name__ == "__main__":
    main()
