//! Zeroed `i32` storage for a worker's deposit maps ([`Zeroed`]): on Linux the maps of a
//! worker ([`Zeroed::many`]) share one anonymous mapping, aligned to 2 MiB and advised for
//! transparent huge pages (`madvise(MADV_HUGEPAGE)`), when together they fill at least one
//! huge page; elsewhere (and for small map sets) each map is a plain `Vec`.
//!
//! Why: the deposits hit a worker's maps (≈ 9 MB on the bundled Cornell box) at random texels,
//! so with 4 KiB pages nearly every deposit also misses the TLB, and a page walk in a virtual
//! machine is a two-dimensional one. With 2 MiB pages the maps need a handful of TLB entries.
//! One mapping for all the maps of a worker, not one per map: maps of a few hundred kB each
//! (the Cornell box's seven) would each round up to a huge page of their own.
//! The contents are the same either way (zeroed pages, plain loads and stores): the sums do
//! not depend on the backing. When the kernel gives no huge pages (THP `never`, no memory to
//! compact) the mapping simply has 4 KiB pages.
//!
//! Tests (`tests.rs`): `zeroed_maps_are_zero_disjoint_and_writable` (both backings); every
//! test of the engine's sums goes through it.

use std::ops::{Deref, DerefMut};

/// Bytes of a huge page (x86-64, AArch64 with 4 KiB base pages): the alignment of the shared
/// mapping and the smallest map set given one.
#[cfg(target_os = "linux")]
const HUGE: usize = 2 << 20;

/// Start of each map inside the shared mapping: a multiple of 16 `i32`s (a cache line).
#[cfg(target_os = "linux")]
const ALIGN: usize = 16;

/// `len` zeroed `i32`s at `ptr`: a `Vec`'s buffer, or a part of a mapping shared with the
/// other maps of a worker (see the module docs). The parts of one mapping are disjoint.
pub(super) struct Zeroed {
    ptr: *mut i32,
    len: usize,
    /// Keeps the buffer alive (never touched otherwise: `ptr` points into it).
    _owner: Owner,
}

enum Owner {
    Vec(#[allow(dead_code)] Vec<i32>),
    #[cfg(target_os = "linux")]
    Mapping(#[allow(dead_code)] std::sync::Arc<Mapping>),
}

/// An anonymous mapping of `bytes` at `base`, unmapped when its last part is dropped.
#[cfg(target_os = "linux")]
struct Mapping {
    base: *mut libc::c_void,
    bytes: usize,
}

// SAFETY: a `Mapping` is only unmapped (in `drop`); its memory is accessed through the
// `Zeroed` parts, each of which owns its disjoint range exclusively.
#[cfg(target_os = "linux")]
unsafe impl Send for Mapping {}
// SAFETY: as above.
#[cfg(target_os = "linux")]
unsafe impl Sync for Mapping {}
// SAFETY: a `Zeroed` owns its range exclusively (as a `Vec` owns its buffer): `&mut` access
// through `&mut Zeroed` only, shared access reads through `&[i32]`.
unsafe impl Send for Zeroed {}
// SAFETY: as above.
unsafe impl Sync for Zeroed {}

impl Zeroed {
    /// `len` zeros in a `Vec`.
    pub(super) fn new(len: usize) -> Zeroed {
        let mut v = vec![0; len];
        Zeroed { ptr: v.as_mut_ptr(), len, _owner: Owner::Vec(v) }
    }

    /// Maps of `lens[k]` zeros: parts of one huge-page advised mapping where `huge`, on Linux,
    /// when they fill at least one huge page and the mapping succeeds; `Vec`s otherwise.
    pub(super) fn many(lens: &[usize], huge: bool) -> Vec<Zeroed> {
        #[cfg(target_os = "linux")]
        if huge && let Some(parts) = mapped_parts(lens) {
            return parts;
        }
        let _ = huge;
        lens.iter().map(|&n| Zeroed::new(n)).collect()
    }

    /// Whether the values are part of a shared (huge-page advised) mapping.
    #[cfg(test)]
    pub(super) fn is_mapped(&self) -> bool {
        !matches!(self._owner, Owner::Vec(_))
    }
}

/// One mapping for all `lens` (`None`: less than a huge page in all, or no mapping).
#[cfg(target_os = "linux")]
fn mapped_parts(lens: &[usize]) -> Option<Vec<Zeroed>> {
    let mut offsets = Vec::with_capacity(lens.len());
    let mut end = 0usize;
    for &n in lens {
        offsets.push(end);
        end = end.checked_add(n)?.checked_next_multiple_of(ALIGN)?;
    }
    let need = end.checked_mul(4)?;
    if need < HUGE {
        return None;
    }
    let need = need.checked_next_multiple_of(HUGE)?;
    let bytes = need.checked_add(HUGE)?;
    // SAFETY: a fresh private anonymous mapping (no file, no fixed address); checked below.
    let base = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            bytes,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
            -1,
            0,
        )
    };
    if base == libc::MAP_FAILED {
        return None;
    }
    let map = std::sync::Arc::new(Mapping { base, bytes });
    let skip = (base as usize).next_multiple_of(HUGE) - base as usize;
    // SAFETY: `skip < HUGE` and `skip + need <= bytes`: inside the mapping.
    let start = unsafe { base.cast::<u8>().add(skip) };
    // Advice only: without it (or without huge pages) the mapping has 4 KiB pages.
    crate::mem::advise_huge(start as usize, need);
    let start = start.cast::<i32>();
    let parts = lens
        .iter()
        .zip(offsets)
        .map(|(&len, off)| Zeroed {
            // SAFETY: `off + len <= end` i32s and `4·end <= need`: inside the mapping.
            ptr: unsafe { start.add(off) },
            len,
            _owner: Owner::Mapping(map.clone()),
        })
        .collect();
    Some(parts)
}

#[cfg(target_os = "linux")]
impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: the mapping made in `mapped_parts`, unmapped once (no part is left).
        unsafe { libc::munmap(self.base, self.bytes) };
    }
}

impl Deref for Zeroed {
    type Target = [i32];
    #[inline(always)]
    fn deref(&self) -> &[i32] {
        // SAFETY: `len` initialised (zeroed) i32s at `ptr`, aligned, alive while `_owner` is,
        // disjoint from every other `Zeroed`; borrowed with `self`.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
}

impl DerefMut for Zeroed {
    #[inline(always)]
    fn deref_mut(&mut self) -> &mut [i32] {
        // SAFETY: as in `deref`; no other `Zeroed` overlaps, so the borrow is exclusive.
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.len) }
    }
}
