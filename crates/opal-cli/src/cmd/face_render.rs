//! `opal fit-ndf` outputs that make the fitted face a material: `face.obsdf` (the tabulated
//! BSDF of both sides, loadable with `<bsdf type="tabulated">`) and `chessboard.png` (the
//! plate over a chessboard under diffuse light, initial guess vs fitted face side by side —
//! the paper's Fig. 10). Library: [`opal_inverse::face_table`]; kept separate from the fitting
//! code so the two evolve independently.

use crate::plot::{LabelledImage, save_image_row};
use crate::util::write_bytes_atomic;
use anyhow::{Result, anyhow};
use opal::bsdf::microfacet::Ndfs;
use opal::bsdf::tabulated::TableGrid;
use opal::gonio::Scattering;
use opal_inverse::face_table::{face_table_for, render_chessboard};
use std::path::Path;

/// Chessboard render size and samples per pixel.
pub const RENDER_SIZE: (usize, usize) = (240, 180);
/// Samples per pixel of the chessboard render.
pub const RENDER_SPP: u32 = 16;

/// Writes `face.obsdf` for `fitted` (with the fit's scattering model) and, unless
/// `skip_render`, `chessboard.png` comparing the `initial` and `fitted` faces; returns a JSON
/// summary (file size, dropped power of a multiple-scattering table, seconds).
pub fn write_face_outputs(
    out: &Path,
    ior: f64,
    scattering: Scattering,
    initial: (&Ndfs, &str),
    fitted: (&Ndfs, &str),
    skip_render: bool,
) -> Result<serde_json::Value> {
    let t0 = std::time::Instant::now();
    let grid = TableGrid::default();
    let (table, dropped) =
        face_table_for(fitted.0, ior, grid, scattering, fitted.1).map_err(|e| anyhow!("face table: {e}"))?;
    let bytes = table.to_bytes();
    write_bytes_atomic(&out.join("face.obsdf"), &bytes)?;
    let table_seconds = t0.elapsed().as_secs_f64();
    let mut json = serde_json::json!({
        "face_obsdf": "face.obsdf",
        "face_obsdf_bytes": bytes.len(),
        "face_obsdf_dropped_fraction": dropped,
        "face_table_seconds": table_seconds,
    });
    if skip_render {
        return Ok(json);
    }
    let t1 = std::time::Instant::now();
    let (init_table, _) = face_table_for(initial.0, ior, grid, scattering, initial.1)
        .map_err(|e| anyhow!("face table: {e}"))?;
    let mut images = Vec::new();
    for (t, label) in
        [(&init_table, format!("initial: {}", initial.1)), (&table, format!("fitted: {}", fitted.1))]
    {
        let r = render_chessboard(t, ior, RENDER_SIZE, RENDER_SPP)
            .map_err(|e| anyhow!("chessboard render: {e}"))?;
        images.push(LabelledImage {
            width: RENDER_SIZE.0 as u32,
            height: RENDER_SIZE.1 as u32,
            rgb: opal::image::write::to_srgb8(&r.image, 1.0),
            label,
        });
    }
    save_image_row(&out.join("chessboard.png"), &images)?;
    json["chessboard_png"] = "chessboard.png".into();
    json["chessboard_seconds"] = t1.elapsed().as_secs_f64().into();
    json["chessboard_size"] = serde_json::json!([RENDER_SIZE.0, RENDER_SIZE.1]);
    json["chessboard_spp"] = RENDER_SPP.into();
    Ok(json)
}
