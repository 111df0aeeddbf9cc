//! Progress of the de-lighting's long stages for a caller's progress bars
//! ([`DelightSettings::progress`](super::DelightSettings::progress)): a callback receives
//! `(stage, done, total)` — the stage's name, the work done so far and the stage's total in
//! the stage's own unit (objects, texels, light-path batches). Per stage the first call has
//! `done = 0` and the last `done = total`; `done` never decreases within a stage (reports
//! from parallel workers are serialised). The library draws nothing itself.
//!
//! Stages, in order: `read views` (views; reported by the readers
//! [`read_views_limited`](super::views::read_views_limited) and
//! [`colmap_views`](super::colmap::colmap_views), before [`delight`](super::delight)), `unwrap`
//! (objects), `direct` (texels of the first estimate: the pilot, or the only pass) and `direct
//! penumbrae` (texels re-estimated at the full count; both this process's share, stepped as
//! texels finish inside the split), `luminance` (objects), `gather` (one step), `light tracing
//! N` (path batches of pass N; under several processes this process's share), `superres`
//! (objects, after the first pass), `post N` (objects, pass N's error maps and albedo update).
//! Tests: `progress_is_monotone_per_stage` in `tests/delight.rs`, the reading's in
//! `limited_read_box_filters_each_photo_as_it_is_read` (COLMAP) and the CLI's
//! `max_view_pixels_works_from_downsampled_views`.

use std::sync::{Arc, Mutex};

/// The callback type: `(stage, done, total)`.
pub type ProgressFn = dyn Fn(&str, u64, u64) + Send + Sync;

/// A progress callback (see the module documentation).
#[derive(Clone)]
pub struct Progress(pub Arc<ProgressFn>);

impl Progress {
    /// Wraps a callback `(stage, done, total)`.
    pub fn new(f: impl Fn(&str, u64, u64) + Send + Sync + 'static) -> Progress {
        Progress(Arc::new(f))
    }
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Progress(callback)")
    }
}

/// One stage's progress: reports 0 when made, `step`s add to it (clamped at the total), and
/// [`Stage::finish`] (or dropping it) reports the total.
pub(crate) struct Stage<'a> {
    f: Option<&'a ProgressFn>,
    name: String,
    total: u64,
    done: Mutex<u64>,
}

impl<'a> Stage<'a> {
    /// Starts stage `name` of `total` units (a total of 0 counts as 1).
    pub(crate) fn start(p: Option<&'a Progress>, name: impl Into<String>, total: u64) -> Stage<'a> {
        let st = Stage { f: p.map(|p| &*p.0), name: name.into(), total: total.max(1), done: Mutex::new(0) };
        if let Some(f) = st.f {
            f(&st.name, 0, st.total);
        }
        st
    }

    /// `k` more units done.
    pub(crate) fn step(&self, k: u64) {
        let Some(f) = self.f else { return };
        let mut d = self.done.lock().unwrap_or_else(|e| e.into_inner());
        let next = (*d + k).min(self.total);
        if next != *d {
            *d = next;
            f(&self.name, next, self.total);
        }
    }

    /// The stage is done (reports the total if not reached yet).
    pub(crate) fn finish(self) {}
}

impl Drop for Stage<'_> {
    fn drop(&mut self) {
        let rest = self.total - *self.done.get_mut().unwrap_or_else(|e| e.into_inner());
        if rest > 0 {
            self.step(rest);
        }
    }
}
