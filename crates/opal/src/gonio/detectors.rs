//! Circular detectors of the goniophotometer and their fast look-up.
//!
//! A detector is an axis (unit vector, world frame) and an angular radius r, on side R
//! (axis z > 0, photons leaving the lit face) or T (axis z < 0, photons leaving the back face).
//! Neighbouring detectors may overlap (a photon is then counted by each). The look-up bins a
//! direction by its components parallel to the plate, `(d_x, d_y)` (the orthographic projection
//! of each hemisphere onto the unit disk), on an n × n grid per side — no `acos`/`atan2`, two
//! multiply-adds per photon. Each cell lists the detectors whose cap may project into it (the
//! bounding box of the projected cap boundary, of the part of the horizon inside the cap, and a
//! margin), so counting a photon costs one cell look-up and a few dot products. Cells are
//! about half a detector radius wide (n ≤ 512); near the horizon a cell spans a larger polar
//! angle (dθ = dρ/cos θ), which only lengthens its candidate list.
//! Test: `gonio::tests::detector_lookup_matches_brute_force` (every detector, random and
//! near-boundary directions, both layouts).

use crate::math::Vec3;
use std::f64::consts::PI;

/// Side of the plate a detector looks at.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    /// Reflected side (z > 0).
    R,
    /// Transmitted side (z < 0).
    T,
}

impl Side {
    /// "R" or "T".
    pub fn label(self) -> &'static str {
        match self {
            Side::R => "R",
            Side::T => "T",
        }
    }
}

/// Where the detectors are.
#[derive(Clone, Debug, PartialEq)]
pub enum DetectorGrid {
    /// In the plane of incidence at these signed angles p (radians, −90° < p < 90°), on both
    /// sides (axis `(sin p cos φb, sin p sin φb, ±cos p)`).
    PlaneOfIncidence {
        /// Signed angles from the plate normal (positive towards the specular direction).
        angles: Vec<f64>,
    },
    /// Over both hemispheres: polar angles θ (radians, 0 ≤ θ < 90°) × azimuths φ (radians,
    /// measured from the plane of incidence); at θ = 0 a single detector.
    Hemisphere {
        /// Polar angles.
        polar: Vec<f64>,
        /// Azimuths.
        azimuth: Vec<f64>,
    },
}

/// Detector layout: grid, angular radius and (optionally) the distance from the plate centre.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorLayout {
    /// Positions.
    pub grid: DetectorGrid,
    /// Angular radius r (radians, 0 < r < 90°).
    pub radius: f64,
    /// Distance of the detectors from the plate centre in mm (finite plates only); `None` =
    /// far field (only the direction of a photon matters).
    pub distance_mm: Option<f64>,
}

/// One detector.
#[derive(Clone, Copy, Debug)]
pub struct Detector {
    /// Side.
    pub side: Side,
    /// Axis (world frame, unit).
    pub axis: Vec3,
    /// Signed angle p in the plane of incidence, or polar angle θ (degrees, for output).
    pub angle_deg: f64,
    /// Azimuth from the plane of incidence (degrees; 0 for the plane layout).
    pub azimuth_deg: f64,
}

/// The detectors with their look-up grid.
#[derive(Clone, Debug)]
pub struct Detectors {
    list: Vec<Detector>,
    cos_r: f32,
    omega: f64,
    distance: Option<f32>,
    /// Grid size per side (n × n cells over [−1, 1]²).
    n: usize,
    /// Per grid row (side R rows, then side T rows): the range `[lo, hi)` of its non-empty
    /// columns and the index in `start` of column `lo` (keeps the look-up data small: for the
    /// plane-of-incidence layout a few cells per row).
    rows: Vec<[u32; 3]>,
    /// Start offsets into `items` of the stored cells, row by row, plus the final end.
    start: Vec<u32>,
    items: Vec<u32>,
    /// Axes as plain arrays, same order as `list` (compact for the look-up loop).
    axes: Vec<[f32; 3]>,
    hemisphere: bool,
}

impl Detectors {
    /// Builds the detectors for a beam of azimuth `azimuth` (radians).
    pub fn new(layout: &DetectorLayout, azimuth: f64) -> crate::Result<Self> {
        let r = layout.radius;
        if !(r.is_finite() && r > 0.0 && r < PI / 2.0) {
            return Err(crate::Error::invalid(
                "detectors.radius_deg",
                format!("must be in (0°, 90°), got {}°", r.to_degrees()),
            ));
        }
        if let Some(dist) = layout.distance_mm
            && !(dist.is_finite() && dist > 0.0)
        {
            return Err(crate::Error::invalid("detectors.distance_mm", format!("must be > 0, got {dist}")));
        }
        let (ca, sa) = (azimuth.cos(), azimuth.sin());
        let mut list = Vec::new();
        let mut hemisphere = false;
        match &layout.grid {
            DetectorGrid::PlaneOfIncidence { angles } => {
                for side in [Side::R, Side::T] {
                    for &p in angles {
                        if !(p.is_finite() && p.abs() < PI / 2.0) {
                            return Err(crate::Error::invalid(
                                "detectors.angles_deg",
                                format!("must be in (−90°, 90°), got {}°", p.to_degrees()),
                            ));
                        }
                        let z = if side == Side::R { p.cos() } else { -p.cos() };
                        let axis = Vec3::new((p.sin() * ca) as f32, (p.sin() * sa) as f32, z as f32);
                        list.push(Detector { side, axis, angle_deg: p.to_degrees(), azimuth_deg: 0.0 });
                    }
                }
            }
            DetectorGrid::Hemisphere { polar, azimuth: phis } => {
                hemisphere = true;
                for side in [Side::R, Side::T] {
                    for &t in polar {
                        if !(t.is_finite() && (0.0..PI / 2.0).contains(&t)) {
                            return Err(crate::Error::invalid(
                                "detectors.polar_deg",
                                format!("must be in [0°, 90°), got {}°", t.to_degrees()),
                            ));
                        }
                        let phis_here: &[f64] = if t == 0.0 { &[0.0] } else { phis };
                        for &ph in phis_here {
                            let a = azimuth + ph;
                            let z = if side == Side::R { t.cos() } else { -t.cos() };
                            let axis =
                                Vec3::new((t.sin() * a.cos()) as f32, (t.sin() * a.sin()) as f32, z as f32);
                            list.push(Detector {
                                side,
                                axis,
                                angle_deg: t.to_degrees(),
                                azimuth_deg: ph.to_degrees(),
                            });
                        }
                    }
                }
            }
        }
        if list.is_empty() {
            return Err(crate::Error::invalid("detectors", "no detector defined"));
        }
        // look-up grid over (d_x, d_y) per side: cells of ~r/2 (in projected units sin r / 2)
        let n = ((4.0 / r.sin()).ceil() as usize).clamp(8, 512);
        let h = 2.0 / n as f64;
        let cell_of = |x: f64| (((x + 1.0) / h).floor().max(0.0) as usize).min(n - 1);
        let mut cells: Vec<Vec<u32>> = vec![Vec::new(); 2 * n * n];
        for (k, det) in list.iter().enumerate() {
            let a = det.axis.as_dvec3();
            let (e1, e2) = a.any_orthonormal_pair();
            let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            let mut add = |p: crate::math::DVec3| {
                x0 = x0.min(p.x);
                x1 = x1.max(p.x);
                y0 = y0.min(p.y);
                y1 = y1.max(p.y);
            };
            // cap boundary (a convex curve on the sphere: its projection bounds the projected cap
            // unless the cap crosses the horizon, whose arc inside the cap is added below)
            let nb = 256;
            for i in 0..nb {
                let b = 2.0 * PI * i as f64 / nb as f64;
                add(a * r.cos() + (e1 * b.cos() + e2 * b.sin()) * r.sin());
            }
            add(a);
            let nh = if a.z.abs() < (r + 0.01).min(PI / 2.0).sin() { 4096 } else { 0 };
            for i in 0..nh {
                let b = 2.0 * PI * i as f64 / nh as f64;
                let p = crate::math::DVec3::new(b.cos(), b.sin(), 0.0);
                if p.dot(a) >= (r + 2.0 * PI / nh as f64).cos() {
                    add(p);
                }
            }
            // margin: chord sagitta of the sampled boundary (r·(π/nb)²/2 < 8e-5); the horizon
            // samples extend one step beyond the cap, covering the ends of its arc
            let m = 1e-4;
            let side_off = if det.side == Side::R { 0 } else { n * n };
            for i in cell_of(x0 - m)..=cell_of(x1 + m) {
                for j in cell_of(y0 - m)..=cell_of(y1 + m) {
                    cells[side_off + i * n + j].push(k as u32);
                }
            }
        }
        let mut rows = Vec::with_capacity(2 * n);
        let mut start = Vec::new();
        let mut items = Vec::new();
        for row in cells.chunks(n) {
            let lo = row.iter().position(|c| !c.is_empty()).unwrap_or(0);
            let hi = row.iter().rposition(|c| !c.is_empty()).map_or(0, |j| j + 1);
            rows.push([lo as u32, hi.max(lo) as u32, start.len() as u32]);
            for c in &row[lo..hi.max(lo)] {
                start.push(items.len() as u32);
                items.extend_from_slice(c);
            }
        }
        start.push(items.len() as u32);
        let axes = list.iter().map(|d| [d.axis.x, d.axis.y, d.axis.z]).collect();
        Ok(Detectors {
            list,
            cos_r: r.cos() as f32,
            omega: 2.0 * PI * (1.0 - r.cos()),
            distance: layout.distance_mm.map(|d| d as f32),
            n,
            rows,
            start,
            items,
            axes,
            hemisphere,
        })
    }

    /// Number of detectors (both sides).
    pub fn len(&self) -> usize {
        self.list.len()
    }
    /// Never true (construction refuses an empty layout).
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }
    /// The detectors: side R first, then side T.
    pub fn list(&self) -> &[Detector] {
        &self.list
    }
    /// Solid angle of one detector, 2π(1 − cos r).
    pub fn solid_angle(&self) -> f64 {
        self.omega
    }
    /// Detector distance (finite plate) in mm.
    pub fn distance_mm(&self) -> Option<f64> {
        self.distance.map(|d| d as f64)
    }
    /// True for the hemisphere layout.
    pub fn is_hemisphere(&self) -> bool {
        self.hemisphere
    }

    /// Direction in which the detectors see a photon leaving `p` along `d`: `d` itself in the far
    /// field, else the direction from the plate centre to where the photon crosses the detector
    /// sphere (`None` if it never does).
    #[inline]
    fn seen_direction(&self, d: Vec3, p: Vec3) -> Option<Vec3> {
        let Some(dist) = self.distance else { return Some(d) };
        let b = p.dot(d);
        let disc = b * b - (p.length_squared() - dist * dist);
        (disc >= 0.0).then(|| (p + d * (-b + disc.sqrt())).normalize())
    }

    /// Calls `f(i)` for every detector `i` of `side` that counts a photon leaving point `p`
    /// (plate frame, mm; ignored in the far field) in direction `d`.
    #[inline]
    pub fn for_each_hit(&self, side: Side, d: Vec3, p: Vec3, mut f: impl FnMut(usize)) {
        let Some(q) = self.seen_direction(d, p) else { return };
        let nf = self.n as f32;
        let ix = (((q.x + 1.0) * 0.5 * nf) as usize).min(self.n - 1);
        let iy = (((q.y + 1.0) * 0.5 * nf) as usize).min(self.n - 1);
        let [lo, hi, base] = self.rows[if side == Side::R { 0 } else { self.n } + ix];
        let iy = iy as u32;
        if iy < lo || iy >= hi {
            return;
        }
        let c = (base + iy - lo) as usize;
        let (a, b) = (self.start[c] as usize, self.start[c + 1] as usize);
        for &k in &self.items[a..b] {
            let ax = self.axes[k as usize];
            if ax[0] * q.x + ax[1] * q.y + ax[2] * q.z >= self.cos_r {
                f(k as usize);
            }
        }
    }

    /// Brute-force version of [`Detectors::for_each_hit`] (every detector of `side`), for tests.
    pub fn for_each_hit_brute_force(&self, side: Side, d: Vec3, p: Vec3, mut f: impl FnMut(usize)) {
        let Some(q) = self.seen_direction(d, p) else { return };
        for (k, det) in self.list.iter().enumerate() {
            if det.side == side && det.axis.dot(q) >= self.cos_r {
                f(k);
            }
        }
    }
}
