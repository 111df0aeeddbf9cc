"""Reference values of Mitsuba 3's metal and coating BSDFs for Opal's unit tests.

Evaluates `bsdf.eval` (which includes the cosine of the outgoing direction) and `bsdf.pdf` of
Mitsuba 3.9.1 (`llvm_ad_rgb`) for a few plugin configurations at fixed direction pairs and
prints them as a Rust table (`wo` = Mitsuba's `si.wi`, the direction towards the camera; `wi`
= Mitsuba's `wo`). Opal's `crates/opal/src/bsdf/mitsuba_values.rs` holds the output and the
tests in `plastic.rs`, `rough_plastic.rs`, `conductor.rs` compare against it.

Usage: bench/.venv/bin/python bench/scripts/mitsuba_material_values.py
"""
import math
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")

CONFIGS = {
    "plastic": {"type": "plastic", "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}},
    "plastic_nl": {"type": "plastic", "int_ior": 1.9, "nonlinear": True,
                   "diffuse_reflectance": {"type": "rgb", "value": [0.9, 0.1, 0.4]}},
    "roughplastic": {"type": "roughplastic", "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}},
    "roughplastic_ggx": {"type": "roughplastic", "distribution": "ggx", "alpha": 0.4, "int_ior": 1.6,
                         "nonlinear": True, "specular_reflectance": 0.7,
                         "diffuse_reflectance": {"type": "rgb", "value": [0.8, 0.3, 0.1]}},
    "roughconductor_au": {"type": "roughconductor", "material": "Au", "alpha": 0.3},
    "roughconductor_aniso": {"type": "roughconductor", "material": "Cu", "distribution": "ggx",
                             "alpha_u": 0.1, "alpha_v": 0.4},
}


def d(theta, phi):
    return [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]


PAIRS = [(d(0.0, 0.0), d(0.3, 2.0)), (d(0.5, 0.3), d(0.5, 0.3 + math.pi)), (d(1.2, 1.0), d(0.2, 4.0)),
         (d(0.8, 0.0), d(1.4, 2.5)), (d(1.0, 0.7), d(1.0, 0.7 + math.pi + 0.1))]

print("// (config, wo, wi, f·cos θi (r, g, b), pdf)")
for name, cfg in CONFIGS.items():
    b = mi.load_dict(cfg)
    for wo, wi in PAIRS:
        si = mi.SurfaceInteraction3f()
        si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
        si.wi = mi.Vector3f(wo)
        ctx = mi.BSDFContext()
        f = b.eval(ctx, si, mi.Vector3f(wi))
        p = b.pdf(ctx, si, mi.Vector3f(wi))
        fv = [float(f[c][0]) for c in range(3)]
        print(f'    ("{name}", [{wo[0]:.7}, {wo[1]:.7}, {wo[2]:.7}], [{wi[0]:.7}, {wi[1]:.7}, {wi[2]:.7}], '
              f'[{fv[0]:.7e}, {fv[1]:.7e}, {fv[2]:.7e}], {float(p[0]):.7e}),')
