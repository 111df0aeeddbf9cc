//! Industry scatter-data file formats: tables of BRDF/BTDF values indexed by angle of
//! incidence and scatter direction, read and written so that measured data from an instrument
//! can be fitted directly and fitted faces can be handed to optical design software.
//!
//! * [`zemax`] — Zemax/OpticStudio tabular `.BSDF` (the Radiant "BSDF Data Interchange"
//!   layout): [`zemax::parse`] / [`zemax::read`] into a [`zemax::BsdfTable`], [`zemax::write`]
//!   back to text, [`zemax::BsdfTable::to_measured`] to the plane-of-incidence curves that
//!   [`crate::ndf_fit`] fits.
//!
//! Formats are documented in `docs/formats.md`; tests live next to each reader.

pub mod zemax;
