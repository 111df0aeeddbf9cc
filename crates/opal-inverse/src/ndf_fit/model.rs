//! NDF models: the analytic families ([`Family`]), the full parameter set of one model
//! ([`Model`]: α, Student-t γ, shift δ, hybrid table, dotted coverage f) and the bounded coordinates the optimisers
//! move (`Coord`, with clamping and the penalty that walks a simplex back into bounds); the
//! hybrid node spacing ([`hybrid_spacing`]).
//!
//! Angles are radians in the model, degrees in reports (`describe`, `params_json`,
//! `param_values`) and in the δ coordinate.
//!
//! Tests: `tests.rs` (models build the right NDF, coordinates are clamped and penalised).

use opal::bsdf::microfacet::{Beckmann, Ggx, Ndf, Ndfs, Profile};
use opal::gonio::{Face, Scattering};
use opal::math::Vec3;
/// NDF families.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Beckmann (Gauss-like slopes), parameter α.
    Beckmann,
    /// GGX / Trowbridge–Reitz (Cauchy-like slopes), parameter α.
    Ggx,
    /// Generalised Student-t slopes (`Profile::StudentT`): α and the tail exponent γ ≥ 2
    /// (γ = 2 is GGX, γ → ∞ is Beckmann, with the same α).
    Student,
    /// The best analytic model plus a piecewise-linear table of D over θm ∈ [0, θK]
    /// (`Profile::Hybrid`).
    Hybrid,
    /// Dotted face: dots of roughness α (base shape GGX or Beckmann) covering a fraction f of
    /// a polished land (area mixture, `opal::gonio::Face::Dotted`); parameters α and f.
    Dotted,
}

/// Tail exponent γ a Student-t model starts from when nothing better is known.
pub const STUDENT_GAMMA_START: f64 = 4.0;

impl Family {
    /// The one-parameter analytic families.
    pub const ALL: [Family; 2] = [Family::Ggx, Family::Beckmann];
    /// What `auto` fits (then keeps one by the selection rule, see
    /// [`Problem::compare`](super::Problem::compare)).
    pub const AUTO: [Family; 3] = [Family::Ggx, Family::Beckmann, Family::Student];

    /// Lower-case name (`ggx`, `beckmann`, `student`, `hybrid`).
    pub fn name(self) -> &'static str {
        match self {
            Family::Beckmann => "beckmann",
            Family::Ggx => "ggx",
            Family::Student => "student",
            Family::Hybrid => "hybrid",
            Family::Dotted => "dotted",
        }
    }

    /// Parses a family name.
    pub fn parse(s: &str) -> Option<Family> {
        match s.to_ascii_lowercase().as_str() {
            "beckmann" | "gauss" => Some(Family::Beckmann),
            "ggx" | "cauchy" | "trowbridge-reitz" => Some(Family::Ggx),
            "student" | "student-t" => Some(Family::Student),
            "hybrid" => Some(Family::Hybrid),
            "dotted" => Some(Family::Dotted),
            _ => None,
        }
    }

    /// The NDF of roughness `alpha` (> 0) with the family's default shape (Student:
    /// γ = [`STUDENT_GAMMA_START`]; Hybrid: GGX without table). Panics unless `alpha > 0`.
    pub fn ndf(self, alpha: f64) -> Ndfs {
        Model::new(self, alpha).ndf().expect("alpha > 0")
    }

    /// tan θ / α at which D(θ) falls to half its peak, small-α limit (GGX: (1 + t²)⁻² = 1/2,
    /// t = √(√2 − 1) ≈ 0.644; Beckmann: exp(−t²) = 1/2, t = √ln 2 ≈ 0.833; Student γ:
    /// t² = (γ − 1)(2^(1/γ) − 1)).
    pub(super) fn half_max_slope(self) -> f64 {
        match self {
            Family::Ggx | Family::Hybrid | Family::Dotted => (2f64.sqrt() - 1.0).sqrt(),
            Family::Beckmann => 2f64.ln().sqrt(),
            Family::Student => {
                let g = STUDENT_GAMMA_START;
                ((g - 1.0) * (2f64.powf(1.0 / g) - 1.0)).sqrt()
            }
        }
    }
}

/// One NDF model with every parameter: an analytic base shape (Beckmann, GGX or Student-t),
/// optionally shifted (`D(θ) ∝ base(|θ − δ|)`), optionally with a hybrid table.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    /// The family reported (Hybrid when `nodes` is not empty).
    pub family: Family,
    /// Shape of the analytic part: Beckmann, Ggx or Student.
    pub base: Family,
    /// Roughness α.
    pub alpha: f64,
    /// Student-t tail exponent γ (Student base only).
    pub gamma: Option<f64>,
    /// Peak shift δ in radians (`Some` when the shift is fitted).
    pub delta: Option<f64>,
    /// Hybrid table: (θ radians, multiplier of the normalised analytic part at θ). The last
    /// node is the anchor (multiplier 1, not fitted) that joins the table to the analytic part.
    pub nodes: Vec<(f64, f64)>,
    /// Per node of `nodes`: whether its multiplier is pinned at 1 (an anchor joining the table
    /// to the analytic part, not fitted). A missing entry means fitted, except for the last
    /// node, always an anchor.
    pub pinned: Vec<bool>,
    /// Dotted face: fraction f ∈ (0, 1) of the face covered by rough dots carrying this NDF,
    /// the rest polished (`Some` when f is fitted).
    pub coverage: Option<f64>,
}

/// Coverage a dotted model starts from when nothing better is known.
pub const DOTTED_COVERAGE_START: f64 = 0.5;

impl Model {
    /// The family's default model of roughness `alpha` (no shift, no table).
    pub fn new(family: Family, alpha: f64) -> Model {
        let base = if matches!(family, Family::Hybrid | Family::Dotted) { Family::Ggx } else { family };
        Model {
            family: if family == Family::Hybrid { base } else { family },
            base,
            alpha,
            gamma: (base == Family::Student).then_some(STUDENT_GAMMA_START),
            delta: None,
            nodes: Vec::new(),
            pinned: Vec::new(),
            coverage: (family == Family::Dotted).then_some(DOTTED_COVERAGE_START),
        }
    }

    /// The analytic part (with its shift) as a numeric profile.
    pub fn base_profile(&self) -> Profile {
        let alpha = self.alpha;
        let b = match self.base {
            Family::Beckmann => Profile::Beckmann { alpha },
            Family::Ggx | Family::Hybrid | Family::Dotted => Profile::Ggx { alpha },
            Family::Student => Profile::StudentT { alpha, gamma: self.gamma.unwrap_or(STUDENT_GAMMA_START) },
        };
        match self.delta {
            Some(delta) => Profile::Shifted { base: Box::new(b), delta },
            None => b,
        }
    }

    fn base_ndf(&self) -> opal::Result<Ndfs> {
        match (self.base, self.delta) {
            (Family::Beckmann, None) => Ok(Ndfs::Beckmann(Beckmann::new(self.alpha as f32)?)),
            (Family::Ggx | Family::Hybrid | Family::Dotted, None) => {
                Ok(Ndfs::Ggx(Ggx::new(self.alpha as f32)?))
            }
            _ => Ndfs::numeric(self.base_profile()),
        }
    }

    /// The NDF (analytic when possible, else tabulated by `opal::bsdf::microfacet::numeric`).
    pub fn ndf(&self) -> opal::Result<Ndfs> {
        let base = self.base_ndf()?;
        if self.nodes.is_empty() {
            return Ok(base);
        }
        let theta: Vec<f64> = self.nodes.iter().map(|n| n.0).collect();
        let d: Vec<f64> = self
            .nodes
            .iter()
            .map(|&(t, m)| m * base.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64)
            .collect();
        Ndfs::numeric(Profile::Hybrid { base: Box::new(self.base_profile()), theta, d })
    }

    /// The rough face this model describes: the NDF on the whole face, or (with a coverage)
    /// dots carrying it on a polished land.
    pub fn face(&self, scattering: Scattering) -> opal::Result<Face> {
        let ndf = self.ndf()?;
        Ok(match self.coverage {
            Some(f) => Face::dotted(f, ndf, scattering),
            None => Face::Rough { ndf, scattering },
        })
    }

    /// Indices of the fitted hybrid nodes (every node but the last and the pinned ones).
    pub fn free_nodes(&self) -> Vec<usize> {
        (0..self.nodes.len().saturating_sub(1))
            .filter(|&i| !self.pinned.get(i).copied().unwrap_or(false))
            .collect()
    }

    /// The hybrid table's multiplier of the analytic part at θ (linear between the nodes, 1
    /// outside the table).
    pub fn multiplier_at(&self, theta: f64) -> f64 {
        let n = &self.nodes;
        match n.iter().position(|x| x.0 >= theta) {
            Some(0) if n[0].0 > theta => 1.0,
            Some(0) => n[0].1,
            Some(i) => {
                let (a, b) = (n[i - 1], n[i]);
                a.1 + (b.1 - a.1) * (theta - a.0) / (b.0 - a.0)
            }
            None => 1.0,
        }
    }

    /// Number of fitted parameters.
    pub fn parameter_count(&self) -> usize {
        1 + self.gamma.is_some() as usize
            + self.delta.is_some() as usize
            + self.free_nodes().len()
            + self.coverage.is_some() as usize
    }

    /// Every parameter as JSON (`alpha`, `gamma`, `delta_deg`, `nodes` with θ in degrees, the
    /// multiplier and the tabulated D).
    pub fn params_json(&self) -> serde_json::Value {
        let mut m = serde_json::Map::new();
        m.insert("base".into(), self.base.name().into());
        m.insert("alpha".into(), self.alpha.into());
        if let Some(g) = self.gamma {
            m.insert("gamma".into(), g.into());
        }
        if let Some(d) = self.delta {
            m.insert("delta_deg".into(), d.to_degrees().into());
        }
        if let Some(f) = self.coverage {
            m.insert("coverage".into(), f.into());
        }
        if !self.nodes.is_empty() {
            let base = self.base_ndf().ok();
            let free = self.free_nodes();
            let nodes: Vec<serde_json::Value> = self
                .nodes
                .iter()
                .enumerate()
                .map(|(i, &(t, k))| {
                    let d =
                        base.as_ref().map(|b| k * b.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64);
                    serde_json::json!({"theta_deg": t.to_degrees(), "scale": k, "d_unnormalised": d,
                        "fitted": free.contains(&i)})
                })
                .collect();
            m.insert("hybrid_nodes".into(), nodes.into());
        }
        serde_json::Value::Object(m)
    }

    /// Short description (`student α=0.2013 γ=5.10 δ=9.8° nodes=2`).
    pub fn describe(&self) -> String {
        let mut s = format!("{} α={:.4}", self.family.name(), self.alpha);
        if matches!(self.family, Family::Hybrid | Family::Dotted) {
            s.push_str(&format!(" base={}", self.base.name()));
        }
        if let Some(g) = self.gamma {
            s.push_str(&format!(" γ={g:.2}"));
        }
        if let Some(d) = self.delta {
            s.push_str(&format!(" δ={:.2}°", d.to_degrees()));
        }
        if let Some(f) = self.coverage {
            s.push_str(&format!(" coverage={f:.4}"));
        }
        if !self.nodes.is_empty() {
            let k: Vec<String> =
                self.nodes.iter().map(|(t, k)| format!("{:.1}°×{k:.2}", t.to_degrees())).collect();
            s.push_str(&format!(" nodes=[{}]", k.join(", ")));
        }
        s
    }
}

/// The coordinates an optimiser moves (each bounded; out-of-bounds points are clamped and
/// penalised quadratically so the simplex walks back).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Coord {
    /// ln α ∈ [ln 10⁻³, ln 3].
    LnAlpha,
    /// q = 2/γ ∈ [0.01, 1] (1 = GGX, → 0 Beckmann).
    Q,
    /// δ in degrees ∈ [0, 60].
    DeltaDeg,
    /// ln of the multiplier of hybrid node k ∈ [ln 0.02, ln 50].
    LnScale(usize),
    /// logit of the dotted coverage f, ln(f/(1 − f)) ∈ [logit 0.002, logit 0.998].
    LogitCoverage,
}

impl Coord {
    pub(super) fn bounds(self) -> (f64, f64) {
        match self {
            Coord::LnAlpha => (1e-3f64.ln(), 3f64.ln()),
            Coord::Q => (0.01, 1.0),
            Coord::DeltaDeg => (0.0, 60.0),
            Coord::LnScale(_) => (0.02f64.ln(), 50f64.ln()),
            Coord::LogitCoverage => (-(499f64.ln()), 499f64.ln()),
        }
    }
    /// Coarse initial simplex step.
    pub(super) fn step(self) -> f64 {
        match self {
            Coord::LnAlpha => 0.15,
            Coord::Q => 0.3,
            Coord::DeltaDeg => 4.0,
            Coord::LnScale(_) => 0.4,
            Coord::LogitCoverage => 0.6,
        }
    }
    pub(super) fn get(self, m: &Model) -> f64 {
        match self {
            Coord::LnAlpha => m.alpha.ln(),
            Coord::Q => 2.0 / m.gamma.unwrap_or(STUDENT_GAMMA_START),
            Coord::DeltaDeg => m.delta.unwrap_or(0.0).to_degrees(),
            Coord::LnScale(k) => m.nodes[k].1.ln(),
            Coord::LogitCoverage => {
                let f = m.coverage.unwrap_or(DOTTED_COVERAGE_START);
                (f / (1.0 - f)).ln()
            }
        }
    }
    fn set(self, m: &mut Model, x: f64) {
        match self {
            Coord::LnAlpha => m.alpha = x.exp(),
            Coord::Q => m.gamma = Some(2.0 / x),
            Coord::DeltaDeg => m.delta = Some(x.to_radians()),
            Coord::LnScale(k) => m.nodes[k].1 = x.exp(),
            Coord::LogitCoverage => m.coverage = Some(1.0 / (1.0 + (-x).exp())),
        }
    }
}

/// The model at coordinates `x` (clamped into bounds) and the squared distance clamped away.
pub(super) fn apply(start: &Model, coords: &[Coord], x: &[f64]) -> (Model, f64) {
    let mut m = start.clone();
    let mut pen = 0.0;
    for (c, &v) in coords.iter().zip(x) {
        let (lo, hi) = c.bounds();
        let vc = if v.is_finite() { v.clamp(lo, hi) } else { lo };
        pen += (v - vc).powi(2);
        c.set(&mut m, vc);
    }
    (m, pen)
}

impl Model {
    /// The parameter values in reporting units: α, then γ, δ (degrees) and the hybrid
    /// multipliers when present.
    pub fn param_values(&self) -> Vec<f64> {
        let mut v = vec![self.alpha];
        v.extend(self.gamma);
        v.extend(self.delta.map(f64::to_degrees));
        v.extend(self.free_nodes().iter().map(|&i| self.nodes[i].1));
        v.extend(self.coverage);
        v
    }
}

/// Angular spacing of the hybrid nodes: a third of the analytic part's half width at half
/// maximum in θm (measured on the NDF itself, from its peak outward), in [0.5°, 10°].
pub fn hybrid_spacing(model: &Model) -> f64 {
    let base = Model { nodes: Vec::new(), pinned: Vec::new(), ..model.clone() };
    let Ok(ndf) = base.ndf() else { return 2f64.to_radians() };
    let d = |t: f64| ndf.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64;
    let step = 0.05f64.to_radians();
    let n = (89.0f64.to_radians() / step) as usize;
    let (ipk, dpk) =
        (0..n).map(|i| (i, d(i as f64 * step))).fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let ihalf = (ipk..n).find(|&i| d(i as f64 * step) < 0.5 * dpk).unwrap_or(n);
    (((ihalf - ipk) as f64 * step) / 3.0).clamp(0.5f64.to_radians(), 10f64.to_radians())
}
