//! Circular detectors of the goniophotometer and their fast look-up.
//!
//! A detector is an axis (unit vector, world frame) and an angular radius r, on side R
//! (axis z > 0, photons leaving the lit face) or T (axis z < 0, photons leaving the back face).
//! Neighbouring detectors may overlap (a photon is then counted by each). The look-up is a
//! latitude–longitude grid over the sphere whose cells list the detectors that may contain a
//! direction of the cell, so counting a photon costs one cell lookup and a few dot products.

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
    nt: usize,
    np: usize,
    start: Vec<u32>,
    items: Vec<u32>,
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
        if let Some(dist) = layout.distance_mm {
            if !(dist.is_finite() && dist > 0.0) {
                return Err(crate::Error::invalid(
                    "detectors.distance_mm",
                    format!("must be > 0, got {dist}"),
                ));
            }
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
        // look-up grid: cells of ~max(r, 0.5°)
        let cell = r.max(0.5f64.to_radians());
        let nt = ((PI / cell).ceil() as usize).clamp(1, 720);
        let np = ((2.0 * PI / cell).ceil() as usize).clamp(1, 1440);
        let dt = PI / nt as f64;
        let dp = 2.0 * PI / np as f64;
        let margin = r + 1.5 * cell.max(dt).max(dp);
        let cos_margin = margin.min(PI).cos();
        let mut cells: Vec<Vec<u32>> = vec![Vec::new(); nt * np];
        for (k, det) in list.iter().enumerate() {
            let a = det.axis.as_dvec3();
            let ta = a.z.clamp(-1.0, 1.0).acos();
            let i0 = ((ta - margin) / dt).floor().max(0.0) as usize;
            let i1 = (((ta + margin) / dt).ceil() as usize).min(nt);
            for i in i0..i1 {
                let t = (i as f64 + 0.5) * dt;
                for j in 0..np {
                    let p = (j as f64 + 0.5) * dp;
                    let c = crate::math::spherical_direction_f64(t, p);
                    if c.dot(a) >= cos_margin {
                        cells[i * np + j].push(k as u32);
                    }
                }
            }
        }
        let mut start = Vec::with_capacity(nt * np + 1);
        let mut items = Vec::new();
        start.push(0u32);
        for c in &cells {
            items.extend_from_slice(c);
            start.push(items.len() as u32);
        }
        Ok(Detectors {
            list,
            cos_r: r.cos() as f32,
            omega: 2.0 * PI * (1.0 - r.cos()),
            distance: layout.distance_mm.map(|d| d as f32),
            nt,
            np,
            start,
            items,
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

    /// Calls `f(i)` for every detector `i` of `side` that counts a photon leaving point `p`
    /// (plate frame, mm; ignored in the far field) in direction `d`.
    #[inline]
    pub fn for_each_hit(&self, side: Side, d: Vec3, p: Vec3, mut f: impl FnMut(usize)) {
        let q = match self.distance {
            None => d,
            Some(dist) => {
                let b = p.dot(d);
                let c = p.length_squared() - dist * dist;
                let disc = b * b - c;
                if disc < 0.0 {
                    return;
                }
                let t = -b + disc.sqrt();
                (p + d * t).normalize()
            }
        };
        let theta = q.z.clamp(-1.0, 1.0).acos();
        let mut phi = q.y.atan2(q.x);
        if phi < 0.0 {
            phi += 2.0 * std::f32::consts::PI;
        }
        let i = ((theta * self.nt as f32 / std::f32::consts::PI) as usize).min(self.nt - 1);
        let j = ((phi * self.np as f32 / (2.0 * std::f32::consts::PI)) as usize).min(self.np - 1);
        let c = i * self.np + j;
        for &k in &self.items[self.start[c] as usize..self.start[c + 1] as usize] {
            let det = &self.list[k as usize];
            if det.side == side && det.axis.dot(q) >= self.cos_r {
                f(k as usize);
            }
        }
    }
}
