"""Acceptance scenes for Mitsuba's metal, coating and sheet BSDFs and the disk/cylinder shapes.

Writes, for each plugin, a small box scene (a Cornell-like room: white floor, ceiling and
back wall, red left and green right wall, a square ceiling light) holding one test object, as
`crates/opal/tests/data/mitsuba_materials/<name>/scene.xml`, and renders it with Mitsuba 3
(`llvm_ad_rgb`, box filter, `path` with max_depth 8) in 16 independent passes:
`ref.exr` (mean, float32) and `ref_stderr.exr` (standard error of the mean from the scatter of
the passes, float16). Opal's `tests/mitsuba_materials.rs` renders the same XML and compares
16×16-pixel block means by a z-test (the Cornell box acceptance of `tests/mitsuba_cbox.rs`).

Scenes: conductor (gold sphere), roughconductor (anisotropic GGX copper sphere), plastic (blue
sphere), roughplastic (Beckmann, bitmap-textured diffuse reflectance on a sphere),
thindielectric (a tilted thin pane in front of the camera), disk (a disk ceiling light and a
tilted diffuse disk), cylinder (a diffuse cylinder from p0/p1/radius and a flipped one),
instance (a shapegroup of a sphere mesh and a cube, instanced three times with uniform,
non-uniform and rotated transforms).

Usage: bench/.venv/bin/python bench/scripts/mitsuba_materials_scenes.py [--spp 1024] [--res 96]
"""
import argparse
import os
import numpy as np
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
ROOT = os.path.join(os.path.dirname(__file__), "..", "..", "crates", "opal", "tests", "data", "mitsuba_materials")

ROOM = """
    <shape type="rectangle" id="floor"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
    <shape type="rectangle" id="ceiling"><transform name="to_world"><rotate x="1" angle="90"/><translate y="1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
    <shape type="rectangle" id="back"><transform name="to_world"><translate z="-1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
    <shape type="rectangle" id="front"><transform name="to_world"><rotate y="1" angle="180"/><translate z="3.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf></shape>
    <shape type="rectangle" id="left"><transform name="to_world"><scale x="2.1"/><rotate y="1" angle="90"/><translate x="-1" z="1.1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.65, 0.1, 0.08"/></bsdf></shape>
    <shape type="rectangle" id="right"><transform name="to_world"><scale x="2.1"/><rotate y="1" angle="-90"/><translate x="1" z="1.1"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.55, 0.1"/></bsdf></shape>
"""
LIGHT = """
    <shape type="rectangle" id="light"><transform name="to_world"><scale value="0.45"/><rotate x="1" angle="90"/><translate y="0.999"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="6, 5.5, 4.5"/></emitter></shape>
"""
# floor and ceiling span z in [-1, 1]; the side walls and a front wall behind the camera reach z = 3.2


def scene(body, res, spp, light=LIGHT):
    # front wall is only one-sided (normal towards -z): the camera at z = 3 sees through its back
    return f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="box"/></film>
    </sensor>
{ROOM}{light}{body}
</scene>
"""


# The test spheres are one shared PLY mesh (64 × 32 latitude-longitude grid, vertex normals, uv =
# (φ/2π, θ/π)) so that both renderers see the same geometry: a delta reflection in a
# tessellated sphere (Opal's `sphere`) and in Mitsuba's analytic one differ at the highlight.
SPHERE = ('<shape type="ply"><string name="filename" value="../sphere.ply"/><transform name="to_world">'
          '<scale value="0.55"/><translate y="-0.45"/></transform>{}</shape>')


def write_sphere_ply(path, n_phi=64, n_theta=32):
    import struct
    verts, faces = [], []
    for j in range(n_theta + 1):
        t = np.pi * j / n_theta
        for i in range(n_phi + 1):
            ph = 2 * np.pi * i / n_phi
            p = (np.sin(t) * np.cos(ph), np.sin(t) * np.sin(ph), np.cos(t))
            verts.append((*p, *p, i / n_phi, j / n_theta))
    idx = lambda j, i: j * (n_phi + 1) + i
    for j in range(n_theta):
        for i in range(n_phi):
            a, b, c, d = idx(j, i), idx(j, i + 1), idx(j + 1, i + 1), idx(j + 1, i)
            if j + 1 < n_theta:
                faces.append((a, d, c))
            if j > 0:
                faces.append((a, c, b))
    with open(path, "wb") as f:
        f.write((f"ply\nformat binary_little_endian 1.0\nelement vertex {len(verts)}\n"
                 "property float x\nproperty float y\nproperty float z\nproperty float nx\n"
                 "property float ny\nproperty float nz\nproperty float u\nproperty float v\n"
                 f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode())
        for v in verts:
            f.write(struct.pack("<8f", *v))
        for t in faces:
            f.write(struct.pack("<B3i", 3, *t))
SCENES = {
    "conductor": SPHERE.format('<bsdf type="conductor"><string name="material" value="Au"/></bsdf>'),
    "roughconductor": SPHERE.format(
        '<bsdf type="roughconductor"><string name="material" value="Cu"/><string name="distribution" value="ggx"/>'
        '<float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/></bsdf>'),
    "plastic": SPHERE.format(
        '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.1, 0.25, 0.6"/></bsdf>'),
    "roughplastic": SPHERE.format(
        '<bsdf type="roughplastic"><float name="alpha" value="0.2"/><float name="int_ior" value="1.6"/>'
        '<texture type="bitmap" name="diffuse_reflectance"><string name="filename" value="checker.exr"/>'
        '<string name="filter_type" value="nearest"/></texture></bsdf>'),
    "thindielectric": SPHERE.format('<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.2"/></bsdf>')
    + '<shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate y="1" angle="30"/>'
      '<translate x="0.2" y="0.1" z="1.2"/></transform><bsdf type="thindielectric"><float name="int_ior" value="1.7"/></bsdf></shape>',
    "disk": '<shape type="disk"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="-60"/>'
            '<rotate y="1" angle="25"/><translate y="-0.4"/></transform>'
            '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.7"/></bsdf></shape>',
    "cylinder": '<shape type="cylinder"><point name="p0" value="-0.3, -1, -0.2"/><point name="p1" value="0.1, 0.2, 0.1"/>'
                '<float name="radius" value="0.25"/><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.2"/></bsdf></shape>'
                '<shape type="cylinder"><point name="p0" value="0.55, -1, 0.3"/><point name="p1" value="0.55, -0.3, 0.3"/>'
                '<float name="radius" value="0.2"/><boolean name="flip_normals" value="true"/>'
                '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.6, 0.6"/></bsdf></bsdf></shape>',
    "instance": '<shape type="shapegroup" id="group">'
                '<shape type="ply"><string name="filename" value="../sphere.ply"/><transform name="to_world">'
                '<scale value="0.6"/><translate y="1.1"/></transform>'
                '<bsdf type="diffuse"><rgb name="reflectance" value="0.75, 0.6, 0.2"/></bsdf></shape>'
                '<shape type="cube"><transform name="to_world"><scale value="0.5"/></transform>'
                '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.35, 0.7"/></bsdf></shape></shape>'
                '<shape type="instance" id="a"><ref id="group"/><transform name="to_world"><scale value="0.3"/>'
                '<translate x="-0.5" y="-0.85" z="0.2"/></transform></shape>'
                '<shape type="instance" id="b"><ref id="group"/><transform name="to_world">'
                '<scale x="0.35" y="0.22" z="0.25"/><rotate y="1" angle="35"/><translate x="0.45" y="-0.89" z="-0.2"/></transform></shape>'
                '<shape type="instance" id="c"><ref id="group"/><transform name="to_world"><scale value="0.2"/>'
                '<rotate x="1" angle="25"/><rotate z="1" angle="-15"/><translate x="0.05" y="0.15" z="-0.45"/></transform></shape>',
}
# the disk scene lights the room with a disk light instead of the square one
DISK_LIGHT = """
    <shape type="disk" id="light"><transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/><translate y="0.999"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="8, 7.3, 6"/></emitter></shape>
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--passes", type=int, default=16)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--only", default=None)
    a = ap.parse_args()
    write_sphere_ply(os.path.join(ROOT, "sphere.ply"))
    for name, body in SCENES.items():
        if a.only and name != a.only:
            continue
        d = os.path.join(ROOT, name)
        os.makedirs(d, exist_ok=True)
        if name == "roughplastic":
            n = 8
            c = np.zeros((n, n, 3), np.float32)
            for y in range(n):
                for x in range(n):
                    c[y, x] = [0.7, 0.15, 0.1] if (x + y) % 2 == 0 else [0.15, 0.5, 0.7]
            mi.Bitmap(c).write(os.path.join(d, "checker.exr"))
        light = DISK_LIGHT if name == "disk" else LIGHT
        xml = scene(body, a.res, 64, light)
        with open(os.path.join(d, "scene.xml"), "w") as f:
            f.write(xml)
        sc = mi.load_file(os.path.join(d, "scene.xml"))
        per = a.spp // a.passes
        acc = acc2 = None
        for p in range(a.passes):
            img = np.array(mi.render(sc, spp=per, seed=7919 * p + 1), dtype=np.float64)
            acc = img if acc is None else acc + img
            acc2 = img * img if acc2 is None else acc2 + img * img
        mean = acc / a.passes
        se = np.sqrt(np.maximum(acc2 / a.passes - mean * mean, 0.0) / (a.passes - 1))
        mi.Bitmap(mean.astype(np.float32)).write(os.path.join(d, "ref.exr"))
        mi.Bitmap(se.astype(np.float16)).write(os.path.join(d, "ref_stderr.exr"))
        print(f"{name}: mean {mean.mean(axis=(0, 1))}, median rel stderr "
              f"{np.median(se.mean(axis=2) / np.maximum(mean.mean(axis=2), 1e-6)):.4f}", flush=True)


if __name__ == "__main__":
    main()
