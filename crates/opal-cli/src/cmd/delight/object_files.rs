//! The per-object output files of `opal delight` (albedo EXR and PNG, mesh OBJ, each
//! iteration's error maps): encoded in parallel by one process, dealt to the ranks in rounds
//! under MPI (rank 0 writes every file atomically). Tests: the CLI tests `tests/delight.rs` and
//! the MPI tier `tests/mpi.rs` (same bytes for any number of ranks).

use super::html;
use crate::util;
use anyhow::Result;
use opal::image::Image;
use opal_inverse::delight::{DelightResult, ObjectResult};
use std::fmt::Write as _;
use std::path::Path;

/// The output files of each object, in this order: the albedo as EXR and as PNG (kind
/// [`ALBEDO_PNG`]), its mesh as OBJ, then each iteration's error map as PNG and EXR.
fn object_file_kinds(r: &DelightResult) -> usize {
    3 + 2 * r.iterations.len()
}

/// Kind of the albedo PNG among an object's files ([`object_file_kinds`]).
const ALBEDO_PNG: usize = 1;

/// Path (inside the output folder) of file `kind` of object `j`.
fn object_file_name(r: &DelightResult, j: usize, kind: usize) -> String {
    let id = &r.objects[j].id;
    match kind {
        0 => format!("albedo/{id}.exr"),
        ALBEDO_PNG => format!("albedo/{id}.png"),
        2 => format!("meshes/{id}.obj"),
        k => {
            let it = r.iterations[(k - 3) / 2].iteration;
            let ext = if (k - 3) % 2 == 0 { "png" } else { "exr" };
            format!("errors/iter_{it:02}_{id}.{ext}")
        }
    }
}

/// Encodes file `kind` of object `j` into `w`.
fn encode_object_file<W: std::io::Write + std::io::Seek>(
    r: &DelightResult,
    j: usize,
    kind: usize,
    mut w: W,
) -> Result<()> {
    let o = &r.objects[j];
    match kind {
        0 => opal::image::write::write_exr(&o.kd_image(), w)?,
        ALBEDO_PNG => opal::image::write::write_png_srgb(&o.kd_image(), 1.0, w)?,
        2 => w.write_all(obj_text(o).as_bytes())?,
        k => {
            let e = &r.iterations[(k - 3) / 2].error_maps[j];
            let (wd, ht) = (o.atlas.width, o.atlas.height);
            if (k - 3) % 2 == 0 {
                let abs: Vec<f32> = e.iter().map(|v| v.abs()).collect();
                opal::image::write::write_false_colour_png(&abs, wd, ht, html::TEXEL_ERROR_RANGE, w)?;
            } else {
                let mut ei = Image::new(wd, ht);
                // Unobserved texels (NaN in the library's map) are 0 here: no NaN in an output
                // file; the PNG marks them.
                for (p, v) in ei.data.iter_mut().zip(e) {
                    *p = opal::spectrum::Spectrum::splat(if v.is_finite() { *v } else { 0.0 });
                }
                opal::image::write::write_exr(&ei, w)?;
            }
        }
    }
    Ok(())
}

/// File `kind` of object `j` as bytes.
fn object_file_bytes(r: &DelightResult, j: usize, kind: usize) -> Result<Vec<u8>> {
    let mut c = std::io::Cursor::new(Vec::new());
    encode_object_file(r, j, kind, &mut c)?;
    Ok(c.into_inner())
}

/// Writes every object's files ([`object_file_kinds`]) and returns the albedo PNGs (for the
/// glTF; empty on ranks other than 0). One process encodes the files in parallel, each
/// straight into its file; under MPI the files are dealt to the ranks in rounds (file `i` of
/// round `k` on rank `i`), each rank encodes its file and sends the bytes, and rank 0 writes
/// them: the output work is split too, and at most one file per rank is in memory at a time.
pub(super) fn write_object_files(r: &DelightResult, out: &Path) -> Result<Vec<Vec<u8>>> {
    let units: Vec<(usize, usize)> =
        (0..r.objects.len()).flat_map(|j| (0..object_file_kinds(r)).map(move |k| (j, k))).collect();
    let pngs = vec![Vec::new(); r.objects.len()];
    let comm = crate::dist::comm_or_solo();
    let (rank, size) = (comm.rank(), comm.size());
    // a bar over the files (hidden with --quiet or off a terminal)
    let pb = util::progress(units.len() as u64, "outputs");
    let pngs = write_units(r, out, &units, pngs, (rank, size), &*comm, &pb);
    pb.finish_and_clear();
    pngs
}

/// [`write_object_files`]'s work: the `units` (object, kind) encoded and written, `pb` advanced
/// per file.
fn write_units(
    r: &DelightResult,
    out: &Path,
    units: &[(usize, usize)],
    mut pngs: Vec<Vec<u8>>,
    (rank, size): (usize, usize),
    comm: &dyn opal::dist::Comm,
    pb: &indicatif::ProgressBar,
) -> Result<Vec<Vec<u8>>> {
    use rayon::prelude::*;
    if size == 1 {
        let kept: Vec<Option<Vec<u8>>> = units
            .par_iter()
            .map(|&(j, k)| -> Result<Option<Vec<u8>>> {
                let path = out.join(object_file_name(r, j, k));
                if k == ALBEDO_PNG {
                    let b = object_file_bytes(r, j, k)?;
                    util::write_bytes_atomic(&path, &b)?;
                    pb.inc(1);
                    return Ok(Some(b));
                }
                util::write_atomic(&path, |f| encode_object_file(r, j, k, std::io::BufWriter::new(f)))?;
                pb.inc(1);
                Ok(None)
            })
            .collect::<Result<_>>()?;
        for (&(j, _), b) in units.iter().zip(kept) {
            if let Some(b) = b {
                pngs[j] = b;
            }
        }
        return Ok(pngs);
    }
    for round in units.chunks(size) {
        let mine = match round.get(rank) {
            Some(&(j, k)) => object_file_bytes(r, j, k)?,
            None => Vec::new(),
        };
        let all = comm.all_gather_bytes(&mine);
        pb.inc(round.len() as u64);
        if rank == 0 {
            for (&(j, k), b) in round.iter().zip(all) {
                util::write_bytes_atomic(&out.join(object_file_name(r, j, k)), &b)?;
                if k == ALBEDO_PNG {
                    pngs[j] = b;
                }
            }
        }
    }
    Ok(pngs)
}

/// OBJ text of an object's atlas mesh (OBJ `vt` has v = 0 at the bottom: v_obj = 1 − v).
fn obj_text(o: &ObjectResult) -> String {
    let m = &o.atlas.mesh;
    let mut s = format!("# opal delight: {} with atlas UVs ({}x{})\n", o.id, o.atlas.width, o.atlas.height);
    for p in &m.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for uv in &m.uvs {
        let _ = writeln!(s, "vt {} {}", uv.x, 1.0 - uv.y);
    }
    for n in &m.normals {
        let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
    }
    for t in &m.indices {
        let [a, b, c] = t.map(|i| i + 1);
        if m.normals.is_empty() {
            let _ = writeln!(s, "f {a}/{a} {b}/{b} {c}/{c}");
        } else {
            let _ = writeln!(s, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}");
        }
    }
    s
}
