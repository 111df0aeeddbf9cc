//! Memory hints for the large tables that a render reads at random (no effect on results).
//!
//! [`huge_vec`] allocates a vector whose whole 2 MiB pages the kernel is asked to back with
//! transparent huge pages (Linux `madvise(MADV_HUGEPAGE)`, which takes effect where the
//! system's THP mode is `madvise` or `always`), before anything is written into it. The path
//! tracer reads its per-triangle rows (128 bytes per triangle: 10.5 MB on an 82 k-triangle scan)
//! at the hit triangles, all over the table: with 4 KiB pages nearly every such read also
//! misses the TLB and walks the page tables, and every page is one page fault when the table
//! is filled; one 2 MiB page covers 512 of them. The same holds for a linear-valued bitmap texture
//! (an EXR: 12 bytes per texel), which the bounces read all over. Elsewhere (other systems, small vectors, a
//! refused hint) the vector is an ordinary one.
//!
//! Tests: `huge_vec_is_an_ordinary_vector` below (capacity, contents, small and empty vectors).

/// Smallest allocation that is advised (one huge page; whether a whole 2 MiB page lies inside
/// depends on where the allocation starts).
const MIN_BYTES: usize = 2 << 20;

/// An empty vector with room for `capacity` elements, its whole 2 MiB pages advised for
/// transparent huge pages when it takes at least 2 MiB (see the module docs).
pub fn huge_vec<T>(capacity: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(capacity);
    let bytes = v.capacity().saturating_mul(std::mem::size_of::<T>());
    if bytes >= MIN_BYTES {
        advise_huge(v.as_ptr() as usize, bytes);
    }
    v
}

/// `madvise(MADV_HUGEPAGE)` on the whole 2 MiB pages of `[start, start + len)`; failures are
/// ignored (the memory stays in 4 KiB pages).
#[cfg(target_os = "linux")]
pub(crate) fn advise_huge(start: usize, len: usize) {
    const HUGE: usize = 2 << 20;
    let first = start.next_multiple_of(HUGE);
    let end = (start + len) / HUGE * HUGE;
    if end > first {
        // SAFETY: the range lies inside the vector's own allocation (whole pages, so aligned as
        // madvise requires); MADV_HUGEPAGE changes no contents and no access rights.
        unsafe {
            libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
pub(crate) fn advise_huge(_start: usize, _len: usize) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_vec_is_an_ordinary_vector() {
        for n in [0usize, 1, 1000, 3 << 20] {
            let mut v: Vec<u32> = huge_vec(n);
            assert!(v.is_empty());
            assert!(v.capacity() >= n);
            v.extend((0..n as u32).map(|i| i.wrapping_mul(2_654_435_761)));
            assert_eq!(v.len(), n);
            assert!(v.iter().enumerate().all(|(i, &x)| x == (i as u32).wrapping_mul(2_654_435_761)));
        }
        let z: Vec<()> = huge_vec(10);
        assert!(z.is_empty());
    }
}
