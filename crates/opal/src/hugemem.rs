//! Large zeroed buffers backed by transparent huge pages where the OS offers them.
//!
//! The light tracer adds every deposit into a random texel of maps of tens of megabytes: with
//! 4 KiB pages nearly every add (and its prefetch) misses the TLB, and the page walk stalls the
//! prefetch instruction itself. [`ZeroedBuf`] maps such a buffer anonymously, aligned to 2 MiB,
//! and asks Linux for huge pages on it (`madvise(MADV_HUGEPAGE)`, which also works where the
//! system setting is `madvise`, the common default) before any page is touched, so the whole
//! map is covered by a handful of TLB entries. Elsewhere, or if the mapping fails, it is a plain
//! zeroed `Vec`. The contents are the same either way (zeros, then whatever is written):
//! huge pages change the speed only.
//!
//! Tests: `tests` below (zeroed, writable, both back-ends, drop).

/// A zeroed buffer of `T` (see the module docs). `T` must be a type for which all-zero bytes
/// are a valid value: [`Zeroable`].
pub struct ZeroedBuf<T: Zeroable> {
    repr: Repr<T>,
}

/// Types whose all-zero bit pattern is a valid value (plain integers and floats).
///
/// # Safety
/// Implementors must be valid when all their bytes are zero and need no drop.
pub unsafe trait Zeroable: Copy {}
// SAFETY: plain integers and floats: all-zero bytes are the value 0.
unsafe impl Zeroable for i32 {}
// SAFETY: as above.
unsafe impl Zeroable for i64 {}
// SAFETY: as above.
unsafe impl Zeroable for f32 {}
// SAFETY: as above.
unsafe impl Zeroable for f64 {}

enum Repr<T> {
    Vec(Vec<T>),
    #[cfg(target_os = "linux")]
    Map {
        base: *mut libc::c_void,
        map_len: usize,
        data: *mut T,
        len: usize,
    },
}

// SAFETY: the mapping is owned exclusively by the buffer (like a `Vec<T>`), so it may move to
// and be shared between threads whenever `T` may.
unsafe impl<T: Zeroable + Send> Send for ZeroedBuf<T> {}
// SAFETY: as above; shared access only reads.
unsafe impl<T: Zeroable + Sync> Sync for ZeroedBuf<T> {}

/// Huge page size asked for.
#[cfg(target_os = "linux")]
const HUGE: usize = 2 << 20;
/// Buffers smaller than this are plain `Vec`s (huge pages only pay off for big maps).
const MIN_BYTES: usize = 1 << 20;

impl<T: Zeroable> ZeroedBuf<T> {
    /// `len` zeros.
    pub fn new(len: usize) -> Self {
        let bytes = len.saturating_mul(std::mem::size_of::<T>());
        #[cfg(target_os = "linux")]
        if bytes >= MIN_BYTES && std::mem::align_of::<T>() <= HUGE {
            if let Some(repr) = Self::map(len, bytes) {
                return ZeroedBuf { repr };
            }
        }
        let _ = bytes;
        // SAFETY: `T: Zeroable`, so all-zero bytes are valid values.
        let v = (0..len).map(|_| unsafe { std::mem::zeroed::<T>() }).collect();
        ZeroedBuf { repr: Repr::Vec(v) }
    }

    /// An anonymous mapping of `bytes` (rounded up) at a 2 MiB boundary, advised for huge pages.
    #[cfg(target_os = "linux")]
    fn map(len: usize, bytes: usize) -> Option<Repr<T>> {
        let map_len = bytes.div_ceil(HUGE).checked_add(1)?.checked_mul(HUGE)?;
        // SAFETY: a fresh private anonymous mapping; no existing memory is affected.
        let base = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                map_len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if base == libc::MAP_FAILED {
            return None;
        }
        let offset = (HUGE - base as usize % HUGE) % HUGE;
        // SAFETY: `offset < HUGE` and the mapping is `bytes + HUGE` or more long, so the data
        // range `offset .. offset + bytes` lies inside it.
        let data = unsafe { base.cast::<u8>().add(offset) };
        // SAFETY: advice on our own mapping; failure only means no huge pages.
        unsafe { libc::madvise(data.cast(), bytes.div_ceil(HUGE) * HUGE, libc::MADV_HUGEPAGE) };
        Some(Repr::Map { base, map_len, data: data.cast(), len })
    }

    /// Whether the buffer is an advised mapping (else a `Vec`).
    pub fn is_mapped(&self) -> bool {
        !matches!(self.repr, Repr::Vec(_))
    }
}

impl<T: Zeroable> std::ops::Deref for ZeroedBuf<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.repr {
            Repr::Vec(v) => v,
            // SAFETY: `data` is aligned for `T` (2 MiB boundary), points to `len` values that
            // are zero (fresh anonymous pages) or were written through `DerefMut`, and lives as
            // long as `self`.
            #[cfg(target_os = "linux")]
            Repr::Map { data, len, .. } => unsafe { std::slice::from_raw_parts(*data, *len) },
        }
    }
}

impl<T: Zeroable> std::ops::DerefMut for ZeroedBuf<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.repr {
            Repr::Vec(v) => v,
            // SAFETY: as in `deref`; `&mut self` makes the access exclusive.
            #[cfg(target_os = "linux")]
            Repr::Map { data, len, .. } => unsafe { std::slice::from_raw_parts_mut(*data, *len) },
        }
    }
}

impl<T: Zeroable> Drop for ZeroedBuf<T> {
    fn drop(&mut self) {
        #[cfg(target_os = "linux")]
        if let Repr::Map { base, map_len, .. } = self.repr {
            // SAFETY: unmaps exactly the mapping made in `map`, which nothing else refers to.
            unsafe { libc::munmap(base, map_len) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zeroed_writable_and_dropped_for_both_backends() {
        for len in [0usize, 10, 3 << 18, 3 << 20] {
            let mut b = ZeroedBuf::<i32>::new(len);
            assert_eq!(b.len(), len);
            assert!(b.iter().all(|&x| x == 0));
            for (i, x) in b.iter_mut().enumerate() {
                *x = i as i32;
            }
            assert!(b.iter().enumerate().all(|(i, &x)| x == i as i32));
            if cfg!(target_os = "linux") {
                assert_eq!(b.is_mapped(), len * 4 >= MIN_BYTES, "len {len}");
            }
        }
    }
}
