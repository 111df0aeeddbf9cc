#!/usr/bin/env python3
"""Independent multi-view HDR data set for the de-lighting (method C): a closed room, rendered
by Mitsuba 3 — not the shared Cornell box.

Scene (units: metres, right-handed, +y up): a closed room 3.2 × 1.4 × 2.2 (x ∈ [-1.6, 1.6],
y ∈ [0, 1.4], z ∈ [-1.1, 1.1]); textured floor (256² bitmap albedo: tiles with grout and a
smooth colour variation), a textured poster on the back wall (128² bitmap albedo), four walls
and a ceiling of constant albedos, a faceted UV sphere (48 × 24 segments, a mesh, not a box), a
rotated cuboid pedestal; two ceiling area lights of different size and colour (a warm
0.6 × 0.4 panel and a cool, brighter 0.25 × 0.25 one). Six pinhole cameras inside the room at
different heights, directions, fields of view and resolutions (landscape, square, portrait).
Every surface is Lambertian (Mitsuba `diffuse`), meshes use face normals, the OBJ files carry
UVs for the textured quads only.

Writes into OUT:
  scene.xml           Mitsuba 3 scene (the sensors are the six views; Opal loads it as is)
  meshes/*.obj        geometry
  textures/*.exr      true albedo textures (float32, linear)
  views/view_XX.exr   linear HDR radiance, RGB float32 (box pixel filter, SPP samples/pixel)
  views/view_XX_stderr.exr  per-pixel standard error (scatter of the per-pass means)
  transforms.json     NeRF-style cameras (OpenGL axes), what `opal delight --views` reads
  truth.json          true albedos, lights, cameras, noise summary, timings

Usage: bench/.venv/bin/python bench/scripts/room_multiview.py OUT [--spp 1024] [--pass-spp 64]
       [--variant llvm_ad_rgb] [--scale 1.0] [--ring N --width W --height H]
(--scale multiplies the view resolutions, e.g. 0.5 for a quick look; --ring N replaces the six
cameras by N cameras of W × H on two rings inside the room, looking inwards — the
photo-resolution data set of issue 23 is `--ring 24 --width 4000 --height 3000 --spp 8
--pass-spp 4`). The de-lighting
acceptance on it: `OPAL_ROOM_DIR=OUT cargo test -p opal-inverse --test delight_room --
--ignored --nocapture` (crates/opal-inverse/tests/delight_room.rs).
"""
import argparse
import glob
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np

ROOM = dict(x0=-1.6, x1=1.6, y0=0.0, y1=1.4, z0=-1.1, z1=1.1)

ALBEDO = {
    "ceiling": [0.82, 0.82, 0.8],
    "back_wall": [0.35, 0.45, 0.6],
    "front_wall": [0.7, 0.6, 0.45],
    "left_wall": [0.65, 0.35, 0.15],
    "right_wall": [0.3, 0.5, 0.35],
    "sphere": [0.8, 0.25, 0.3],
    "pedestal": [0.2, 0.3, 0.7],
}

LIGHTS = [
    # name, centre (x, z), size (x, z), radiance RGB
    ("light_warm", (-0.5, -0.3), (0.6, 0.4), [9.0, 7.5, 5.0]),
    ("light_cool", (0.9, 0.5), (0.25, 0.25), [14.0, 16.0, 22.0]),
]

# origin, target, fov_x (deg), width, height
CAMERAS = [
    ((0.0, 1.0, 1.0), (0.0, 0.4, -0.6), 70.0, 320, 240),
    ((1.45, 1.2, 0.95), (-0.3, 0.3, -0.4), 65.0, 288, 216),
    ((-1.45, 0.9, 0.9), (0.5, 0.3, -0.5), 60.0, 256, 256),
    ((1.4, 0.7, -0.9), (-0.6, 0.3, 0.4), 72.0, 320, 200),
    ((-1.4, 1.25, -0.95), (0.6, 0.2, 0.3), 55.0, 240, 320),
    ((0.2, 1.3, 0.2), (0.1, 0.0, -0.5), 75.0, 256, 192),
]


def ring_cameras(n, width, height):
    """N cameras on two rings (heights 0.55 and 1.15 m) on an ellipse inside the room, each looking
    across the room at a point near its centre; the horizontal field of view is 65°."""
    cams = []
    for k in range(n):
        a = 2.0 * math.pi * (k + 0.5 * (k % 2)) / n
        y = 0.55 if k % 2 == 0 else 1.15
        o = (1.35 * math.cos(a), y, 0.85 * math.sin(a))
        t = (-0.35 * math.cos(a + 0.6), 0.45 + 0.1 * math.sin(3 * a), -0.25 * math.sin(a + 0.6))
        cams.append((o, t, 65.0, width, height))
    return cams


def find_libllvm():
    """A libLLVM >= 16 for Dr.Jit's llvm_* variants (LLVM 15 fails on `fminimum`)."""
    cands = []
    for pat in ("/usr/lib/x86_64-linux-gnu/libLLVM-*.so", "/usr/lib/llvm-*/lib/libLLVM*.so*",
                "/usr/lib/x86_64-linux-gnu/libLLVM.so.*"):
        cands += glob.glob(pat)

    def ver(p):
        m = re.search(r"LLVM[-.so]*?(\d+)", os.path.basename(p)) or re.search(r"llvm-(\d+)", p)
        return int(m.group(1)) if m else 0

    cands = sorted((c for c in cands if ver(c) >= 16), key=ver, reverse=True)
    return cands[0] if cands else None


# ---------------------------------------------------------------- geometry (OBJ writers)

def write_obj(path: Path, name, verts, faces, uvs=None, normals=None):
    """faces: lists of vertex indices (0-based, CCW seen from the front); uvs/normals per vertex."""
    lines = [f"# {name}: {len(faces)} faces, CCW seen from the front", f"o {name}"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in verts]
    if uvs is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in uvs]
    if normals is not None:
        lines += [f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in normals]
    for f in faces:
        if uvs is not None and normals is not None:
            lines.append("f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in f))
        elif uvs is not None:
            lines.append("f " + " ".join(f"{i + 1}/{i + 1}" for i in f))
        else:
            lines.append("f " + " ".join(f"{i + 1}" for i in f))
    path.write_text("\n".join(lines) + "\n")
    return sum(len(f) - 2 for f in faces)


def quad(p0, p1, p2, p3):
    """Quad p0 p1 p2 p3 (CCW from the front), UVs (0,0) (1,0) (1,1) (0,1), its normal."""
    p = np.array([p0, p1, p2, p3], dtype=float)
    n = np.cross(p[1] - p[0], p[3] - p[0])
    n /= np.linalg.norm(n)
    return p.tolist(), [[0, 0], [1, 0], [1, 1], [0, 1]], [n.tolist()] * 4, [[0, 1, 2], [0, 2, 3]]


def room_meshes():
    r = ROOM
    x0, x1, y0, y1, z0, z1 = r["x0"], r["x1"], r["y0"], r["y1"], r["z0"], r["z1"]
    m = {}
    # all walls face the inside; floor: u along +x, v along -z (OBJ v=0 at the image bottom, so
    # the image's top row is at the back, z = z0)
    m["floor"] = quad((x0, y0, z1), (x1, y0, z1), (x1, y0, z0), (x0, y0, z0))
    m["ceiling"] = quad((x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1))
    m["back_wall"] = quad((x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0))
    m["front_wall"] = quad((x1, y0, z1), (x0, y0, z1), (x0, y1, z1), (x1, y1, z1))
    m["left_wall"] = quad((x0, y0, z1), (x0, y0, z0), (x0, y1, z0), (x0, y1, z1))
    m["right_wall"] = quad((x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0))
    # poster: 1.0 × 0.7 on the back wall, 2 mm in front of it
    zp = z0 + 0.002
    m["poster"] = quad((-1.1, 0.45, zp), (-0.1, 0.45, zp), (-0.1, 1.15, zp), (-1.1, 1.15, zp))
    return m


def light_mesh(centre, size):
    (cx, cz), (sx, sz) = centre, size
    y = ROOM["y1"] - 0.01
    # facing down (-y): CCW seen from below
    return quad((cx - sx / 2, y, cz - sz / 2), (cx + sx / 2, y, cz - sz / 2),
                (cx + sx / 2, y, cz + sz / 2), (cx - sx / 2, y, cz + sz / 2))


def sphere_mesh(centre, radius, nphi=48, ntheta=24):
    c = np.array(centre, dtype=float)
    verts = [c + [0, radius, 0]]
    for i in range(1, ntheta):
        th = math.pi * i / ntheta
        for j in range(nphi):
            ph = 2 * math.pi * j / nphi
            verts.append(c + radius * np.array([math.sin(th) * math.cos(ph), math.cos(th),
                                                -math.sin(th) * math.sin(ph)]))
    verts.append(c - [0, radius, 0])
    ring = lambda i, j: 1 + (i - 1) * nphi + (j % nphi)
    faces = []
    for j in range(nphi):
        faces.append([0, ring(1, j), ring(1, j + 1)])
    for i in range(1, ntheta - 1):
        for j in range(nphi):
            a, b, cc, d = ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)
            faces.append([a, b, cc])
            faces.append([a, cc, d])
    south = len(verts) - 1
    for j in range(nphi):
        faces.append([south, ring(ntheta - 1, j + 1), ring(ntheta - 1, j)])
    # orientation check: outward
    v = np.array(verts)
    for f in faces[:3] + faces[-3:]:
        n = np.cross(v[f[1]] - v[f[0]], v[f[2]] - v[f[0]])
        assert np.dot(n, v[f].mean(axis=0) - c) > 0, "sphere winding"
    return v.tolist(), faces


def cuboid_mesh(centre_floor, size, yaw_deg):
    """Axis-aligned box rotated about +y, standing on the floor, no bottom face, outward CCW."""
    sx, sy, sz = size
    a = math.radians(yaw_deg)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    c = np.array(centre_floor, dtype=float)
    corners = []
    for y in (0.0, sy):
        for x, z in ((-sx / 2, -sz / 2), (sx / 2, -sz / 2), (sx / 2, sz / 2), (-sx / 2, sz / 2)):
            corners.append(c + rot @ np.array([x, y, z]))
    faces = [[4, 7, 6, 5]]  # top (seen from above: CCW)
    for k in range(4):
        a0, a1 = k, (k + 1) % 4
        faces.append([a0, a1, a1 + 4, a0 + 4])
    v = np.array(corners)
    cen = v.mean(axis=0)
    out = []
    for f in faces:
        n = np.cross(v[f[1]] - v[f[0]], v[f[2]] - v[f[0]])
        if np.dot(n, v[f].mean(axis=0) - cen) < 0:
            f = f[::-1]
        out.append([f[0], f[1], f[2]])
        out.append([f[0], f[2], f[3]])
    return v.tolist(), out


# ---------------------------------------------------------------- textures

def smooth_noise(rng, n, cells):
    """Value noise: a random cells×cells grid, bicubic-ish (smoothstep) interpolation to n×n."""
    g = rng.random((cells + 1, cells + 1))
    t = (np.arange(n) + 0.5) / n * cells
    i = np.minimum(t.astype(int), cells - 1)
    f = t - i
    f = f * f * (3 - 2 * f)
    a = g[i][:, i] * (1 - f)[None, :] + g[i][:, i + 1] * f[None, :]
    b = g[i + 1][:, i] * (1 - f)[None, :] + g[i + 1][:, i + 1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def blur(img, r):
    """Separable box blur of radius r texels, applied twice (≈ a tent), clamp at the edges."""
    for _ in range(2):
        for ax in (0, 1):
            pad = [(0, 0)] * img.ndim
            pad[ax] = (r, r)
            p = np.pad(img, pad, mode="edge")
            c = np.cumsum(p, axis=ax, dtype=float)
            c = np.concatenate([np.zeros_like(np.take(c, [0], axis=ax)), c], axis=ax)
            n = img.shape[ax]
            img = (np.take(c, np.arange(2 * r + 1, 2 * r + 1 + n), axis=ax)
                   - np.take(c, np.arange(0, n), axis=ax)) / (2 * r + 1)
    return img


def floor_texture(rng, n=256):
    """Tiles (8 × 8) of slightly different warm colours, dark grout lines, a smooth stain."""
    y, x = np.mgrid[0:n, 0:n]
    tiles = 8
    tid = (y * tiles // n) * tiles + (x * tiles // n)
    base = np.array([0.62, 0.5, 0.36])
    tint = 1.0 + 0.18 * (rng.random((tiles * tiles, 3)) - 0.5)
    img = base[None, None, :] * tint[tid]
    s = n // tiles
    grout = ((x % s) < 2) | ((y % s) < 2)
    img[grout] = [0.2, 0.19, 0.18]
    img = blur(img, 1)
    stain = smooth_noise(rng, n, 5)
    img *= (0.75 + 0.35 * stain)[:, :, None]
    return np.clip(img, 0.03, 0.95)


def poster_texture(rng, n=128):
    """A smooth 'painting': colour gradients, three soft discs and a dark frame."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    img = np.stack([0.25 + 0.5 * x, 0.3 + 0.4 * (1 - y), 0.5 + 0.3 * np.sin(3 * x + 2 * y)], axis=-1)
    for (cx, cy, r, col) in ((0.3, 0.35, 0.18, (0.85, 0.8, 0.2)), (0.7, 0.6, 0.22, (0.15, 0.55, 0.25)),
                             (0.45, 0.75, 0.12, (0.8, 0.2, 0.15))):
        d = np.sqrt((x - cx) ** 2 + (y - cy) ** 2)
        a = np.clip((r - d) / 0.02 + 0.5, 0, 1)[:, :, None]
        img = img * (1 - a) + np.array(col) * a
    frame = (x < 0.05) | (x > 0.95) | (y < 0.05) | (y > 0.95)
    img[frame] = [0.08, 0.07, 0.06]
    img = blur(img, 1)
    img *= (0.9 + 0.2 * smooth_noise(rng, n, 4))[:, :, None]
    return np.clip(img, 0.03, 0.95)


# ---------------------------------------------------------------- cameras

def look_at(origin, target, up=(0, 1, 0)):
    """Mitsuba's look_at: columns left, up, forward, origin (camera looks along local +z)."""
    o, t, u = (np.array(v, dtype=float) for v in (origin, target, up))
    f = t - o
    f /= np.linalg.norm(f)
    left = np.cross(u, f)
    left /= np.linalg.norm(left)
    up2 = np.cross(f, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, up2, f, o
    return m


def fmt(v):
    return " ".join(f"{x:.9g}" for x in v)


def write_scene(out: Path, objects, cams, max_depth):
    lines = ['<scene version="3.0.0">',
             "    <!-- room_multiview.py: independent de-lighting data set -->",
             '    <integrator type="path">',
             f'        <integer name="max_depth" value="{max_depth}"/>',
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
                  '        <boolean name="face_normals" value="true"/>',
                  '        <bsdf type="diffuse">']
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
    lines.append("</scene>")
    (out / "scene.xml").write_text("\n".join(lines) + "\n")


def write_transforms(out: Path, cams):
    frames = []
    for c in cams:
        m = np.array(c["to_world"])
        c2w = m.copy()
        c2w[:3, 0], c2w[:3, 2] = -m[:3, 0], -m[:3, 2]  # OpenGL: +x right, looks along -z
        frames.append({"file_path": c["image"], "transform_matrix": c2w.tolist(),
                       "w": c["width"], "h": c["height"],
                       "camera_angle_x": math.radians(c["fov_deg"])})
    j = {"convention": "camera-to-world, OpenGL camera axes (+x right, +y up, looks along -z); "
                       "camera_angle_x = full horizontal field of view in radians; images are "
                       "linear HDR radiance (EXR); pixel centres at (i+0.5, j+0.5), row 0 on top",
         "frames": frames}
    (out / "transforms.json").write_text(json.dumps(j, indent=1) + "\n")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--pass-spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--max-depth", type=int, default=-1)
    ap.add_argument("--ring", type=int, default=0)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--height", type=int, default=3000)
    a = ap.parse_args()
    if a.variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi
    mi.set_variant(a.variant)

    out = a.out
    for d in ("meshes", "textures", "views"):
        (out / d).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2026)
    objects = []
    for name, (verts, uvs, normals, faces) in room_meshes().items():
        textured = name in ("floor", "poster")
        ntri = write_obj(out / "meshes" / f"{name}.obj", name, verts, faces,
                         uvs if textured else None, normals)
        o = {"name": name, "obj": f"meshes/{name}.obj", "n_triangles": ntri}
        if textured:
            o["albedo_texture"] = f"textures/{name}_albedo.exr"
        else:
            o["albedo_rgb"] = ALBEDO[name]
        objects.append(o)
    tex = {"floor": floor_texture(rng), "poster": poster_texture(rng)}
    for name, img in tex.items():
        mi.Bitmap(img.astype(np.float32)).write(str(out / "textures" / f"{name}_albedo.exr"))
    v, f = sphere_mesh((0.55, 0.36, -0.25), 0.35)
    objects.append({"name": "sphere", "obj": "meshes/sphere.obj", "albedo_rgb": ALBEDO["sphere"],
                    "n_triangles": write_obj(out / "meshes/sphere.obj", "sphere", v, f)})
    v, f = cuboid_mesh((-0.65, 0.0, 0.15), (0.45, 0.65, 0.35), 30.0)
    objects.append({"name": "pedestal", "obj": "meshes/pedestal.obj", "albedo_rgb": ALBEDO["pedestal"],
                    "n_triangles": write_obj(out / "meshes/pedestal.obj", "pedestal", v, f)})
    for name, centre, size, rad in LIGHTS:
        verts, uvs, normals, faces = light_mesh(centre, size)
        objects.append({"name": name, "obj": f"meshes/{name}.obj", "albedo_rgb": [0.78, 0.78, 0.78],
                        "radiance_rgb": rad, "area": size[0] * size[1],
                        "n_triangles": write_obj(out / "meshes" / f"{name}.obj", name, verts, faces,
                                                 None, normals)})
    cams = []
    layout = ring_cameras(a.ring, a.width, a.height) if a.ring > 0 else CAMERAS
    for k, (o, t, fov, w, h) in enumerate(layout):
        cams.append({"index": k, "origin": o, "target": t, "fov_deg": fov,
                     "width": max(8, round(w * a.scale)), "height": max(8, round(h * a.scale)),
                     "to_world": look_at(o, t).tolist(), "image": f"views/view_{k:02d}.exr"})
    write_scene(out, objects, cams, a.max_depth)
    write_transforms(out, cams)

    scene = mi.load_file(str(out / "scene.xml"))
    passes = max(1, a.spp // a.pass_spp)
    noise, timings = {}, {}
    for k, c in enumerate(cams):
        t0 = time.time()
        acc = None
        acc2 = None
        for p in range(passes):
            img = np.array(mi.render(scene, sensor=k, spp=a.pass_spp, seed=1000 * k + p), dtype=np.float64)
            acc = img if acc is None else acc + img
            acc2 = img * img if acc2 is None else acc2 + img * img
        mean = acc / passes
        var = np.maximum(acc2 / passes - mean * mean, 0.0) / max(1, passes - 1)
        se = np.sqrt(var)
        mi.Bitmap(mean.astype(np.float32)).write(str(out / c["image"]))
        mi.Bitmap(se.astype(np.float32)).write(str(out / c["image"].replace(".exr", "_stderr.exr")))
        lum = mean.mean(axis=2)
        ok = lum > 1e-3
        rel = (se.mean(axis=2)[ok] / lum[ok])
        noise[f"view_{k:02d}"] = {"median_rel_stderr": float(np.median(rel)),
                                  "p95_rel_stderr": float(np.percentile(rel, 95))}
        timings[f"view_{k:02d}"] = round(time.time() - t0, 2)
        print(f"view {k}: {c['width']}x{c['height']} {passes * a.pass_spp} spp, {timings[f'view_{k:02d}']} s, "
              f"median rel stderr {noise[f'view_{k:02d}']['median_rel_stderr']:.4f}", flush=True)
    truth = {"generator": "bench/scripts/room_multiview.py (Mitsuba 3)", "mitsuba_version": mi.__version__,
             "variant": a.variant, "room": ROOM, "objects": objects, "cameras": cams,
             "integrator": {"type": "path", "max_depth": a.max_depth, "rr_depth": 5, "hide_emitters": False},
             "sampling": {"spp": passes * a.pass_spp, "passes": passes, "pixel_filter": "box"},
             "noise": noise, "timings_seconds": timings}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(out / "scene.xml")


if __name__ == "__main__":
    main()
