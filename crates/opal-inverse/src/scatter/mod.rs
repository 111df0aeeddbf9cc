//! Industry scatter-data file formats: tables of BRDF/BTDF values indexed by angle of
//! incidence and scatter direction, read and written so that measured data from an instrument
//! can be fitted directly and fitted faces can be handed to optical design software.
//!
//! * [`zemax`] — Zemax/OpticStudio tabular `.BSDF` (the Radiant "BSDF Data Interchange"
//!   layout): [`zemax::parse`] / [`zemax::read`] into a [`zemax::BsdfTable`], [`zemax::write`]
//!   back to text, [`zemax::BsdfTable::to_measured`] to the plane-of-incidence curves that
//!   [`crate::ndf_fit`] fits.
//! * [`lighttools`] — LightTools BSDF text (also written by Light Tec MiniDiff): both sides,
//!   R and T in one file, global spherical scatter angles: [`lighttools::parse`] /
//!   [`lighttools::read`] into a [`lighttools::LtTable`], [`lighttools::write`] back to text.
//!
//! Formats are documented in `docs/formats.md`; tests live next to each reader.

pub mod lighttools;
pub mod zemax;
