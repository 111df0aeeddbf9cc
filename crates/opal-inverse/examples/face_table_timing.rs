//! Times the fitted-face table and the chessboard render (docs/performance.md):
//! `cargo run -p opal-inverse --example face_table_timing`.
//! Prints wall seconds of: building the default-grid table (GGX α = 0.15, n = 1.49), writing and
//! loading it, rendering the chessboard scene (240 × 180, 16 spp) with the table and with the
//! analytic rough dielectric it was built from (same scene, same seed), and the mean radiance
//! of both images.

use opal::bsdf::microfacet::Ndfs;
use opal::bsdf::tabulated::TableGrid;
use opal::bsdf::{Bxdfs, TabulatedBsdf};
use opal::integrator::path::{PathSettings, render};
use opal::scene::Scene;
use opal_inverse::export::face_bsdf;
use opal_inverse::face_table::{chessboard_scene, face_table};
use std::time::Instant;

fn main() -> opal::Result<()> {
    let ndf = Ndfs::ggx(0.15);
    let ior = 1.49;
    let t = Instant::now();
    let table = face_table(&ndf, ior, TableGrid::default(), "ggx 0.15")?;
    println!("build table: {:.3} s", t.elapsed().as_secs_f64());
    let dir = std::env::temp_dir().join("opal_face_table_timing.obsdf");
    let t = Instant::now();
    table.save(&dir)?;
    let loaded = TabulatedBsdf::load(&dir)?;
    println!(
        "save + load ({} bytes): {:.3} s",
        std::fs::metadata(&dir).map(|m| m.len()).unwrap_or(0),
        t.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_file(&dir);
    let s = PathSettings { spp: 16, max_depth: 12, rr_depth: 4, hide_emitters: false, seed: 7 };
    for (name, face) in [
        ("tabulated", Bxdfs::Tabulated(loaded)),
        ("analytic", Bxdfs::RoughDielectric(face_bsdf(ndf.clone(), ior)?)),
    ] {
        let scene = Scene::build(&chessboard_scene(face, ior, 240, 180)?)?;
        let t = Instant::now();
        let out = render(&scene, 0, &s, &|| {});
        println!("render {name}: {:.3} s, mean {:?}", t.elapsed().as_secs_f64(), out.image.mean());
    }
    Ok(())
}
