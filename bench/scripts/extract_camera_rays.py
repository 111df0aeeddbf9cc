"""Extract pixel-centre hit positions from Mitsuba's AOV EXRs (reference Cornell box) into a
small CSV used by crates/opal/tests/camera_rays.rs: for each view, every 41st pixel that hits
geometry: view, i, j, position x y z (the ray through pixel centre (i+0.5, j+0.5) hits there).
Usage: python extract_camera_rays.py <shared>/reference/mitsuba/cbox OUT.csv
Needs: pip install OpenEXR numpy"""
import sys, OpenEXR, numpy as np
root, out = sys.argv[1], sys.argv[2]
rows = ["view,i,j,x,y,z"]
for v in range(8):
    f = OpenEXR.File(f"{root}/aov/view_{v:02d}_center.exr")
    ch = f.channels()
    def get(name):
        return np.asarray(ch[name].pixels, dtype=np.float64)
    depth = get("depth.T")
    px, py, pz = get("position.X"), get("position.Y"), get("position.Z")
    h, w = depth.shape
    k = 0
    for j in range(h):
        for i in range(w):
            k += 1
            if k % 41 or depth[j, i] <= 0:
                continue
            rows.append(f"{v},{i},{j},{px[j,i]:.7g},{py[j,i]:.7g},{pz[j,i]:.7g}")
open(out, "w").write("\n".join(rows) + "\n")
print(len(rows) - 1, "rays")
