//! A check of an OpenEXR file's chunk table before the `exr` crate reads the pixels.
//!
//! The `exr` crate sizes the buffer of each chunk from the byte count stored in the chunk's
//! own header and fills it before reading: a small corrupt file (fuzz target `image_exr` found
//! a 40 KB file whose data window is 3.2 M × 64 pixels) can make it allocate and clear hundreds
//! of megabytes per chunk. Every chunk of a valid file lies inside the file, so each chunk the
//! offset tables point at must declare a byte count that fits between its header and the end
//! of the file; a file where one does not is refused before any pixel buffer exists.
//!
//! Layout (OpenEXR file layout, "Chunk layout"): magic and version (8 bytes), the headers
//! (attributes `name\0type\0size:i32 value`, each header ended by a null byte, multi-part files
//! ended by one more), then per header an offset table of `chunk_count` u64 file offsets. A
//! chunk starts with the part number (i32, multi-part files only), then `y` (scan lines) or
//! four tile coordinates (tiles), then the data's byte count (i32). Deep data is not checked
//! here (Opal refuses it when reading).
//!
//! Tests: `tests/scene_load.rs::exr_whose_chunks_overrun_the_file_is_refused` (the fuzz find)
//! and every EXR the test suite reads (valid files pass).

use crate::error::{Error, Result};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// Per header: whether its blocks are tiles, and how many chunks it has.
pub(super) struct PartLayout {
    /// Tiled blocks (four coordinates before the byte count) rather than scan lines (one).
    pub tiled: bool,
    /// Entries of its offset table.
    pub chunks: usize,
}

fn err(path: &Path, msg: String) -> Error {
    Error::Parse { path: path.to_path_buf(), line: 0, col: 0, msg: format!("cannot decode image: {msg}") }
}

fn read_i32(f: &mut impl Read) -> std::io::Result<i32> {
    let mut b = [0u8; 4];
    f.read_exact(&mut b)?;
    Ok(i32::from_le_bytes(b))
}

/// Skips one null-terminated string; returns whether it was empty (a lone null byte).
fn skip_cstr(f: &mut impl Read) -> std::io::Result<bool> {
    let mut b = [0u8; 1];
    let mut n = 0usize;
    loop {
        f.read_exact(&mut b)?;
        if b[0] == 0 {
            return Ok(n == 0);
        }
        n += 1;
        if n > 1024 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "attribute name over 1024 bytes",
            ));
        }
    }
}

/// Refuses the file at `path` when a chunk its offset tables point at declares more bytes than
/// the file holds after that chunk's header. `parts` are the file's headers as the `exr` crate
/// read them (same order), `multipart` whether the file is multi-part. Offsets outside the file
/// are left to the `exr` crate (it reports them or rebuilds the table).
pub(super) fn check(path: &Path, parts: &[PartLayout], multipart: bool) -> Result<()> {
    let io = |e: std::io::Error| err(path, format!("chunk table: {e}"));
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut f = std::io::BufReader::new(file);
    f.seek(SeekFrom::Start(8)).map_err(io)?;
    // the headers: attributes until an empty name; multi-part files end with one more null
    for _ in 0..parts.len() {
        while !skip_cstr(&mut f).map_err(io)? {
            skip_cstr(&mut f).map_err(io)?; // type name
            let size = read_i32(&mut f).map_err(io)?;
            if size < 0 {
                return Err(err(path, format!("attribute of negative size {size}")));
            }
            f.seek(SeekFrom::Current(size as i64)).map_err(io)?;
        }
    }
    if multipart {
        skip_cstr(&mut f).map_err(io)?;
    }
    let mut tables = Vec::with_capacity(parts.len());
    for p in parts {
        let mut offsets = Vec::with_capacity(p.chunks.min(1 << 20));
        for _ in 0..p.chunks {
            let mut b = [0u8; 8];
            f.read_exact(&mut b).map_err(io)?;
            offsets.push(u64::from_le_bytes(b));
        }
        tables.push(offsets);
    }
    for (p, offsets) in parts.iter().zip(&tables) {
        let head = 4 * (multipart as u64) + if p.tiled { 16 } else { 4 } + 4;
        for &off in offsets {
            if off.checked_add(head).is_none_or(|end| end > len) {
                continue;
            }
            f.seek(SeekFrom::Start(off + head - 4)).map_err(io)?;
            let size = read_i32(&mut f).map_err(io)?;
            if size < 0 || off + head + size as u64 > len {
                return Err(err(
                    path,
                    format!(
                        "the chunk at byte {off} declares {size} bytes of pixel data, but the file ends {} bytes after its header",
                        len - off - head
                    ),
                ));
            }
        }
    }
    Ok(())
}
