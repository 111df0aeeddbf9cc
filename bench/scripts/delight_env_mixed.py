#!/usr/bin/env python3
"""Small independent de-lighting data set with non-diffuse objects, rendered by Mitsuba 3.

Scene (metres, +y up): an open courtyard — a 2 × 2 floor, a back wall and a left wall (1 m
high), a diffuse box, a textured poster on the left wall (64² bitmap albedo, smooth content), a
**rough aluminium panel** (`roughconductor`, GGX α 0.1, a 0.5 × 0.75 m slab turned to throw
the reflected sun onto the back wall and the floor) and a **rough plastic sphere**
(`roughplastic`, GGX α 0.15, faceted). Lights: a procedural 64 × 32 lat-long `envmap` (sky
gradient, a bright 2 × 2-texel sun at elevation 30° from +x+z, a dark ground half) and a small
warm area light (0.3 × 0.3 m quad facing down at 1.2 m). Five pinhole views of 96 × 72 pixels
that also see the sky, the metal and the plastic.

`--metal-black` renders the same scene with the panel a black diffuse (only to measure how
much of the walls' light comes by way of the metal; not committed).

Writes into OUT: scene.xml, meshes/*.obj, env.exr, textures/poster_albedo.exr,
views/view_XX.exr (linear HDR radiance, box filter) and views/view_XX_stderr.exr,
transforms.json (NeRF-style, OpenGL axes), truth.json.

Usage: bench/.venv/bin/python bench/scripts/delight_env_mixed.py OUT [--spp 2048]
The committed copy is crates/opal-inverse/tests/data/env_mixed; the test that reads it is
`env_mixed_non_diffuse_objects` in crates/opal-inverse/tests/delight_env_mixed.rs.
"""
import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from room_multiview import (blur, cuboid_mesh, find_libllvm, fmt, look_at, quad, smooth_noise,  # noqa: E402
                            sphere_mesh, write_obj, write_transforms)

ALBEDO = {
    "floor": [0.6, 0.55, 0.45],
    "back_wall": [0.45, 0.55, 0.65],
    "left_wall": [0.7, 0.35, 0.25],
    "box": [0.3, 0.35, 0.75],
}
SUN_DIR = np.array([0.775, 0.5, 0.387])  # towards the sun, world frame
CAMERAS = [
    ((1.6, 1.4, 1.8), (-0.2, 0.3, -0.3), 60.0, 96, 72),
    ((-0.2, 1.6, 2.0), (0.0, 0.2, -0.4), 60.0, 96, 72),
    ((1.9, 0.9, -0.2), (-0.5, 0.35, -0.2), 60.0, 96, 72),
    ((0.3, 2.2, 0.9), (0.0, 0.0, -0.2), 60.0, 96, 72),
    ((0.9, 1.0, 1.9), (-0.7, 0.5, -0.3), 60.0, 96, 72),
]
METAL = ('        <bsdf type="roughconductor">\n            <string name="material" value="Al"/>\n'
         '            <string name="distribution" value="ggx"/>\n            <float name="alpha" value="0.1"/>\n'
         '        </bsdf>\n')
PLASTIC = ('        <bsdf type="roughplastic">\n            <string name="distribution" value="ggx"/>\n'
           '            <float name="alpha" value="0.15"/>\n            <float name="int_ior" value="1.49"/>\n'
           '            <rgb name="diffuse_reflectance" value="0.2 0.5 0.3"/>\n        </bsdf>\n')


def env_map(w=64, h=32):
    """Sky gradient over a dark ground; a 2 × 2-texel sun in SUN_DIR (Mitsuba's lat-long
    convention: u = atan2(x, −z)/2π, v = acos(y)/π)."""
    img = np.zeros((h, w, 3), np.float32)
    for j in range(h):
        t = (j + 0.5) / h
        for i in range(w):
            if t < 0.5:
                s = 1.0 - t
                img[j, i] = [0.3 * s + 0.1, 0.45 * s + 0.1, 0.8 * s + 0.15]
                img[j, i] *= 1.0 + 0.3 * np.sin(2 * np.pi * i / w)
            else:
                img[j, i] = [0.12, 0.1, 0.08]
    d = SUN_DIR / np.linalg.norm(SUN_DIR)
    u = (math.atan2(d[0], -d[2]) / (2 * math.pi)) % 1.0
    v = math.acos(d[1]) / math.pi
    i0, j0 = int(round(u * w)) - 1, int(round(v * h)) - 1
    img[j0:j0 + 2, i0:i0 + 2] = [120.0, 104.0, 80.0]
    return img


def poster_texture(rng, n=64):
    """Smooth 'painting': colour gradients, two soft discs, value noise (no hard edges)."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    img = np.stack([0.3 + 0.45 * x, 0.25 + 0.45 * (1 - y), 0.45 + 0.25 * np.sin(3 * x + 2 * y)], axis=-1)
    for (cx, cy, r, col) in ((0.3, 0.4, 0.2, (0.85, 0.75, 0.2)), (0.7, 0.6, 0.22, (0.15, 0.5, 0.3))):
        dd = np.sqrt((x - cx) ** 2 + (y - cy) ** 2)
        a = np.clip((r - dd) / 0.08 + 0.5, 0, 1)[:, :, None]
        img = img * (1 - a) + np.array(col) * a
    img = blur(img, 2)
    img *= (0.85 + 0.3 * smooth_noise(rng, n, 3))[:, :, None]
    return np.clip(img, 0.05, 0.9)


def write_scene(out: Path, objects, cams):
    lines = ['<scene version="3.0.0">',
             "    <!-- delight_env_mixed.py: independent de-lighting data set -->",
             '    <integrator type="path">',
             '        <integer name="max_depth" value="-1"/>',
             '        <integer name="rr_depth" value="5"/>',
             "    </integrator>"]
    for k, c in enumerate(cams):
        lines += [f'    <sensor type="perspective" id="view_{k:02d}">',
                  f'        <float name="fov" value="{c["fov_deg"]:.9g}"/>',
                  '        <string name="fov_axis" value="x"/>',
                  '        <transform name="to_world">',
                  f'            <matrix value="{fmt(np.array(c["to_world"]).flatten())}"/>',
                  "        </transform>",
                  '        <sampler type="independent"><integer name="sample_count" value="64"/></sampler>',
                  '        <film type="hdrfilm">',
                  f'            <integer name="width" value="{c["width"]}"/>',
                  f'            <integer name="height" value="{c["height"]}"/>',
                  '            <rfilter type="box"/>',
                  '            <string name="pixel_format" value="rgb"/>',
                  "        </film>",
                  "    </sensor>"]
    for o in objects:
        lines += [f'    <shape type="obj" id="{o["name"]}">',
                  f'        <string name="filename" value="{o["obj"]}"/>',
                  '        <boolean name="face_normals" value="true"/>']
        if "bsdf_xml" in o:
            lines.append(o["bsdf_xml"].rstrip("\n"))
        else:
            lines.append('        <bsdf type="diffuse">')
            if "albedo_texture" in o:
                lines += ['            <texture type="bitmap" name="reflectance">',
                          f'                <string name="filename" value="{o["albedo_texture"]}"/>',
                          '                <string name="filter_type" value="bilinear"/>',
                          '                <string name="wrap_mode" value="clamp"/>',
                          '                <boolean name="raw" value="true"/>',
                          "            </texture>"]
            else:
                lines.append(f'            <rgb name="reflectance" value="{fmt(o["albedo_rgb"])}"/>')
            lines.append("        </bsdf>")
        if "radiance_rgb" in o:
            lines += ['        <emitter type="area">',
                      f'            <rgb name="radiance" value="{fmt(o["radiance_rgb"])}"/>',
                      "        </emitter>"]
        lines.append("    </shape>")
    lines += ['    <emitter type="envmap" id="sky">', '        <string name="filename" value="env.exr"/>',
              "    </emitter>", "</scene>"]
    (out / "scene.xml").write_text("\n".join(lines) + "\n")


def build(out: Path, metal_black: bool):
    rng = np.random.default_rng(27)
    meshes = {
        "floor": quad((-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)),
        "back_wall": quad((-1, 0, -1), (1, 0, -1), (1, 1, -1), (-1, 1, -1)),
        "left_wall": quad((-1, 0, 1), (-1, 0, -1), (-1, 1, -1), (-1, 1, 1)),
        "poster": quad((-0.998, 0.3, 0.1), (-0.998, 0.3, -0.7), (-0.998, 0.8, -0.7), (-0.998, 0.8, 0.1)),
    }
    objects = []
    for name, (verts, uvs, normals, faces) in meshes.items():
        tex = name == "poster"
        n = write_obj(out / "meshes" / f"{name}.obj", name, verts, faces, uvs if tex else None, normals)
        o = {"name": name, "obj": f"meshes/{name}.obj", "n_triangles": n}
        if tex:
            o["albedo_texture"] = "textures/poster_albedo.exr"
        else:
            o["albedo_rgb"] = ALBEDO[name]
        objects.append(o)
    v, f = cuboid_mesh((-0.45, 0.0, -0.45), (0.35, 0.35, 0.3), 20.0)
    objects.append({"name": "box", "obj": "meshes/box.obj", "albedo_rgb": ALBEDO["box"],
                    "n_triangles": write_obj(out / "meshes/box.obj", "box", v, f)})
    v, f = cuboid_mesh((0.5, 0.0, -0.45), (0.5, 0.75, 0.03), 135.0)
    metal = {"name": "metal", "obj": "meshes/metal.obj", "bsdf": "roughconductor Al ggx alpha 0.1",
             "n_triangles": write_obj(out / "meshes/metal.obj", "metal", v, f)}
    if metal_black:
        metal["albedo_rgb"] = [0.0, 0.0, 0.0]
    else:
        metal["bsdf_xml"] = METAL
    objects.append(metal)
    v, f = sphere_mesh((0.05, 0.2, 0.35), 0.2, nphi=24, ntheta=12)
    objects.append({"name": "plastic", "obj": "meshes/plastic.obj", "bsdf_xml": PLASTIC,
                    "bsdf": "roughplastic ggx alpha 0.15 ior 1.49 diffuse 0.2 0.5 0.3",
                    "n_triangles": write_obj(out / "meshes/plastic.obj", "plastic", v, f)})
    verts, _uvs, normals, faces = quad((-0.45, 1.2, -0.1), (-0.15, 1.2, -0.1), (-0.15, 1.2, 0.2), (-0.45, 1.2, 0.2))
    objects.append({"name": "lamp", "obj": "meshes/lamp.obj", "albedo_rgb": [0.2, 0.2, 0.2],
                    "radiance_rgb": [16.0, 12.0, 8.0],
                    "n_triangles": write_obj(out / "meshes/lamp.obj", "lamp", verts, faces, None, normals)})
    assert normals[0][1] < 0, "lamp faces down"
    return objects, poster_texture(rng)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=2048)
    ap.add_argument("--pass-spp", type=int, default=256)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--metal-black", action="store_true")
    a = ap.parse_args()
    if a.variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi
    mi.set_variant(a.variant)
    out = a.out
    for d in ("meshes", "views", "textures"):
        (out / d).mkdir(parents=True, exist_ok=True)
    mi.Bitmap(env_map()).write(str(out / "env.exr"))
    objects, poster = build(out, a.metal_black)
    mi.Bitmap(poster.astype(np.float32)).write(str(out / "textures/poster_albedo.exr"))
    cams = []
    for k, (o, t, fov, w, h) in enumerate(CAMERAS):
        cams.append({"index": k, "origin": o, "target": t, "fov_deg": fov, "width": w, "height": h,
                     "to_world": look_at(o, t).tolist(), "image": f"views/view_{k:02d}.exr"})
    write_scene(out, objects, cams)
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
        noise[f"view_{k:02d}"] = {"median_rel_stderr": float(np.median(rel)),
                                  "p95_rel_stderr": float(np.percentile(rel, 95))}
        print(f"view {k}: median rel stderr {noise[f'view_{k:02d}']['median_rel_stderr']:.4f}", flush=True)
    truth = {"generator": "bench/scripts/delight_env_mixed.py (Mitsuba 3)", "mitsuba_version": mi.__version__,
             "variant": a.variant, "metal_black": a.metal_black, "sun_direction": SUN_DIR.tolist(),
             "objects": objects, "cameras": cams,
             "sampling": {"spp": passes * a.pass_spp, "passes": passes, "pixel_filter": "box"},
             "noise": noise, "seconds": round(time.time() - t_all, 1)}
    for o in truth["objects"]:
        o.pop("bsdf_xml", None)
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")


if __name__ == "__main__":
    main()
