"""RGB complex indices of refraction (eta, k) of conductors, derived from spectral data.

Source of the spectra: the files `data/ior/<name>.{eta,k}.spd` shipped with Mitsuba 3, which
state "data from www.luxpop.com database", compiled from E. D. Palik (ed.), "Handbook of
Optical Constants of Solids" (Academic Press 1985) and "... II" (1991), and LLNL/CXRO tables.

Derivation (independent of Mitsuba's code): linear interpolation of n(λ) and k(λ), integrated
against the CIE 1931 2° colour-matching functions over 360–830 nm (1 nm steps, the tabulated
CMFs taken from Mitsuba's `cie1931_xyz`, i.e. the CIE table), normalised so that a constant
spectrum c has Y = c, then XYZ → linear sRGB (IEC 61966-2-1 matrix). The same is done by
Mitsuba in RGB mode (`spectrum_list_to_srgb`, unbounded), so the script also prints
Mitsuba's values (`mi.traverse` of a `conductor` with `material=<name>`) and the difference.

Usage: bench/.venv/bin/python bench/scripts/conductor_ior_rgb.py  (prints a Rust table)
"""
import numpy as np
import mitsuba as mi
import os

mi.set_variant("llvm_ad_rgb")
IOR = os.path.join(os.path.dirname(mi.__file__), "data", "ior")
NAMES = ["Ag", "Al", "Au", "Cr", "Cu", "Cu2O", "CuO", "Hg", "Ir", "Li", "Mo", "Na_palik", "Nb",
         "Ni_palik", "Rh", "Ta", "TiN", "W", "Be", "K", "V_palik", "a-C"]

lam = np.arange(360.0, 831.0, 1.0)
cmf = np.array([[float(v[0]) for v in mi.cie1931_xyz(mi.Float(float(l)))] for l in lam])  # (N, 3)
cmf_y_int = cmf[:, 1].sum()
M = np.array([[3.2404542, -1.5371385, -0.4985314],
              [-0.9692660, 1.8760108, 0.0415560],
              [0.0556434, -0.2040259, 1.0572252]])


def load(path):
    rows = [l.split() for l in open(path) if l.strip() and not l.startswith("#")]
    a = np.array([[float(r[0]), float(r[1])] for r in rows])
    return a[:, 0], a[:, 1]


def to_rgb(w, v):
    inside = (lam >= w[0]) & (lam <= w[-1])
    y = np.interp(lam, w, v)
    xyz = (cmf * (y * inside)[:, None]).sum(0) / cmf_y_int
    return M @ xyz


print("// name, eta (r, g, b), k (r, g, b)")
for n in NAMES:
    eta = to_rgb(*load(os.path.join(IOR, n + ".eta.spd")))
    k = to_rgb(*load(os.path.join(IOR, n + ".k.spd")))
    p = mi.traverse(mi.load_dict({"type": "conductor", "material": n}))
    me, mk = np.array(p["eta.value"]).ravel(), np.array(p["k.value"]).ravel()
    d = max(np.abs(eta - me).max(), np.abs(k - mk).max())
    print(f'    ("{n}", [{eta[0]:.5}, {eta[1]:.5}, {eta[2]:.5}], [{k[0]:.5}, {k[1]:.5}, {k[2]:.5}]), '
          f'// Mitsuba: eta {np.round(me, 5).tolist()} k {np.round(mk, 5).tolist()}, max |diff| {d:.2e}')
