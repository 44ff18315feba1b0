//! How a run was made: `metrics.json`'s `run` record and the report's header.
//!
//! Figures from a shared machine mean little without their conditions (a second run of one
//! config under load measured gathers 10x slower, and nothing said so), so every run records
//! the biscale build (version, git commit and whether the tree was dirty, rustc), the config's
//! text and hash, the seed, when and where it ran (host, CPU model, cores, rayon threads, the
//! load average at start and end) and the wall and CPU seconds of each stage
//! ([`StageClock`]).

use biscale_core::io::ContentHash;
use std::time::{Instant, SystemTime};

pub use biscale_report::metrics::{RunRecord, StageTime, SCHEMA_VERSION};

/// Times the stages of a run: [`StageClock::mark`] closes the stage that ran since the last
/// mark.
pub struct StageClock {
    record: RunRecord,
    start: Instant,
    cpu_start: Option<f64>,
    last: Instant,
    last_cpu: Option<f64>,
}

impl StageClock {
    /// Start timing a run of the config whose text is `config_text`.
    pub fn start(config_text: &str, seed: u64) -> Self {
        let now = Instant::now();
        let cpu = process_cpu_seconds();
        let record = RunRecord {
            biscale_version: env!("CARGO_PKG_VERSION").to_string(),
            git_commit: Some(env!("BISCALE_GIT_COMMIT").to_string()).filter(|s| !s.is_empty()),
            git_dirty: match env!("BISCALE_GIT_DIRTY") {
                "true" => Some(true),
                "false" => Some(false),
                _ => None,
            },
            rustc: env!("BISCALE_RUSTC").to_string(),
            command: std::env::args().collect(),
            config_text: config_text.to_string(),
            config_hash: format!("{:032x}", ContentHash::default().write(config_text.as_bytes()).finish128()),
            seed,
            started_at: rfc3339_utc(SystemTime::now()),
            host: std::fs::read_to_string("/proc/sys/kernel/hostname")
                .map(|h| h.trim().to_string())
                .unwrap_or_default(),
            cpu_model: cpu_model().unwrap_or_else(|| "unknown".into()),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            threads: rayon::current_num_threads(),
            load_average_start: load_average(),
            load_average_end: None,
            stages: vec![],
            wall_seconds: 0.0,
            cpu_seconds: None,
        };
        Self { record, start: now, cpu_start: cpu, last: now, last_cpu: cpu }
    }

    /// Close the stage `stage`: the time since the previous mark (or the start).
    pub fn mark(&mut self, stage: impl Into<String>) {
        release_freed_memory();
        let (now, cpu) = (Instant::now(), process_cpu_seconds());
        let stage = StageTime {
            stage: stage.into(),
            wall_seconds: (now - self.last).as_secs_f64(),
            cpu_seconds: cpu.zip(self.last_cpu).map(|(b, a)| round_ms(b - a)),
        };
        if log::log_enabled!(log::Level::Debug) {
            let cpu = stage.cpu_seconds.map_or(String::new(), |c| format!(", {c:.1} s CPU"));
            log::debug!("stage {}: {:.2} s wall{cpu}", stage.stage, stage.wall_seconds);
        }
        self.record.stages.push(stage);
        (self.last, self.last_cpu) = (now, cpu);
    }

    /// The record, with the totals and the load at the end.
    pub fn finish(&self) -> RunRecord {
        let mut r = self.record.clone();
        r.wall_seconds = self.start.elapsed().as_secs_f64();
        r.cpu_seconds = process_cpu_seconds().zip(self.cpu_start).map(|(b, a)| round_ms(b - a));
        r.load_average_end = load_average();
        r
    }
}

/// A difference of clock-tick counts without its binary-fraction noise (0.61000000000000001).
fn round_ms(seconds: f64) -> f64 {
    (seconds * 1e3).round() / 1e3
}

/// User plus system CPU seconds of this process, all threads (`/proc/self/stat`).
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces, inside parentheses): utime and
    // stime are the 12th and 13th.
    let rest = stat.get(stat.rfind(')')? + 2..)?;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // SAFETY: sysconf only reads a system constant.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    (hz > 0).then(|| ticks / hz as f64)
}

fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = text.split_whitespace().map(|x| x.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

fn cpu_model() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines()
        .find_map(|l| l.strip_prefix("model name").and_then(|r| r.split_once(':')).map(|(_, v)| v.trim().to_string()))
}

/// `t` as `YYYY-MM-DDTHH:MM:SSZ` (UTC), by the civil-from-days algorithm (H. Hinnant,
/// "chrono-Compatible Low-Level Date Algorithms").
pub fn rfc3339_utc(t: SystemTime) -> String {
    let secs = match t.duration_since(SystemTime::UNIX_EPOCH) {
        Ok(d) => d.as_secs() as i64,
        Err(e) => -(e.duration().as_secs() as i64),
    };
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// Hand the heap's freed pages back to the system at a stage boundary (glibc's
/// `malloc_trim`): a stage's temporaries, freed from several threads' arenas, otherwise stay
/// in the process's resident memory and add to the next stage's peak by an amount that
/// depends on thread timing, which the memory estimate cannot know.
fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free heap memory to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn dates_are_utc_rfc3339() {
        let at = |s: u64| rfc3339_utc(SystemTime::UNIX_EPOCH + Duration::from_secs(s));
        assert_eq!(at(0), "1970-01-01T00:00:00Z");
        // `date -u -d @1700000000`, `date -u -d @951782400` (a leap day), `@4102444799`.
        assert_eq!(at(1_700_000_000), "2023-11-14T22:13:20Z");
        assert_eq!(at(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(at(4_102_444_799), "2099-12-31T23:59:59Z");
        assert_eq!(rfc3339_utc(SystemTime::UNIX_EPOCH - Duration::from_secs(1)), "1969-12-31T23:59:59Z");
    }

    #[test]
    fn stages_partition_the_run() {
        let mut clock = StageClock::start("name = \"x\"\n", 3);
        let spin = |ms: u64| {
            let t = Instant::now();
            while t.elapsed() < Duration::from_millis(ms) {}
        };
        spin(30);
        clock.mark("a");
        std::thread::sleep(Duration::from_millis(30));
        clock.mark("b");
        let r = clock.finish();
        assert_eq!(r.stages.iter().map(|s| s.stage.as_str()).collect::<Vec<_>>(), ["a", "b"]);
        let sum: f64 = r.stages.iter().map(|s| s.wall_seconds).sum();
        assert!(r.stages.iter().all(|s| s.wall_seconds >= 0.03), "{:?}", r.stages);
        assert!(sum <= r.wall_seconds, "{sum} > {}", r.wall_seconds);
        // Spinning costs CPU, sleeping does not (CPU clock ticks are 10 ms).
        let (a, b) = (r.stages[0].cpu_seconds.unwrap(), r.stages[1].cpu_seconds.unwrap());
        assert!(a >= 0.01 && b <= a, "spin {a}, sleep {b}");
        assert_eq!(r.config_hash, format!("{:032x}", ContentHash::default().write(b"name = \"x\"\n").finish128()));
        assert_eq!((r.seed, r.threads), (3, rayon::current_num_threads()));
        assert!(r.load_average_start.is_some() && r.load_average_end.is_some());
        assert!(r.started_at.ends_with('Z') && r.started_at.len() == 20, "{}", r.started_at);
    }
}
