//! # Opal — forward light-transport engine
//!
//! The engine under Opal's three inverse methods (rough-surface BSDF recovery, physically
//! correct BRDFs, de-lighting). Conventions are written out in `docs/conventions.md`:
//! radians inside, degrees only at I/O; f32 for geometry and per-sample values, f64 for
//! accumulators, quadrature and statistics; a plain `pdf` is per unit solid angle.
//!
//! Modules:
//! * [`math`] — vectors (glam), orthonormal frames, reflection/refraction, Fresnel.
//! * [`spectrum`] — the RGB [`Spectrum`] newtype every colour goes through.
//! * [`sampling`] — counter-based random numbers and warping functions with their pdfs.
//! * [`bsdf`] — the [`Bxdf`](bsdf::Bxdf) contract, [`TransportMode`](bsdf::TransportMode) and models.
//! * [`fastmath`] — fast f32 polynomial sincos/exp/ln/erf/erfinv and Fresnel for hot loops.
//! * [`validate`] — χ² goodness-of-fit, quadrature helpers (product code: tests and CLI use it).
//! * [`texture`] — texture lookups (Mitsuba `bitmap` semantics).
//! * [`simd`] — the SIMD policy: instruction set detected once, lane types.
//! * [`mem`] — memory hints (huge pages) for large tables read at random.
//! * [`error`] — the library error type.
//! * [`dist`] — splitting work across processes ([`dist::Comm`]), bitwise independent of their count.
#![warn(missing_docs)]

pub mod accel;
pub mod bsdf;
pub mod camera;
pub mod dist;
pub mod error;
pub mod fastmath;
pub mod geometry;
pub mod gonio;
pub mod image;
pub mod integrator;
pub mod light;
pub mod math;
pub mod mem;
pub mod sampling;
pub mod scene;
pub mod simd;
pub mod spectrum;
pub mod texture;
pub mod validate;

pub use error::{Error, Result};
pub use spectrum::Spectrum;
