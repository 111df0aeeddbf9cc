//! Stage timing of the de-lighting: wall and CPU clocks per stage (`DelightResult::timings`,
//! `DelightResult::cpu_timings`). CPU time comes from `/proc/self/stat` (NaN elsewhere).
//! No dedicated test; exercised by every de-lighting run (`tests/delight.rs`).

/// CPU time (user + system, all threads) of this process in seconds, from `/proc/self/stat`
/// (clock ticks of 1/100 s); NaN where that file is not available. On a shared machine the CPU
/// time of a stage is far steadier than its wall time.
pub fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            // fields after the command name (in parentheses): utime is field 14, stime 15
            let rest: Vec<&str> = s.rsplit_once(')')?.1.split_whitespace().collect();
            let ut: f64 = rest.get(11)?.parse().ok()?;
            let st: f64 = rest.get(12)?.parse().ok()?;
            Some((ut + st) / 100.0)
        })
        .unwrap_or(f64::NAN)
}

/// Wall and CPU clock of a stage ([`cpu_seconds`]).
#[derive(Clone, Copy, Debug)]
pub struct StageClock {
    wall: std::time::Instant,
    cpu: f64,
}

impl StageClock {
    /// Starts the clock.
    pub fn start() -> Self {
        StageClock { wall: std::time::Instant::now(), cpu: cpu_seconds() }
    }
    /// (wall seconds, CPU seconds) since [`StageClock::start`].
    pub fn elapsed(&self) -> (f64, f64) {
        (self.wall.elapsed().as_secs_f64(), cpu_seconds() - self.cpu)
    }
}

/// Stage timings being recorded: wall and CPU seconds per named stage.
#[derive(Default)]
pub(super) struct Timings {
    pub(super) wall: Vec<(String, f64)>,
    pub(super) cpu: Vec<(String, f64)>,
}

impl Timings {
    pub(super) fn push(&mut self, name: &str, (wall, cpu): (f64, f64)) {
        self.wall.push((name.into(), wall));
        self.cpu.push((name.into(), cpu));
    }
}
