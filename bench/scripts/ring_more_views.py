"""More ring cameras for a room of `room_multiview.py --ring N` (issue 23: 50+ views of 12 MP).

    python bench/scripts/ring_more_views.py SRC OUT [--extra 26] [--width 4000] [--height 3000]

SRC is a data set of `room_multiview.py OUT --ring N ...` (its scene.xml, transforms.json,
truth.json, meshes/ and textures/). OUT gets a scene.xml, transforms.json and truth.json with
SRC's N cameras followed by EXTRA more on the same two rings (heights 0.55 / 1.15 m, the same
ellipse and look-at rule as `ring_cameras`, angles shifted by a quarter step so they fall between
SRC's), every film set to WIDTH × HEIGHT, and links to SRC's meshes/ and textures/. The views are
not rendered here; render them with Opal (as the 12 MP ring of docs/performance.md):

    for i in $(seq 0 $((N+EXTRA-1))); do
      opal render OUT/scene.xml --sensor $i --spp 1 --seed $((100+i)) -o OUT/views/view_$(printf %02d $i).exr
    done
"""
import argparse
import importlib.util
import json
import math
import os
from pathlib import Path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("src", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--extra", type=int, default=26)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--height", type=int, default=3000)
    a = ap.parse_args()
    spec = importlib.util.spec_from_file_location("rm", Path(__file__).with_name("room_multiview.py"))
    rm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rm)
    truth = json.load(open(a.src / "truth.json"))
    cams = []
    for c in truth["cameras"]:
        c = dict(c)
        c["width"], c["height"] = a.width, a.height
        cams.append(c)
    n = a.extra
    for k in range(n):
        ang = 2.0 * math.pi * (k + 0.5 * (k % 2) + 0.25) / n
        y = 0.55 if k % 2 == 0 else 1.15
        o = (1.35 * math.cos(ang), y, 0.85 * math.sin(ang))
        t = (-0.35 * math.cos(ang + 0.6), 0.45 + 0.1 * math.sin(3 * ang), -0.25 * math.sin(ang + 0.6))
        i = len(cams)
        cams.append({"index": i, "origin": o, "target": t, "fov_deg": 65.0, "width": a.width,
                     "height": a.height, "to_world": rm.look_at(o, t).tolist(),
                     "image": f"views/view_{i:02d}.exr"})
    (a.out / "views").mkdir(parents=True, exist_ok=True)
    for d in ("meshes", "textures"):
        if not (a.out / d).exists():
            os.symlink((a.src / d).resolve(), a.out / d)
    rm.write_scene(a.out, truth["objects"], cams, truth["integrator"]["max_depth"])
    rm.write_transforms(a.out, cams)
    truth["cameras"] = cams
    truth["generator"] += f" + bench/scripts/ring_more_views.py (--extra {n}; views by opal render)"
    json.dump(truth, open(a.out / "truth.json", "w"), indent=1)
    print(f"{len(cams)} cameras of {a.width}x{a.height} in {a.out}")


if __name__ == "__main__":
    main()
