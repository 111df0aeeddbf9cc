//! Virtual goniophotometer (method A, forward part): a collimated beam lights a plane-parallel
//! plate whose faces are polished or rough; every photon is followed through all internal
//! reflections until it leaves the plate, is absorbed or exceeds the interaction limit, and is
//! counted by circular detectors on the reflected (R, z > 0) and transmitted (T, z < 0) side.
//!
//! Geometry (same as `<shared>/reference/mitsuba/gonio`): plate normal +z, lit face at z = 0
//! (outward normal +z), back face at z = −thickness (outward normal −z). The beam propagates
//! along `k = (sin t cos φb, sin t sin φb, −cos t)` (incidence t, azimuth φb) with directions
//! uniform in solid angle inside a cone of half-angle `divergence`. A detector at signed angle
//! p in the plane of incidence has axis `(sin p cos φb, sin p sin φb, ±cos p)` (+ on side R,
//! − on side T): the specular reflection and the undeviated transmission are both at p = +t.
//! A photon leaving with direction d is counted by a detector of angular radius r when the
//! angle between d (far field) — or between the line from the plate centre to the point where
//! the photon crosses the detector sphere (finite plate, detectors at `distance_mm`) — and the
//! axis is ≤ r.
//!
//! Faces: polished = exact unpolarised Fresnel (reflect with probability R, else refract),
//! rough = [`RoughDielectric`] (single scattering, separable or height-correlated G) or
//! [`RoughDielectricMs`] (multiple scattering on the micro-surface), sampled in
//! [`TransportMode::Importance`] (power): the photon weight is multiplied by the sample weight,
//! and what the single-scattering model loses is reported as `lost`. Absorption: the weight is
//! multiplied by `exp(−μ L)` on every traversal of length L (the rest is `absorbed`).
//!
//! Output per detector: `value` = Σw/(N Ω) [1/sr] (intensity per incident power, cone
//! average), its standard error, and `bsdf` = Σ(w/|cos θ|)/(N Ω) (BRDF/BTDF-like cone
//! average). Totals R, T, lost, absorbed, fractions of the incident power.
//!
//! Determinism: photon j of incidence i draws from its own stream `Rng::new(seed, i, j)`, so a
//! photon's random numbers do not depend on how many the photons before it consumed (common
//! random numbers when a fit changes the face); photons are processed in fixed batches of
//! [`BATCH`]; each batch fills its own f64 accumulator and batches are
//! merged in index order, so the result is identical for any number of threads (tested). The
//! photon loops allocate only per batch (accumulators, the wavefront scratch); a fitting
//! workflow can call [`Gonio::run_plate`] many times with the same seed (common random numbers)
//! and a different rough face.
//!
//! Two photon loops: `fast` (infinite plate, polished faces, single-scattering GGX or
//! Beckmann faces and dotted faces of these: f32 fast math, NDF resolved once, see
//! `gonio/fast.rs`) and the general
//! `trace_photon` (finite plates, multiple scattering, height-correlated G, numerical NDFs).
//! Both follow the same random-number contract.
//!
//! Mitsuba compatibility: [`Scattering::SingleMitsuba`] evaluates G1 as Mitsuba 3 does (for
//! Beckmann Walter et al.'s rational approximation, < 0.35 % off the exact erf form, which
//! shifts e.g. `lost` of the Beckmann α = 0.25 plate at 60° by ~0.6 %, visible at 16 M photons);
//! [`Scattering::Single`] keeps the exact form.
//!
//! Tests: polished plate vs the closed form T = (1−R)²/(1−R²); thread-count independence;
//! energy bookkeeping; fast loop vs general loop (z-tests of totals and detectors); detector
//! look-up vs brute force; `tests/gonio_reference.rs` compares with the Mitsuba reference data.

mod acc;
mod detectors;
mod fast;

use acc::{Acc, Exchange};

pub use detectors::{Detector, DetectorGrid, DetectorLayout, Detectors, Side};

use crate::bsdf::TransportMode;
use crate::bsdf::microfacet::Ndfs;
use crate::bsdf::rough_dielectric::{RoughDielectric, Shadowing};
use crate::bsdf::rough_dielectric_ms::RoughDielectricMs;
use crate::math::{Vec2, Vec3, fresnel_dielectric};
use crate::sampling::{Rng, square_to_uniform_cone, square_to_uniform_disk_concentric};
use rayon::prelude::*;

/// Photons per batch (the unit of parallel work and of random-number streams).
pub const BATCH: u64 = 1 << 14;

/// How a rough face scatters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Scattering {
    /// Single scattering, separable Smith G (Mitsuba's `roughdielectric`).
    #[default]
    Single,
    /// Single scattering, separable Smith G with G1 evaluated as Mitsuba 3 does (Beckmann:
    /// Walter et al.'s rational approximation; other NDFs: identical to `Single`). Use it to
    /// reproduce Mitsuba's `roughdielectric` exactly.
    SingleMitsuba,
    /// Single scattering, height-correlated Smith G.
    SingleHeightCorrelated,
    /// Multiple scattering on the micro-surface (random walk, energy-conserving).
    Multiple,
}

/// One face of the plate.
#[derive(Clone, Debug)]
pub enum Face {
    /// Optically smooth (Fresnel).
    Polished,
    /// Rough, with its NDF and scattering model.
    Rough {
        /// Micro-facet normal distribution.
        ndf: Ndfs,
        /// Scattering model.
        scattering: Scattering,
    },
    /// Dotted face: a fraction `coverage` of the area is `dots`, the rest `land` (each
    /// `Polished` or `Rough`, not nested): an area mixture, see [`crate::bsdf::Dotted`]. A
    /// light-guide plate's dotted face is rough dots on a polished land.
    Dotted {
        /// Fraction f ∈ [0, 1] of the face covered by `dots`.
        coverage: f64,
        /// The covered fraction (usually rough).
        dots: Box<Face>,
        /// The rest (usually polished).
        land: Box<Face>,
    },
}

impl Face {
    /// Whether any part of the face is rough.
    pub fn is_rough(&self) -> bool {
        match self {
            Face::Polished => false,
            Face::Rough { .. } => true,
            Face::Dotted { dots, land, .. } => dots.is_rough() || land.is_rough(),
        }
    }

    /// A dotted face of rough dots (`ndf`, `scattering`) covering `coverage` of a polished land.
    pub fn dotted(coverage: f64, ndf: Ndfs, scattering: Scattering) -> Face {
        Face::Dotted {
            coverage,
            dots: Box::new(Face::Rough { ndf, scattering }),
            land: Box::new(Face::Polished),
        }
    }
}

/// The sample: a plane-parallel plate.
#[derive(Clone, Debug)]
pub struct Plate {
    /// Refractive index of the plate (outside: 1).
    pub ior: f64,
    /// Thickness in mm.
    pub thickness_mm: f64,
    /// Absorption coefficient μ in 1/mm (0 = clear).
    pub absorption_per_mm: f64,
    /// The lit face (z = 0).
    pub front: Face,
    /// The back face (z = −thickness).
    pub back: Face,
    /// Radius of a finite (disk-shaped) plate in mm; `None` = infinite plate. Photons reaching
    /// the rim of a finite plate are counted as `lost` (the edge is not modelled).
    pub radius_mm: Option<f64>,
}

/// The collimated beam.
#[derive(Clone, Debug)]
pub struct Beam {
    /// Azimuth of the plane of incidence (radians).
    pub azimuth: f64,
    /// Half-angle of the cone of directions (radians; 0 = perfectly collimated).
    pub divergence: f64,
    /// Radius of the beam's circular cross-section in mm (matters for finite plates only).
    pub aperture_radius_mm: f64,
}

/// Everything the simulator needs besides the plate.
#[derive(Clone, Debug)]
pub struct GonioSetup {
    /// Beam.
    pub beam: Beam,
    /// Incidence angles (radians).
    pub incidences: Vec<f64>,
    /// Detector layout.
    pub detectors: DetectorLayout,
    /// Photons per incidence angle.
    pub photons: u64,
    /// Seed of the random streams.
    pub seed: u64,
    /// Interaction limit per photon (the rest is `lost_maxdepth`).
    pub max_interactions: u32,
}

/// Per-incidence result.
#[derive(Clone, Debug)]
pub struct IncidenceResult {
    /// Incidence angle (radians).
    pub incidence: f64,
    /// Per detector (same order as [`Detectors::list`]): value [1/sr].
    pub value: Vec<f64>,
    /// Standard error of `value`.
    pub value_stderr: Vec<f64>,
    /// BSDF-like cone average Σ(w/|cos θ|)/(N Ω) [1/sr].
    pub bsdf: Vec<f64>,
    /// Number of photons counted per detector.
    pub hits: Vec<u64>,
    /// Fraction of the incident power leaving on side R.
    pub r: f64,
    /// Fraction leaving on side T.
    pub t: f64,
    /// Fraction lost by the single-scattering model, at the rim of a finite plate, or after
    /// the interaction limit.
    pub lost: f64,
    /// Fraction absorbed in the bulk.
    pub absorbed: f64,
    /// Mean number of surface interactions per photon.
    pub mean_interactions: f64,
    /// Photons that produced a non-finite weight or direction (must be 0).
    pub bad_photons: u64,
}

/// Result of a run.
#[derive(Clone, Debug)]
pub struct GonioResult {
    /// One entry per incidence angle.
    pub incidences: Vec<IncidenceResult>,
    /// Photons per incidence.
    pub photons: u64,
}

/// Interaction model of one face, prepared for the photon loop.
#[derive(Clone, Debug)]
enum FaceModel {
    Polished,
    Single(RoughDielectric),
    Multiple(RoughDielectricMs),
    /// Area mixture: `a` with probability `f`, else `b` (neither is `Dotted`).
    Dotted {
        f: f32,
        a: Box<FaceModel>,
        b: Box<FaceModel>,
    },
}

impl FaceModel {
    fn new(face: &Face, ior: f32) -> crate::Result<Self> {
        Ok(match face {
            Face::Polished => FaceModel::Polished,
            Face::Rough { ndf, scattering } => match scattering {
                Scattering::Single => {
                    FaceModel::Single(RoughDielectric::new(ndf.clone(), ior, Shadowing::Separable)?)
                }
                Scattering::SingleMitsuba => {
                    FaceModel::Single(RoughDielectric::new(ndf.clone(), ior, Shadowing::SeparableMitsuba)?)
                }
                Scattering::SingleHeightCorrelated => {
                    FaceModel::Single(RoughDielectric::new(ndf.clone(), ior, Shadowing::HeightCorrelated)?)
                }
                Scattering::Multiple => FaceModel::Multiple(RoughDielectricMs::new(ndf.clone(), ior)?),
            },
            Face::Dotted { coverage, dots, land } => {
                if !(coverage.is_finite() && (0.0..=1.0).contains(coverage)) {
                    return Err(crate::Error::invalid(
                        "coverage",
                        format!("must be in [0, 1], got {coverage}"),
                    ));
                }
                if matches!(**dots, Face::Dotted { .. }) || matches!(**land, Face::Dotted { .. }) {
                    return Err(crate::Error::invalid(
                        "dotted face",
                        "the dots and the land cannot be dotted again",
                    ));
                }
                FaceModel::Dotted {
                    f: *coverage as f32,
                    a: Box::new(FaceModel::new(dots, ior)?),
                    b: Box::new(FaceModel::new(land, ior)?),
                }
            }
        })
    }
}

/// Per-incidence constants of the beam.
#[derive(Clone, Copy)]
struct BeamFrame {
    sa: f32,
    ca: f32,
    st: f32,
    ct: f32,
    cos_div: f32,
}

/// The simulator: a validated setup with its detector look-up.
#[derive(Clone, Debug)]
pub struct Gonio {
    setup: GonioSetup,
    dets: Detectors,
    force_general: bool,
    simd: bool,
    /// Set from outside to stop a run early (see [`Gonio::with_cancel`]).
    cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Processes that share the batches (see [`Gonio::with_comm`]); `None` = this one alone.
    comm: Option<std::sync::Arc<dyn crate::dist::Comm>>,
}

/// Checks a plate's parameters (what the CLI and a fitting workflow must reject).
pub fn validate_plate(p: &Plate) -> crate::Result<()> {
    if !(p.ior.is_finite() && p.ior > 0.0) {
        return Err(crate::Error::invalid("ior", format!("must be > 0, got {}", p.ior)));
    }
    if !(p.thickness_mm.is_finite() && p.thickness_mm > 0.0) {
        return Err(crate::Error::invalid("thickness_mm", format!("must be > 0, got {}", p.thickness_mm)));
    }
    if !(p.absorption_per_mm.is_finite() && p.absorption_per_mm >= 0.0) {
        return Err(crate::Error::invalid(
            "absorption_per_mm",
            format!("must be ≥ 0, got {}", p.absorption_per_mm),
        ));
    }
    if let Some(r) = p.radius_mm
        && !(r.is_finite() && r > 0.0)
    {
        return Err(crate::Error::invalid("radius_mm", format!("must be > 0, got {r}")));
    }
    let rough = p.front.is_rough() || p.back.is_rough();
    if rough && (p.ior - 1.0).abs() < 1e-4 {
        return Err(crate::Error::invalid("ior", format!("a rough face needs ior ≠ 1, got {}", p.ior)));
    }
    Ok(())
}

impl Gonio {
    /// Validates the setup and builds the detector look-up.
    pub fn new(setup: GonioSetup) -> crate::Result<Self> {
        let b = &setup.beam;
        if !(b.divergence.is_finite() && (0.0..std::f64::consts::FRAC_PI_2).contains(&b.divergence)) {
            return Err(crate::Error::invalid(
                "divergence",
                format!("must be in [0°, 90°), got {}°", b.divergence.to_degrees()),
            ));
        }
        if !(b.aperture_radius_mm.is_finite() && b.aperture_radius_mm >= 0.0) {
            return Err(crate::Error::invalid(
                "aperture_radius_mm",
                format!("must be ≥ 0, got {}", b.aperture_radius_mm),
            ));
        }
        if !b.azimuth.is_finite() {
            return Err(crate::Error::invalid("azimuth", "must be finite"));
        }
        for &t in &setup.incidences {
            if !(t.is_finite() && (0.0..std::f64::consts::FRAC_PI_2).contains(&t)) {
                return Err(crate::Error::invalid(
                    "incidence",
                    format!("must be in [0°, 90°), got {}°", t.to_degrees()),
                ));
            }
        }
        if setup.photons == 0 {
            return Err(crate::Error::invalid("photons", "must be > 0"));
        }
        let dets = Detectors::new(&setup.detectors, setup.beam.azimuth)?;
        Ok(Gonio { setup, dets, force_general: false, simd: true, cancel: None, comm: None })
    }

    /// A flag that stops a run early when set (e.g. by Ctrl-C): the run returns
    /// [`crate::Error::Interrupted`] at its next group of batches. Unset, results are unchanged.
    pub fn with_cancel(mut self, cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>) -> Self {
        self.cancel = cancel;
        self
    }

    /// Shares every run's photon batches with the other processes of `comm`: batch `b` is
    /// traced by rank `b mod size`, the batch accumulators are exchanged whole and every rank
    /// merges them in batch order, so each rank gets the result one process computes, bit for
    /// bit. Every rank must make the same runs in the same order (and a cancel flag, if any,
    /// must be set on every rank: a rank that stops alone leaves the others waiting).
    pub fn with_comm(mut self, comm: Option<std::sync::Arc<dyn crate::dist::Comm>>) -> Self {
        self.comm = comm;
        self
    }

    fn cancelled(&self) -> bool {
        self.cancel.as_ref().is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Forces the general photon loop even where the fast one applies (for comparisons and
    /// benchmarks; the results agree in distribution, not bit for bit).
    pub fn with_general_loop(mut self, yes: bool) -> Self {
        self.force_general = yes;
        self
    }

    /// `false` runs the fast photon loop with the portable kernels (the target's baseline
    /// instruction set) instead of the widest SIMD version the CPU supports (AVX2 or AVX-512,
    /// detected at run time). The results are identical bit for bit; for tests and benchmarks.
    pub fn with_simd(mut self, yes: bool) -> Self {
        self.simd = yes;
        self
    }

    /// The setup.
    pub fn setup(&self) -> &GonioSetup {
        &self.setup
    }

    /// The detectors (axes, sides, labels).
    pub fn detectors(&self) -> &Detectors {
        &self.dets
    }

    /// Simulates every incidence angle for `plate`.
    pub fn run_plate(&self, plate: &Plate) -> crate::Result<GonioResult> {
        self.run_plate_with_progress(plate, &|| {})
    }

    /// Same, calling `tick` once per finished batch (progress bars).
    pub fn run_plate_with_progress(
        &self,
        plate: &Plate,
        tick: &(dyn Fn() + Sync),
    ) -> crate::Result<GonioResult> {
        validate_plate(plate)?;
        if self.dets.distance_mm().is_some() != plate.radius_mm.is_some() {
            return Err(crate::Error::invalid(
                "detectors.distance_mm",
                "a finite plate (radius_mm) needs detectors at a distance, and detectors at a distance need a finite plate",
            ));
        }
        let ior = plate.ior as f32;
        let front = FaceModel::new(&plate.front, ior)?;
        let back = FaceModel::new(&plate.back, ior)?;
        let fast = if self.force_general { None } else { fast::FastPlate::new(plate) };
        let kernels = fast::Kernels::detect(self.simd);
        let mut out = Vec::with_capacity(self.setup.incidences.len());
        let mut ex = Exchange::default();
        for (ii, &inc) in self.setup.incidences.iter().enumerate() {
            let faces = (&front, &back);
            out.push(self.run_incidence(plate, faces, fast.as_ref(), kernels, ii as u64, inc, tick, &mut ex));
            if self.cancelled() {
                return Err(crate::Error::Interrupted {
                    kept: "nothing (the simulation was not finished)".into(),
                });
            }
        }
        Ok(GonioResult { incidences: out, photons: self.setup.photons })
    }

    #[allow(clippy::too_many_arguments)]
    fn run_incidence(
        &self,
        plate: &Plate,
        (front, back): (&FaceModel, &FaceModel),
        fast: Option<&fast::FastPlate>,
        kernels: fast::Kernels,
        stream: u64,
        inc: f64,
        tick: &(dyn Fn() + Sync),
        ex: &mut Exchange,
    ) -> IncidenceResult {
        let n = self.setup.photons;
        let nb = n.div_ceil(BATCH);
        let ndet = self.dets.len();
        let comm = self.comm.as_deref().filter(|c| c.size() > 1);
        // groups of batches bound the memory of the per-batch accumulators (64 per process); split
        // across processes, each group ends with an exchange where every rank waits for the
        // slowest: larger groups (≈ 8 MB of accumulators per process, at most 1024 batches) wait
        // less often. The merge order (batch order) and so the result do not depend on the group.
        let group = match comm {
            None => 64,
            Some(c) => ((8 << 20) / (32 * ndet as u64 + 48)).clamp(64, 1024) * c.size() as u64,
        };
        let mut total = Acc::new(ndet);
        let mut g0 = 0;
        while g0 < nb {
            if self.cancelled() {
                // the caller discards this incidence and returns `Interrupted`
                break;
            }
            let g1 = (g0 + group).min(nb);
            let mine: Vec<u64> = (g0..g1).filter(|&b| comm.is_none_or(|c| c.owns(b))).collect();
            let accs: Vec<Acc> = mine
                .into_par_iter()
                .map(|b| {
                    let mut acc = Acc::new(ndet);
                    let count = BATCH.min(n - b * BATCH);
                    let a = self.setup.beam.azimuth;
                    let bf = BeamFrame {
                        sa: a.sin() as f32,
                        ca: a.cos() as f32,
                        st: inc.sin() as f32,
                        ct: inc.cos() as f32,
                        cos_div: self.setup.beam.divergence.cos() as f32,
                    };
                    if let Some(fp) = fast {
                        self.trace_batch_fast(fp, &bf, stream, b * BATCH, count, &mut acc, kernels);
                    } else {
                        for k in 0..count {
                            // one stream per photon: a photon keeps its random numbers whatever
                            // the other photons consumed (common random numbers for fitting)
                            let mut rng = Rng::new(self.setup.seed, stream, b * BATCH + k);
                            self.trace_photon(plate, front, back, &bf, &mut rng, &mut acc);
                        }
                    }
                    tick();
                    acc
                })
                .collect();
            match comm {
                Some(c) => ex.merge(c, g0..g1, &accs, &mut total),
                None => accs.iter().for_each(|a| total.merge(a)),
            }
            g0 = g1;
        }
        let nf = n as f64;
        let mut value = vec![0.0; ndet];
        let mut stderr = vec![0.0; ndet];
        let mut bsdf = vec![0.0; ndet];
        for i in 0..ndet {
            let om = self.dets.solid_angle();
            value[i] = total.sum[i] / (nf * om);
            let mean = total.sum[i] / nf;
            let var = (total.sum2[i] / nf - mean * mean).max(0.0) / nf;
            stderr[i] = var.sqrt() / om;
            bsdf[i] = total.sum_bsdf[i] / (nf * om);
        }
        IncidenceResult {
            incidence: inc,
            value,
            value_stderr: stderr,
            bsdf,
            hits: total.hits,
            r: total.r / nf,
            t: total.t / nf,
            lost: total.lost / nf,
            absorbed: total.absorbed / nf,
            mean_interactions: total.interactions as f64 / nf,
            bad_photons: total.bad,
        }
    }

    #[inline]
    fn trace_photon(
        &self,
        plate: &Plate,
        front: &FaceModel,
        back: &FaceModel,
        bf: &BeamFrame,
        rng: &mut Rng,
        acc: &mut Acc,
    ) {
        let beam = &self.setup.beam;
        let BeamFrame { sa, ca, st, ct, cos_div } = *bf;
        let k0 = Vec3::new(st * ca, st * sa, -ct);
        let mut d = if beam.divergence > 0.0 {
            let local = square_to_uniform_cone(rng.next_2d(), cos_div);
            // frame around k0: e1 in the plane of incidence, e2 normal to it
            let e1 = Vec3::new(ct * ca, ct * sa, st);
            let e2 = Vec3::new(-sa, ca, 0.0);
            (e1 * local.x + e2 * local.y + k0 * local.z).normalize()
        } else {
            k0
        };
        let finite = plate.radius_mm.is_some();
        let mut pos = Vec2::ZERO;
        if finite {
            // a point of the beam's circular cross-section, projected along d onto z = 0
            let q = square_to_uniform_disk_concentric(rng.next_2d()) * beam.aperture_radius_mm as f32;
            let e1 = Vec3::new(ct * ca, ct * sa, st);
            let e2 = Vec3::new(-sa, ca, 0.0);
            let p3 = e1 * q.x + e2 * q.y;
            // move along d until z = 0
            let s = -p3.z / d.z;
            pos = Vec2::new(p3.x + s * d.x, p3.y + s * d.y);
            if pos.length_squared() as f64 > plate.radius_mm.unwrap_or(0.0).powi(2) {
                // the beam is wider than the plate: this photon passes by, unscattered
                acc.t += 1.0;
                let wf = 1.0;
                let inv_cos = 1.0 / (d.z.abs() as f64).max(1e-6);
                self.dets.for_each_hit(Side::T, d, Vec3::new(pos.x, pos.y, 0.0), |i| {
                    acc.sum[i] += wf;
                    acc.sum2[i] += wf * wf;
                    acc.sum_bsdf[i] += wf * inv_cos;
                    acc.hits[i] += 1;
                });
                return;
            }
        }
        let thick = plate.thickness_mm as f32;
        let mu = plate.absorption_per_mm as f32;
        let mut w = 1.0f32;
        let mut top = true; // the face the photon is at
        for _ in 0..self.setup.max_interactions {
            acc.interactions += 1;
            let model = if top { front } else { back };
            // local frame of the face: +z = outward normal; bottom face = rotation by π about x
            let to_local = |v: Vec3| if top { v } else { Vec3::new(v.x, -v.y, -v.z) };
            let wo = to_local(-d);
            let Some(wi) = interact(model, plate.ior as f32, wo, None, rng, &mut w, acc) else {
                return;
            };
            let dn = to_local(wi); // the rotation is an involution
            if !(dn.is_finite() && w.is_finite()) {
                acc.bad += 1;
                return;
            }
            d = dn;
            let exits = if top { d.z > 0.0 } else { d.z < 0.0 };
            if exits {
                let side = if top { Side::R } else { Side::T };
                let p3 =
                    if finite { Vec3::new(pos.x, pos.y, if top { 0.0 } else { -thick }) } else { Vec3::ZERO };
                match side {
                    Side::R => acc.r += w as f64,
                    Side::T => acc.t += w as f64,
                }
                let wf = w as f64;
                let inv_cos = 1.0 / (d.z.abs() as f64).max(1e-6);
                self.dets.for_each_hit(side, d, p3, |i| {
                    acc.sum[i] += wf;
                    acc.sum2[i] += wf * wf;
                    acc.sum_bsdf[i] += wf * inv_cos;
                    acc.hits[i] += 1;
                });
                return;
            }
            // traverse the plate
            let len = thick / d.z.abs();
            if mu > 0.0 {
                let w2 = w * (-mu * len).exp();
                acc.absorbed += (w - w2) as f64;
                w = w2;
            }
            if finite {
                pos += Vec2::new(d.x, d.y) * len;
                if pos.length_squared() as f64 > plate.radius_mm.unwrap_or(0.0).powi(2) {
                    acc.lost += w as f64;
                    return;
                }
            }
            top = !top;
        }
        acc.lost += w as f64;
    }
}

/// One interaction with a face in importance mode: the new direction (local frame), the photon
/// weight updated (what the single-scattering model loses goes to `acc.lost`); `None` when the
/// photon is lost (its weight is booked). `uc`: the first random number when the caller drew it
/// already (a dotted face choosing its area), else drawn here — polished: one number (Fresnel
/// choice), single scattering: three (`uc`, then the visible normal), multiple scattering: its
/// own stream from `rng`.
#[inline]
fn interact(
    model: &FaceModel,
    ior: f32,
    wo: Vec3,
    uc: Option<f32>,
    rng: &mut Rng,
    w: &mut f32,
    acc: &mut Acc,
) -> Option<Vec3> {
    match model {
        FaceModel::Polished => {
            let (r, _) = fresnel_dielectric(wo.z, ior);
            let uc = uc.unwrap_or_else(|| rng.next_f32());
            Some(if uc < r {
                Vec3::new(-wo.x, -wo.y, wo.z)
            } else {
                let (n, eta) = if wo.z > 0.0 { (Vec3::Z, ior) } else { (-Vec3::Z, 1.0 / ior) };
                match crate::math::refract(wo, n, eta) {
                    Some(t) => t,
                    None => Vec3::new(-wo.x, -wo.y, wo.z),
                }
            })
        }
        FaceModel::Single(b) => {
            let uc = uc.unwrap_or_else(|| rng.next_f32());
            let u = rng.next_2d();
            match b.sample_dir(wo, uc, u, TransportMode::Importance) {
                Some(s) => {
                    let w2 = *w * s.weight;
                    acc.lost += (*w - w2) as f64;
                    *w = w2;
                    Some(s.wi)
                }
                None => {
                    acc.lost += *w as f64;
                    None
                }
            }
        }
        FaceModel::Multiple(b) => match b.sample_dir(wo, rng) {
            Some(wi) => Some(wi),
            None => {
                acc.lost += *w as f64;
                None
            }
        },
        FaceModel::Dotted { f, a, b } => {
            let u = uc.unwrap_or_else(|| rng.next_f32());
            // the area choice reuses the number: rescaled, it is the component's first one
            let (m, ur) = if u < *f { (a, u / f) } else { (b, (u - f) / (1.0 - f)) };
            interact(m, ior, wo, Some(ur.min(1.0 - f32::EPSILON / 2.0)), rng, w, acc)
        }
    }
}

#[cfg(test)]
mod tests;
