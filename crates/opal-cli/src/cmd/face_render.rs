//! `opal fit-ndf` outputs that make the fitted face a material: `face.obsdf` (the tabulated
//! BSDF of both sides, loadable with `<bsdf type="tabulated">`) and `chessboard.png` (the
//! plate over a chessboard under diffuse light, initial guess (for a dotted fit: the best single
//! NDF) vs fitted face side by side —
//! the paper's Fig. 10). Library: [`opal_inverse::face_table`]; kept separate from the fitting
//! code so the two evolve independently.

use crate::plot::{LabelledImage, save_image_row};
use crate::util::write_bytes_atomic;
use anyhow::{Result, anyhow};
use opal::bsdf::microfacet::Ndfs;
use opal::bsdf::tabulated::TableGrid;
use opal::bsdf::{Bxdfs, Dotted, SmoothDielectric};
use opal::gonio::Scattering;
use opal_inverse::face_table::{face_table_for, render_chessboard_face};
use std::path::Path;

/// Chessboard render size (pixels per image; two images side by side).
pub const RENDER_SIZE: (usize, usize) = (480, 360);
/// Samples per pixel of the chessboard render.
pub const RENDER_SPP: u32 = 32;

/// Writes `face.obsdf` for `fitted` (with the fit's scattering model) and, unless
/// `skip_render`, `chessboard.png` comparing the `initial` face (its label as given, e.g.
/// "initial: ggx α=0.1") and the `fitted` one; returns a JSON
/// summary (file size, dropped power of a multiple-scattering table, seconds). With
/// `coverage` = Some(f) the fitted face is dotted: `face.obsdf` is the dots' face (a table
/// cannot hold the polished land's delta lobes) and the render uses the dotted face itself
/// (f of the dots' table, 1 − f polished: [`opal::bsdf::Dotted`]).
pub fn write_face_outputs(
    out: &Path,
    ior: f64,
    scattering: Scattering,
    initial: (&Ndfs, &str),
    fitted: (&Ndfs, &str),
    coverage: Option<f64>,
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
    for (t, label) in [(&init_table, initial.1.to_string()), (&table, format!("fitted: {}", fitted.1))] {
        let face = match coverage {
            Some(f) if std::ptr::eq(t, &table) => Bxdfs::Dotted(
                Dotted::new(
                    f as f32,
                    Bxdfs::Tabulated(t.clone()),
                    Bxdfs::SmoothDielectric(SmoothDielectric::new(ior as f32)?),
                )
                .map_err(|e| anyhow!("dotted face: {e}"))?,
            ),
            _ => Bxdfs::Tabulated(t.clone()),
        };
        let r = render_chessboard_face(face, ior, RENDER_SIZE, RENDER_SPP)
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
    if let Some(f) = coverage {
        json["chessboard_dotted_coverage"] = f.into();
    }
    Ok(json)
}
