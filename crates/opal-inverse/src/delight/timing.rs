//! Stage timing of the de-lighting: wall and CPU clocks per stage (`DelightResult::timings`,
//! `DelightResult::cpu_timings`) and the process's memory at each stage's end
//! (`DelightResult::memory_mb`). CPU time comes from `/proc/self/stat`, memory from
//! `/proc/self/status` (NaN elsewhere).
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

/// Resident memory of this process in MB: (now, peak so far), from `VmRSS` and `VmHWM` of
/// `/proc/self/status`; NaN where that file is not available. The peak is the process's whole
/// history (it is never reset here), so a stage raised it when it is larger at its end than at
/// the end of the stage before.
pub fn rss_mb() -> (f64, f64) {
    let text = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|r| r.split_whitespace().next()?.parse::<f64>().ok())
            .map_or(f64::NAN, |kb| kb / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
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
    /// Resident and peak memory (MB) at each stage's end ([`rss_mb`]).
    pub(super) memory: Vec<(String, [f64; 2])>,
}

impl Timings {
    pub(super) fn push(&mut self, name: &str, (wall, cpu): (f64, f64)) {
        self.wall.push((name.into(), wall));
        self.cpu.push((name.into(), cpu));
        let (now, peak) = rss_mb();
        self.memory.push((name.into(), [now, peak]));
    }
}
