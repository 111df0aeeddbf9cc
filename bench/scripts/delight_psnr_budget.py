#!/usr/bin/env python3
"""Error budget of the back-wall texture PSNR of `opal delight` (issue 6 item 4).

Substitutes the truth for one component at a time. Inputs:
  * a debug dump of a run: opal delight ... --objects back_wall --debug-dump DIR
    writes DIR/back_wall_final_{l,obs,ed,ei,kd}.exr (luminance map B, observed mask, direct and
    indirect irradiance, albedo);
  * the true indirect irradiance of the back wall in the true scene (light tracing with many
    paths): cargo run -p opal-inverse --example oracle_irradiance -- <cbox>/scene.xml back_wall
    256 100000000 /tmp/true   -> /tmp/true_ei.exr
Modes:
  make  DUMP TRUE_EI OUTDIR : writes OUTDIR/E_true.exr (closed-form direct of the dump + the
        oracle indirect smoothed 9x9) and OUTDIR/B_true.exr (= truth * E_true / pi), the inputs of
        the superres hooks (--sr-truth B_true.exr, --sr-shading E_true.exr)
  eval  E_TRUE DUMP...      : PSNR (peak 1, texels seen) of the pipeline albedo, of pi*B/E_true
        (the luminance map alone) and of pi*B_true/E_est (the irradiance alone), and pi*B/E_true
        split into flat texels, texels within 1 texel of the texture's lines (edges) and texels
        within 3 texels of an occlusion hole (occl.), with each part's share of the squared error.
Usage: bench/.venv/bin/python bench/scripts/delight_psnr_budget.py make|eval ... [--cbox DIR]
"""
import argparse
import math
import os
import sys

import numpy as np
import scipy.ndimage as nd


def rd(path):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    return np.array(mi.Bitmap(path), dtype=np.float64)[..., :3]


def wr(path, a):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    mi.Bitmap(a.astype(np.float32)).write(path)


def psnr(est, t, mask):
    return 10 * math.log10(1.0 / np.mean(((est - t)[mask]) ** 2))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["make", "eval"])
    ap.add_argument("args", nargs="+")
    ap.add_argument("--cbox", default=os.path.join(os.path.dirname(__file__),
                                                   "../../../shared/reference/mitsuba/cbox"))
    a = ap.parse_args()
    truth = rd(os.path.join(a.cbox, "textures", "backwall_albedo.exr"))
    if a.mode == "make":
        dump, true_ei, out = a.args
        ed = rd(dump + "_ed.exr")
        ei = rd(true_ei)
        ei = np.stack([nd.uniform_filter(ei[..., c], 9, mode="nearest") for c in range(3)], -1)
        e = ed + ei
        os.makedirs(out, exist_ok=True)
        wr(os.path.join(out, "E_true.exr"), e)
        wr(os.path.join(out, "B_true.exr"), truth * e / np.pi)
        return 0
    e_true = rd(a.args[0])
    g = np.zeros(truth.shape[:2], bool)
    dx = np.abs(np.diff(truth, axis=1)).max(-1) > 0.02
    dy = np.abs(np.diff(truth, axis=0)).max(-1) > 0.02
    g[:, :-1] |= dx
    g[:, 1:] |= dx
    g[:-1, :] |= dy
    g[1:, :] |= dy
    edge = nd.binary_dilation(g, iterations=1)
    for pre in a.args[1:]:
        l = rd(pre + "_l.exr")
        obs = rd(pre + "_obs.exr")[..., 0] > 0.5
        line = f"{pre}:"
        if os.path.exists(pre + "_kd.exr"):
            line += f" pipeline {psnr(rd(pre + '_kd.exr'), truth, obs):.2f} dB |"
            e_est = rd(pre + "_ed.exr") + rd(pre + "_ei.exr")
            line += f" B_true/E_est {psnr(truth * e_true / e_est, truth, obs):.2f} dB |"
        kd = np.pi * l / e_true
        inner = np.zeros_like(obs)
        inner[3:-3, 3:-3] = True
        near = nd.binary_dilation(~obs & inner, iterations=3) & obs
        tot = np.sum(((kd - truth)[obs]) ** 2)

        def part(m):
            se = np.sum(((kd - truth)[m]) ** 2)
            return f"{psnr(kd, truth, m):.2f} dB ({100 * m.sum() / obs.sum():.0f} % texels, {100 * se / tot:.0f} % SE)"
        line += (f" B/E_true {psnr(kd, truth, obs):.2f} dB: flat {part(obs & ~edge & ~near)},"
                 f" edges {part(obs & edge & ~near)}, occl. {part(near)}")
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
