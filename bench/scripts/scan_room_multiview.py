#!/usr/bin/env python3
"""Independent multi-view HDR data set for the de-lighting of a scanned object (issue 17):
a closed room with a high-poly object given WITHOUT UVs, rendered by Mitsuba 3.

Scene (units: metres, right-handed, +y up): a closed room 3.6 × 1.6 × 3.2 (x ∈ [-1.8, 1.8],
y ∈ [0, 1.6], z ∈ [-1.6, 1.6]); a textured floor (256² bitmap albedo: tiles with grout and a
stain, `room_multiview.floor_texture`), four walls and a ceiling of constant albedos; the
"scan": an icosahedron subdivided 6 times (20 · 4⁶ = 81 920 triangles), each vertex moved
radially by `1 + 0.08 · fbm(p)` (four octaves of value noise), scaled to a 0.7 × 0.8 × 0.7 egg,
its lowest point 1 cm below the floor (the object stands in the floor: a contact curve); a
rotated cuboid standing on the floor (a box on a textured floor: straight contact edges); two
ceiling area lights of different size and colour. Eight 256² pinhole cameras around the
object at different heights and distances, one of them looking down onto the floor behind the
box (`--placement original`: the first data set's views, which leave that floor unseen).
Every surface is Lambertian (Mitsuba `diffuse`), every mesh uses face normals.

The scan's albedo is a procedural colour field of the undisplaced direction `d` (smooth colour
patches from 3D value noise, soft-edged painted bands and spots, fine stone-like modulation),
sampled on a 1024 × 512 equirectangular map. Only the truth has UVs: spherical
(`u` = longitude / 2π, `v` = colatitude / π of `d`, triangles across the longitude seam get
vertex copies with `u + 1`, `repeat` wrap; pole vertices one copy per triangle with `u` the mean
of the other two corners). The input scene gives the same triangles (same order, same
positions) without UVs and with a constant placeholder albedo.

Writes into OUT:
  scene.xml           the INPUT scene: scan as `meshes/scan.obj` without UVs (placeholder
                      albedo), everything else as in the truth; sensors = the eight views
  truth_scene.xml     the scene the views were rendered from (`meshes/scan_uv.obj` with the
                      spherical UVs, `textures/scan_albedo.exr`)
  meshes/*.obj        geometry
  textures/*.exr      true albedo textures (float32, linear)
  views/view_XX.exr   linear HDR radiance, RGB float32 (box pixel filter, SPP samples/pixel)
  views/view_XX_stderr.exr  per-pixel standard error (scatter of the per-pass means)
  transforms.json     NeRF-style cameras (OpenGL axes), what `opal delight --views` reads
  truth.json          true albedos, lights, cameras, noise summary, timings

Usage: bench/.venv/bin/python bench/scripts/scan_room_multiview.py OUT [--spp 1024]
       [--pass-spp 64] [--variant llvm_ad_rgb] [--scale 1.0] [--levels 6]
       [--placement cover|original]
The acceptance on it: `OPAL_SCAN_ROOM_DIR=OUT cargo test --release -p opal-inverse --test
delight_scan_room -- --ignored --nocapture` (crates/opal-inverse/tests/delight_scan_room.rs).
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
import room_multiview as rm  # noqa: E402  (shared writers, textures, cameras)

ROOM = dict(x0=-1.8, x1=1.8, y0=0.0, y1=1.6, z0=-1.6, z1=1.6)

ALBEDO = {
    "ceiling": [0.8, 0.8, 0.78],
    "back_wall": [0.55, 0.6, 0.68],
    "front_wall": [0.68, 0.62, 0.5],
    "left_wall": [0.62, 0.38, 0.22],
    "right_wall": [0.32, 0.52, 0.4],
    "box": [0.25, 0.32, 0.6],
}

LIGHTS = [
    # name, centre (x, z), size (x, z), radiance RGB
    ("light_warm", (-0.6, -0.4), (0.7, 0.45), [10.0, 8.0, 5.0]),
    ("light_cool", (0.9, 0.7), (0.3, 0.3), [14.0, 17.0, 24.0]),
]

SCAN_CENTRE = (0.3, -0.15)  # (x, z) of the scan's axis
SCAN_HALF = (0.35, 0.4, 0.35)  # half extents of the egg before displacement
BOX = ((-0.75, 0.0, 0.35), (0.4, 0.5, 0.3), 25.0)  # floor centre, size, yaw (deg)

# origin, target (256² each, fov_x 60°)
CAMERAS = [
    ((0.3, 0.75, 1.05), (0.3, 0.35, -0.15)),
    ((1.35, 0.55, 0.55), (0.3, 0.35, -0.15)),
    ((1.3, 0.95, -1.0), (0.3, 0.3, -0.15)),
    ((0.2, 0.6, -1.35), (0.3, 0.35, -0.15)),
    ((-0.85, 1.1, -0.9), (0.2, 0.3, -0.1)),
    ((-1.2, 0.5, 0.95), (0.0, 0.3, -0.05)),
    ((-0.3, 1.35, 0.35), (0.25, 0.25, -0.15)),
    ((0.95, 1.3, 0.3), (0.3, 0.3, -0.15)),
]
# `--placement cover` (the default): view 6 looks down from near the ceiling over the scan
# onto the box and the floor between the box and the left wall. With the original view 6 no
# camera sees that floor (9 338 of its texels, lit, behind the box for every view) although
# it is what lights the box's face towards the left wall; a capture for de-lighting covers
# the surfaces that light the objects. The new view still sees the scan (70 087 of its
# triangles are seen by some view, 70 311 with the original placement).
COVER_VIEW = (6, ((0.7, 1.5, -0.4), (-0.5, 0.05, 0.45)))
FOV = 60.0
RES = 256


# ---------------------------------------------------------------- noise

def _hash(ix, iy, iz, seed):
    """Integer lattice hash to [-1, 1] (vectorised, uint32 arithmetic)."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.uint32) * np.uint32(0x8DA6B343)) ^ (iy.astype(np.uint32) * np.uint32(0xD8163841)) \
            ^ (iz.astype(np.uint32) * np.uint32(0xCB1AB31F)) ^ np.uint32((seed * 0x2545F491) & 0xFFFFFFFF)
        h ^= h >> np.uint32(15)
        h *= np.uint32(0x2C1B3C6D)
        h ^= h >> np.uint32(12)
        h *= np.uint32(0x297A2D39)
        h ^= h >> np.uint32(15)
    return (h >> np.uint32(8)).astype(np.float64) / float(1 << 23) - 1.0


def value_noise(p, seed):
    """Smooth 3D value noise in [-1, 1] of points p (N × 3), quintic interpolation."""
    f = np.floor(p)
    i = f.astype(np.int64)
    t = p - f
    s = t * t * t * (t * (t * 6 - 15) + 10)
    acc = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (s[:, 0] if dx else 1 - s[:, 0]) * (s[:, 1] if dy else 1 - s[:, 1]) \
                    * (s[:, 2] if dz else 1 - s[:, 2])
                acc = acc + w * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return acc


def fbm(p, octaves, seed):
    total, amp, norm, freq = 0.0, 1.0, 0.0, 1.0
    for o in range(octaves):
        total = total + amp * value_noise(p * freq, seed + o)
        norm += amp
        amp *= 0.5
        freq *= 2.0
    return total / norm


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


# ---------------------------------------------------------------- the scan

def icosphere(levels):
    g = (1 + 5 ** 0.5) / 2
    verts = [(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g), (0, -1, -g),
             (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)]
    verts = [np.array(v, float) / np.linalg.norm(v) for v in verts]
    tris = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
            [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
            [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    for _ in range(levels):
        cache = {}

        def mid(a, b):
            k = (min(a, b), max(a, b))
            if k not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[k] = len(verts) - 1
            return cache[k]

        new = []
        for a, b, c in tris:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        tris = new
    return np.array(verts), np.array(tris, dtype=np.int64)


def scan_mesh(levels):
    """Unit directions, placed positions, triangles (outward CCW)."""
    d, tris = icosphere(levels)
    r = 1.0 + 0.08 * fbm(d * 2.2 + 3.7, 4, 11)
    pos = d * r[:, None] * np.array(SCAN_HALF)
    pos += np.array([SCAN_CENTRE[0], -0.01 - pos[:, 1].min(), SCAN_CENTRE[1]])
    n = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    out = np.einsum("ij,ij->i", n, pos[tris].mean(axis=1) - pos.mean(axis=0))
    assert (out > 0).mean() > 0.999, "scan winding"
    return d, pos, tris


def scan_albedo_of(d):
    """The true albedo (linear RGB) of the unit directions d (N × 3)."""
    palette = np.array([[0.75, 0.62, 0.42], [0.35, 0.55, 0.7], [0.7, 0.3, 0.25], [0.4, 0.6, 0.3]])
    w = np.stack([np.exp(3.0 * fbm(d * 1.7 + 10 * k, 3, 30 + k)) for k in range(4)], axis=1)
    col = (w / w.sum(axis=1, keepdims=True)) @ palette
    # painted bands: soft edges ~1.2 % of the radius wide
    a = np.array([0.3, 0.85, 0.42])
    a /= np.linalg.norm(a)
    band = np.sin(9.0 * (d @ a) + 1.5 * fbm(d * 3 + 5, 2, 50))
    m = smoothstep(0.55, 0.75, band)
    col = col * (1 - m[:, None]) + np.array([0.88, 0.82, 0.7]) * m[:, None]
    # dark spots
    spots = fbm(d * 6.0 + 1.3, 2, 60)
    ms = smoothstep(0.32, 0.42, spots)
    col = col * (1 - ms[:, None]) + np.array([0.12, 0.1, 0.14]) * ms[:, None]
    # stone-like fine modulation
    col *= (0.88 + 0.12 * fbm(d * 14.0, 3, 70))[:, None]
    return np.clip(col, 0.03, 0.92)


def scan_texture(w=1024, h=512):
    """Equirectangular map of scan_albedo_of: row 0 = v 0 (top, colatitude 0)."""
    v, u = np.mgrid[0:h, 0:w]
    th = (v + 0.5) / h * math.pi
    ph = (u + 0.5) / w * 2 * math.pi
    # inverse of u = atan2(z, x) / 2π, v = acos(y) / π
    d = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], axis=-1).reshape(-1, 3)
    return scan_albedo_of(d).reshape(h, w, 3)


def spherical_uv_split(d, tris):
    """Per-corner spherical UVs split at the seam and poles; returns (vertex ids, uvs, faces)."""
    u = np.arctan2(d[:, 2], d[:, 0]) / (2 * math.pi)
    u = np.where(u < 0, u + 1, u)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / math.pi
    pole = (np.abs(d[:, 0]) < 1e-9) & (np.abs(d[:, 2]) < 1e-9)
    ids, uvs, faces, seen = [], [], [], {}
    for t in tris:
        cu = [u[i] for i in t]
        others = [cu[j] for j in range(3) if not pole[t[j]]]
        if max(others) - min(others) > 0.5:
            cu = [x + 1 if (not pole[t[j]] and x < 0.5) else x for j, x in enumerate(cu)]
        for j in range(3):
            if pole[t[j]]:
                cu[j] = sum(cu[k] for k in range(3) if not pole[t[k]]) / sum(1 for k in range(3) if not pole[t[k]])
        f = []
        for j in range(3):
            key = (int(t[j]), cu[j])
            if key not in seen:
                seen[key] = len(ids)
                ids.append(int(t[j]))
                uvs.append((cu[j], 1.0 - v[t[j]]))  # OBJ: v = 0 at the image bottom
            f.append(seen[key])
        faces.append(f)
    return ids, uvs, faces


# ---------------------------------------------------------------- room

def room_meshes():
    r = ROOM
    x0, x1, y0, y1, z0, z1 = r["x0"], r["x1"], r["y0"], r["y1"], r["z0"], r["z1"]
    q = rm.quad
    return {
        "floor": q((x0, y0, z1), (x1, y0, z1), (x1, y0, z0), (x0, y0, z0)),
        "ceiling": q((x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)),
        "back_wall": q((x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)),
        "front_wall": q((x1, y0, z1), (x0, y0, z1), (x0, y1, z1), (x1, y1, z1)),
        "left_wall": q((x0, y0, z1), (x0, y0, z0), (x0, y1, z0), (x0, y1, z1)),
        "right_wall": q((x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)),
    }


def light_mesh(centre, size):
    (cx, cz), (sx, sz) = centre, size
    y = ROOM["y1"] - 0.01
    return rm.quad((cx - sx / 2, y, cz - sz / 2), (cx + sx / 2, y, cz - sz / 2),
                   (cx + sx / 2, y, cz + sz / 2), (cx - sx / 2, y, cz + sz / 2))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--pass-spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--levels", type=int, default=6)
    ap.add_argument("--max-depth", type=int, default=-1)
    ap.add_argument("--placement", choices=("cover", "original"), default="cover",
                    help="cameras: 'original' = the first data set's eight views (the floor behind "
                         "the box unseen), 'cover' = view 6 replaced by one that sees it")
    a = ap.parse_args()
    if a.variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = rm.find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    import mitsuba as mi
    mi.set_variant(a.variant)

    out = a.out
    for sub in ("meshes", "textures", "views"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2017)
    objects = []
    for name, (verts, uvs, normals, faces) in room_meshes().items():
        textured = name == "floor"
        ntri = rm.write_obj(out / "meshes" / f"{name}.obj", name, verts, faces, uvs if textured else None,
                            normals)
        o = {"name": name, "obj": f"meshes/{name}.obj", "n_triangles": ntri}
        if textured:
            o["albedo_texture"] = "textures/floor_albedo.exr"
        else:
            o["albedo_rgb"] = ALBEDO[name]
        objects.append(o)
    mi.Bitmap(rm.floor_texture(rng).astype(np.float32)).write(str(out / "textures/floor_albedo.exr"))

    t0 = time.time()
    d, pos, tris = scan_mesh(a.levels)
    n_scan = rm.write_obj(out / "meshes/scan.obj", "scan", pos.tolist(), tris.tolist())
    ids, uvs, faces = spherical_uv_split(d, tris)
    rm.write_obj(out / "meshes/scan_uv.obj", "scan", pos[ids].tolist(), faces, uvs)
    mi.Bitmap(scan_texture().astype(np.float32)).write(str(out / "textures/scan_albedo.exr"))
    print(f"scan: {n_scan} triangles, {len(pos)} vertices ({len(ids)} with the UV split), "
          f"{time.time() - t0:.1f} s", flush=True)
    scan = {"name": "scan", "obj": "meshes/scan.obj", "truth_obj": "meshes/scan_uv.obj",
            "albedo_texture": "textures/scan_albedo.exr", "wrap_mode": "repeat", "n_triangles": n_scan,
            "bounds": [pos.min(axis=0).tolist(), pos.max(axis=0).tolist()]}
    v, f = rm.cuboid_mesh(*BOX)
    box = {"name": "box", "obj": "meshes/box.obj", "albedo_rgb": ALBEDO["box"],
           "n_triangles": rm.write_obj(out / "meshes/box.obj", "box", v, f)}
    objects += [scan, box]
    for name, centre, size, rad in LIGHTS:
        verts, uvs, normals, faces = light_mesh(centre, size)
        objects.append({"name": name, "obj": f"meshes/{name}.obj", "albedo_rgb": [0.78, 0.78, 0.78],
                        "radiance_rgb": rad, "area": size[0] * size[1],
                        "n_triangles": rm.write_obj(out / "meshes" / f"{name}.obj", name, verts, faces,
                                                    None, normals)})
    res = max(8, round(RES * a.scale))
    cams = []
    placement = list(CAMERAS)
    if a.placement == "cover":
        placement[COVER_VIEW[0]] = COVER_VIEW[1]
    for k, (o, t) in enumerate(placement):
        cams.append({"index": k, "origin": o, "target": t, "fov_deg": FOV, "width": res, "height": res,
                     "to_world": rm.look_at(o, t).tolist(), "image": f"views/view_{k:02d}.exr"})
    # input scene: the scan without UVs and a placeholder albedo
    inp = [dict(o) for o in objects]
    for o in inp:
        if o["name"] == "scan":
            del o["albedo_texture"]
            o["albedo_rgb"] = [0.5, 0.5, 0.5]
    rm.write_scene(out, inp, cams, a.max_depth)
    # truth scene: the scan with UVs and its texture (wrap: repeat across the seam)
    tru = [dict(o, obj=o.get("truth_obj", o["obj"])) for o in objects]
    rm.write_scene(out, tru, cams, a.max_depth)
    xml = (out / "scene.xml").read_text().replace("textures/scan_albedo.exr\"/>\n"
                                                  "                <string name=\"filter_type\" value=\"bilinear\"/>\n"
                                                  "                <string name=\"wrap_mode\" value=\"clamp\"/>",
                                                  "textures/scan_albedo.exr\"/>\n"
                                                  "                <string name=\"filter_type\" value=\"bilinear\"/>\n"
                                                  "                <string name=\"wrap_mode\" value=\"repeat\"/>")
    assert "wrap_mode\" value=\"repeat\"" in xml
    (out / "truth_scene.xml").write_text(xml)
    rm.write_scene(out, inp, cams, a.max_depth)
    assert "scan_uv" not in (out / "scene.xml").read_text()
    rm.write_transforms(out, cams)

    scene = mi.load_file(str(out / "truth_scene.xml"))
    passes = max(1, a.spp // a.pass_spp)
    noise, timings = {}, {}
    for k, c in enumerate(cams):
        t0 = time.time()
        acc = acc2 = None
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
        rel = se.mean(axis=2)[ok] / lum[ok]
        noise[f"view_{k:02d}"] = {"median_rel_stderr": float(np.median(rel)),
                                  "p95_rel_stderr": float(np.percentile(rel, 95))}
        timings[f"view_{k:02d}"] = round(time.time() - t0, 2)
        print(f"view {k}: {c['width']}x{c['height']} {passes * a.pass_spp} spp, {timings[f'view_{k:02d}']} s, "
              f"median rel stderr {noise[f'view_{k:02d}']['median_rel_stderr']:.4f}", flush=True)
    truth = {"generator": "bench/scripts/scan_room_multiview.py (Mitsuba 3)", "mitsuba_version": mi.__version__,
             "variant": a.variant, "placement": a.placement, "room": ROOM, "objects": objects, "cameras": cams,
             "integrator": {"type": "path", "max_depth": a.max_depth, "rr_depth": 5, "hide_emitters": False},
             "sampling": {"spp": passes * a.pass_spp, "passes": passes, "pixel_filter": "box"},
             "noise": noise, "timings_seconds": timings}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(out / "scene.xml")


if __name__ == "__main__":
    main()
