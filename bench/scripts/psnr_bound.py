#!/usr/bin/env python3
"""How well can the 8 reference views resolve the back-wall albedo texture at all?

An optimistic bound for the de-lighting acceptance item "back wall within PSNR >= 38 dB of the
true texture where seen" (issue 6). The views are simulated from the true 256x256 texture with
the exact cameras of transforms.json and the exact image formation of the reference renders
(bilinear texture filter, box pixel filter = pixel-area average), but with everything else made
ideal: uniform irradiance known exactly, no occlusion by the boxes, no interreflection error,
and only the Monte-Carlo noise of the photos (relative per-pixel standard error, default the
median of the back wall in view_00_stderr / view_00, or --rel-noise).

Two reconstructions of the texture from these ideal views are scored (PSNR, peak 1, over the
texels seen, RGB):
  * back-projection: each texel = mean over the views of the bilinearly interpolated pixel
    value at its projection (what Opal's de-lighting does, before lighting is divided out);
  * least squares: the texture that best explains all pixels of all views (multi-view
    super-resolution, scipy lsqr with a small Tikhonov damping; the damping is scanned and the
    best value reported, i.e. an oracle choice -> optimistic).

Usage: bench/.venv/bin/python bench/scripts/psnr_bound.py <shared>/reference/mitsuba/cbox
       [--rel-noise X] [--ss 4] [--seed 1]
Needs numpy, scipy and mitsuba (EXR reading) in the venv.
"""
import argparse
import json
import math
import os
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def read_exr(path):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    return np.array(mi.Bitmap(path), dtype=np.float64)


def view_operator(frame, w, h, fov_x, tex_w, tex_h, ss):
    """Sparse matrix: pixel values (rows, pixels whose every sub-sample hits the wall) from
    texel values (cols), pixel = mean over ss x ss sub-pixel positions of the bilinearly
    filtered texture at the hit point on the back wall z = -1, x, y in [-1, 1]."""
    m = np.array(frame["transform_matrix"], dtype=np.float64)
    origin = m[:3, 3]
    tan_x = math.tan(fov_x / 2)
    tan_y = tan_x * h / w
    offs = (np.arange(ss) + 0.5) / ss
    rows, cols, vals, pix = [], [], [], []
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    jj = jj.ravel()
    ii = ii.ravel()
    npix = w * h
    acc_u = []
    acc_ok = np.ones(npix, dtype=bool)
    for oy in offs:
        for ox in offs:
            px = (ii + ox) / w * 2 - 1
            py = 1 - (jj + oy) / h * 2
            d_cam = np.stack([px * tan_x, py * tan_y, -np.ones(npix)], axis=1)
            d = d_cam @ m[:3, :3].T
            t = (-1.0 - origin[2]) / d[:, 2]
            p = origin[None, :] + t[:, None] * d
            ok = (t > 0) & (np.abs(p[:, 0]) <= 1) & (np.abs(p[:, 1]) <= 1)
            acc_ok &= ok
            # uv: u along +x, v along +y (obj vt); bitmap row 0 is v = 1
            u = (p[:, 0] + 1) / 2
            v = (p[:, 1] + 1) / 2
            acc_u.append((u, v))
    sel = np.nonzero(acc_ok)[0]
    r_index = -np.ones(npix, dtype=np.int64)
    r_index[sel] = np.arange(len(sel))
    wgt = 1.0 / (ss * ss)
    for u, v in acc_u:
        x = u[sel] * tex_w - 0.5
        y = (1 - v[sel]) * tex_h - 0.5
        x0 = np.floor(x).astype(np.int64)
        y0 = np.floor(y).astype(np.int64)
        fx = x - x0
        fy = y - y0
        for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                           (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            cx = np.clip(x0 + dx, 0, tex_w - 1)  # wrap_mode clamp
            cy = np.clip(y0 + dy, 0, tex_h - 1)
            rows.append(np.arange(len(sel)))
            cols.append(cy * tex_w + cx)
            vals.append(ww * wgt)
    a = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(len(sel), tex_w * tex_h))
    a.sum_duplicates()
    # texel footprint: texels per pixel (sqrt of the pixel's area on the texture)
    u0, v0 = acc_u[0]
    return a, sel, len(sel)


def gradient_operator(w, h):
    """Forward differences in x and y of a w x h image (row-major), as a sparse matrix."""
    ix = sp.identity(w, format="csr")
    iy = sp.identity(h, format="csr")
    dx = sp.diags([-np.ones(w - 1), np.ones(w - 1)], [0, 1], shape=(w - 1, w))
    dy = sp.diags([-np.ones(h - 1), np.ones(h - 1)], [0, 1], shape=(h - 1, h))
    return sp.vstack([sp.kron(iy, dx), sp.kron(dy, ix)]).tocsr()


def psnr(est, truth, mask):
    mse = np.mean((est[mask] - truth[mask]) ** 2)
    return 10 * math.log10(1.0 / mse)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("cbox")
    ap.add_argument("--rel-noise", type=float, default=None)
    ap.add_argument("--ss", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--lams", type=lambda t: [float(x) for x in t.split(",")],
                    default=[0.003, 0.01, 0.03, 0.1])
    ap.add_argument("--noises", type=lambda t: [float(x) for x in t.split(",")], default=None)
    ap.add_argument("--skip-damped", action="store_true", help="skip the lsqr damping scan")
    args = ap.parse_args()
    tj = json.load(open(os.path.join(args.cbox, "transforms.json")))
    truth = read_exr(os.path.join(args.cbox, "textures", "backwall_albedo.exr"))[..., :3]
    th, tw = truth.shape[:2]
    t_flat = truth.reshape(-1, 3)

    if args.rel_noise is None:
        img = read_exr(os.path.join(args.cbox, "views", "view_00.exr"))[..., :3]
        err = read_exr(os.path.join(args.cbox, "views", "view_00_stderr.exr"))[..., :3]
        # back-wall pixels of view 0: the central region
        c = img.shape[0] // 2
        reg = (slice(c - 40, c + 40), slice(c - 40, c + 40))
        rel = err[reg] / np.maximum(img[reg], 1e-9)
        args.rel_noise = float(np.median(rel))
    print(f"relative per-pixel noise of the photos: {100 * args.rel_noise:.2f} %")

    ops = []
    for k, fr in enumerate(tj["frames"]):
        w = fr.get("w", tj.get("w"))
        h = fr.get("h", tj.get("h"))
        a, sel, n = view_operator(fr, w, h, fr.get("camera_angle_x", tj["camera_angle_x"]), tw, th, args.ss)
        # footprint: texels covered per pixel, from the row sums of the support
        cover = np.asarray((a > 0).sum(axis=0)).ravel()
        fp = math.sqrt(tw * th * (np.count_nonzero(cover) / (tw * th)) / max(n, 1)) if n else float("nan")
        print(f"{os.path.basename(fr['file_path'])}: {n} pixels fully on the back wall, "
              f"~{fp:.2f} texels per pixel (linear)")
        if n:
            ops.append(a)
    a_all = sp.vstack(ops).tocsr()
    rng = np.random.default_rng(args.seed)
    seen = np.asarray(a_all.sum(axis=0)).ravel() > 0
    print(f"texels seen: {seen.sum()} of {tw * th}")

    for noise in args.noises if args.noises else (0.0, args.rel_noise):
        ys = []
        for c in range(3):
            y = a_all @ t_flat[:, c]
            y = y * (1 + noise * rng.standard_normal(y.shape))
            ys.append(y)
        # back-projection: bilinear sampling of the views at texel centres == A^T with
        # per-texel normalisation (the transpose of the bilinear+box operator)
        bp = np.zeros_like(t_flat)
        norm = np.asarray(a_all.sum(axis=0)).ravel()
        for c in range(3):
            bp[:, c] = (a_all.T @ ys[c]) / np.maximum(norm, 1e-12)
        mask = np.repeat(seen[:, None], 3, axis=1)
        print(f"noise {100 * noise:.2f} %: back-projection PSNR {psnr(bp, t_flat, mask):.2f} dB")
        best = None
        for damp in (() if args.skip_damped else (0.0, 0.01, 0.03, 0.1, 0.3)):
            ls = np.zeros_like(t_flat)
            for c in range(3):
                ls[:, c] = spla.lsqr(a_all, ys[c], damp=damp, atol=1e-10, btol=1e-10, iter_lim=2000)[0]
            p = psnr(ls, t_flat, mask)
            print(f"  least squares, damping {damp}: PSNR {p:.2f} dB")
            best = p if best is None else max(best, p)
        if best is not None:
            print(f"noise {100 * noise:.2f} %: best least-squares PSNR {best:.2f} dB")
        # smoothness prior that does not shrink the mean: ||A t - y||^2 + lam ||grad t||^2,
        # and its edge-preserving variant (total variation by iteratively reweighted least
        # squares, 6 reweightings)
        g = gradient_operator(tw, th)
        for tv in (False, True):
            best = None
            for lam in args.lams:
                est = np.zeros_like(t_flat)
                for c in range(3):
                    wts = np.ones(g.shape[0])
                    x = bp[:, c]
                    for _ in range(6 if tv else 1):
                        gw = sp.diags(np.sqrt(lam * wts)) @ g
                        m = sp.vstack([a_all, gw]).tocsr()
                        rhs = np.concatenate([ys[c], np.zeros(g.shape[0])])
                        x = spla.lsqr(m, rhs, atol=1e-8, btol=1e-8, iter_lim=400, x0=x)[0]
                        if tv:
                            wts = 1.0 / np.maximum(np.abs(g @ x), 0.01)
                    est[:, c] = x
                p = psnr(est, t_flat, mask)
                kind = "total variation" if tv else "gradient (Tikhonov-grad)"
                print(f"  {kind}, lambda {lam}: PSNR {p:.2f} dB")
                best = p if best is None else max(best, p)
            print(f"noise {100 * noise:.2f} %: best {'TV' if tv else 'gradient-prior'} PSNR {best:.2f} dB")


if __name__ == "__main__":
    sys.exit(main())
