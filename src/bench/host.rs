//! What the host says about this process, for the benchmarks: CPU time of the thread and
//! of the process, resident memory, and the load average (Linux `/proc`; `None`
//! elsewhere).

/// CPU time this thread has run so far, s, from `/proc/thread-self/schedstat` (Linux,
/// nanoseconds); `None` elsewhere.
pub fn thread_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = stat.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

/// CPU time (user + system, all threads) of this process so far, s, from
/// `/proc/self/stat` (Linux; clock ticks taken as 1/100 s); `None` elsewhere.
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may contain spaces) start after the last ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// Resident set size of this process, KiB (`VmRSS` of /proc/self/status, Linux); `None`
/// elsewhere.
pub fn resident_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The 1-minute load average from /proc/loadavg (Linux); `None` elsewhere.
pub fn load_average() -> Option<String> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next().map(str::to_owned)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn thread_cpu_time_grows_with_work() {
        let Some(a) = thread_cpu_seconds() else {
            eprintln!("skipped: no /proc/thread-self/schedstat");
            return;
        };
        let mut x = 0u64;
        let t = Instant::now();
        while t.elapsed().as_millis() < 50 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let b = thread_cpu_seconds().unwrap_or(a);
        assert!(b > a, "thread CPU time did not grow: {a} -> {b}");
        assert!(b - a < 10.0, "implausible thread CPU time: {a} -> {b}");
    }
}
