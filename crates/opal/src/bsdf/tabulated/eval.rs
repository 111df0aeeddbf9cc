//! Evaluation and sampling of a tabulated BSDF: the table lookup (value interpolated over the
//! cell centres and the bracketing incidence rows after dividing out the known Fresnel ×
//! projected-area factor, pdf from the rows' piecewise-constant densities) and the [`Bxdf`]
//! impl (`eval`, `pdf`, `sample` from the rows' marginal/conditional CDFs). Conventions in the
//! module docs (`bsdf/tabulated/mod.rs`); χ² and accuracy tests in `tabulated/tests.rs`.

use super::TabulatedBsdf;
use super::grid::{dwm_dwi, half_vector, wi_from_wm};
use crate::bsdf::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, fresnel_dielectric};
use crate::spectrum::Spectrum;

impl TabulatedBsdf {
    /// The known factor of a lobe's power density per dωm for `wo` on micro-normal `wm`:
    /// Fresnel (R: F, T: 1 − F) times the projected facet area |wo·wm| (the rest,
    /// `D·G/|cos θo|`, varies smoothly with θo).
    #[inline]
    pub(super) fn known_factor(wo: Vec3, wm: Vec3, transmit: bool, eta: f32) -> f32 {
        let c = wo.dot(wm);
        if c * wo.z <= 0.0 {
            return 0.0;
        }
        let (f, _) = fresnel_dielectric(c, eta);
        c.abs() * if transmit { 1.0 - f } else { f }
    }

    /// (f·|cos θi| in power units, pdf, η', |cos θi|, transmission) of the pair.
    ///
    /// The value interpolates the table value divided by the cell average of the known factor
    /// (Fresnel × |wo·wm| × 2π dw/du at the row's incidence) — bilinearly over the cell centres
    /// in (u, v) and linearly between the two bracketing rows, over the stencil entries whose
    /// factor is not ~0 — then multiplies by the exact factor of `wo`: Fresnel changes steeply
    /// with θo near the critical angle (light from the inside), the rest of the integrand
    /// smoothly. The pdf is the plain piecewise-constant interpolation of the rows' normalised
    /// densities (what `sample` draws from).
    #[inline]
    pub(super) fn lookup(&self, wo: Vec3, wi: Vec3) -> Option<(f32, f32, f32, f32, bool)> {
        let t = &*self.t;
        let g = &t.grid;
        let (wm, etap, transmit) = half_vector(wo, wi, t.eta)?;
        let (u, v) = g.uv_of(wo, wm);
        let (iu, iv) = g.cell(u, v);
        let side = if wo.z > 0.0 { 0 } else { 1 };
        let (i0, i1, w1) = g.rows(wo.z.abs());
        let idx = (transmit as usize * g.n_u + iu) * g.n_v + iv;
        let cpr = g.cells_per_row();
        let (mut q, mut p) = (0.0f32, 0.0f32);
        // bilinear stencil over cell centres in (u, v), clamped at the edges (v = 0 and 1 are
        // mirror axes, so clamping is the symmetric extension)
        let stencil = |x: f32, n: usize| {
            let f = x * n as f32 - 0.5;
            if f <= 0.0 {
                return (0, 0, 0.0);
            }
            let i = (f.floor() as usize).min(n - 1);
            if i + 1 >= n { (n - 1, n - 1, 0.0) } else { (i, i + 1, f - i as f32) }
        };
        let (u0, u1, tu) = stencil(u, g.n_u);
        let (v0, v1, tv) = stencil(v, g.n_v);
        let lobe0 = transmit as usize * g.n_u;
        let (mut qf, mut wf) = (0.0f32, 0.0f32);
        for (r, w) in [(i0, 1.0 - w1), (i1, w1)] {
            if w == 0.0 {
                continue;
            }
            let sr = side * g.n_theta_o + r;
            let k = sr * cpr + idx;
            let qv = t.q[k];
            q += w * qv;
            if let Some(d) = &t.rows[sr] {
                p += w * qv / d.albedo;
            }
            for (ju, wu) in [(u0, 1.0 - tu), (u1, tu)] {
                for (jv, wv) in [(v0, 1.0 - tv), (v1, tv)] {
                    let wc = w * wu * wv;
                    let kc = sr * cpr + (lobe0 + ju) * g.n_v + jv;
                    if wc > 0.0 && t.inv_known[kc] > 0.0 {
                        qf += wc * t.q[kc] * t.inv_known[kc];
                        wf += wc;
                    }
                }
            }
        }
        if wf > 0.0 {
            q = qf / wf * Self::known_factor(wo, wm, transmit, t.eta) * g.jac(u);
        }
        let j = dwm_dwi(wo, wi, wm, etap, transmit) / g.jac(u);
        Some((q * j, p * j, etap, wi.z.abs(), transmit))
    }
}

impl Bxdf for TabulatedBsdf {
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        let Some((q, _, etap, cos_i, transmit)) = self.lookup(wo, wi) else {
            return Spectrum::ZERO;
        };
        let mut f = q / cos_i;
        if transmit && mode == TransportMode::Radiance {
            f /= etap * etap;
        }
        if f.is_finite() { Spectrum::splat(f) } else { Spectrum::ZERO }
    }

    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        match self.lookup(wo, wi) {
            Some((_, p, ..)) if p.is_finite() => p,
            _ => 0.0,
        }
    }

    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let t = &*self.t;
        let g = &t.grid;
        let side = if wo.z > 0.0 { 0 } else { 1 };
        let (i0, i1, w1) = g.rows(wo.z.abs());
        let (row, mut uc) = if uc < 1.0 - w1 { (i0, uc / (1.0 - w1)) } else { (i1, (uc - (1.0 - w1)) / w1) };
        uc = uc.clamp(0.0, 1.0);
        let sign = if uc < 0.5 { 1.0 } else { -1.0 };
        let d = t.rows[side * g.n_theta_o + row].as_ref()?;
        let (k, _, du) = d.marginal.sample(u.x);
        let (iv, _, dv) = d.conditional[k].as_ref()?.sample(u.y);
        let (lobe, iu) = (k / g.n_u, k % g.n_u);
        let uu = (iu as f32 + du) / g.n_u as f32;
        let vv = (iv as f32 + dv) / g.n_v as f32;
        let wm = g.wm_of(wo, uu, vv, sign);
        let wi = wi_from_wm(wo, wm, lobe == 1, t.eta)?;
        let (f, pdf, etap, _, transmit) = self.lookup(wo, wi)?;
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        let mut fv = f / wi.z.abs();
        if transmit && mode == TransportMode::Radiance {
            fv /= etap * etap;
        }
        Some(BsdfSample {
            wi,
            f: Spectrum::splat(fv),
            pdf,
            flags: BxdfFlags { reflection: !transmit, transmission: transmit, specular: false },
            eta: etap,
        })
    }

    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, transmission: true, specular: false }
    }
}
