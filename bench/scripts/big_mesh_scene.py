"""Writes a scene with one N-triangle binary-PLY mesh (a bumpy height-field grid), for the
absurd-input check "a 10^7-triangle mesh renders or gives a clear error" (issue 21).

    bench/.venv/bin/python bench/scripts/big_mesh_scene.py OUTDIR [TRIANGLES=10000000]
    /usr/bin/time -v target/release/opal render OUTDIR/scene.xml -o OUTDIR/out.exr --spp 4

Only numpy is needed. The grid spans [-1, 1]² in z = 0 with a small sine bump, seen by a
64² camera from above, lit by a constant-radiance quad.
"""
import math
import sys
from pathlib import Path

import numpy as np


def main():
    out = Path(sys.argv[1])
    tris = int(sys.argv[2]) if len(sys.argv) > 2 else 10_000_000
    n = int(math.ceil(math.sqrt(tris / 2))) + 1  # vertices per side
    out.mkdir(parents=True, exist_ok=True)
    u = np.linspace(-1.0, 1.0, n, dtype=np.float32)
    x, y = np.meshgrid(u, u)
    z = (0.02 * np.sin(40 * x) * np.cos(40 * y)).astype(np.float32)
    verts = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1).astype("<f4")
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel().astype("<i4")
    quads = np.stack([a, a + 1, a + n + 1, a + n], axis=1)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rec["n"] = 3
    rec["v"] = faces
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    with open(out / "mesh.ply", "wb") as f:
        f.write(header.encode())
        f.write(verts.tobytes())
        f.write(rec.tobytes())
    (out / "scene.xml").write_text(
        """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/></film>
  </sensor>
  <shape type="ply"><string name="filename" value="mesh.ply"/><bsdf type="diffuse"/></shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/><translate value="0, 0, 2.5"/></transform>
    <emitter type="area"><rgb name="radiance" value="5"/></emitter>
  </shape>
</scene>
"""
    )
    print(f"{len(faces)} triangles, {len(verts)} vertices -> {out}")


if __name__ == "__main__":
    main()
