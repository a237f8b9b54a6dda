//! What the machine can hold: settings that size a stage's tables are checked
//! against the available memory before anything is allocated, so a typo (a grid
//! of 100 000 points per axis) is a settings error naming the setting instead of
//! an abort in the allocator. Estimates are rough (bytes per row of what the stage
//! keeps), which is enough to tell a mistake from a big job.

/// Used when `/proc/meminfo` cannot be read (not Linux, a restricted sandbox):
/// 4 GiB, what a small workstation can spare; a big job on such a machine is
/// refused rather than risking an abort.
const FALLBACK_AVAILABLE_BYTES: u64 = 4 << 30;

/// Share of the available memory one stage may plan for: the rest is for polars'
/// copies while writing, other stages' tables and the rest of the machine.
const USABLE_SHARE: f64 = 0.75;

/// Memory the machine can give without swapping: `MemAvailable` of
/// `/proc/meminfo`, or [`FALLBACK_AVAILABLE_BYTES`]. Reads one small file.
fn available_bytes() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| mem_available(&text))
        .unwrap_or(FALLBACK_AVAILABLE_BYTES)
}

/// `MemAvailable:  12345 kB` → bytes.
fn mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemAvailable:"))?;
    let kib: u64 = line.trim().strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Why `estimate_bytes` (what `what` needs) does not fit in the memory one stage
/// may use, or `None` when it fits.
pub fn over_budget(estimate_bytes: f64, what: &str) -> Option<String> {
    let limit = available_bytes() as f64 * USABLE_SHARE;
    (estimate_bytes > limit).then(|| {
        format!(
            "{what} need about {} of memory; this machine can give a stage about {} \
             (3/4 of the available memory)",
            human(estimate_bytes),
            human(limit)
        )
    })
}

/// Bytes in binary units, e.g. `2.4 GiB`; astronomically large values in powers of ten.
fn human(bytes: f64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes;
    for unit in UNITS {
        if value < 1024.0 {
            return format!("{value:.1} {unit}");
        }
        value /= 1024.0;
    }
    format!("{bytes:.1e} B")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_mem_available_in_kib() {
        let text = "MemTotal:       16000000 kB\nMemFree:  100 kB\nMemAvailable:    8000000 kB\n";
        assert_eq!(mem_available(text), Some(8_000_000 * 1024));
        assert_eq!(mem_available("MemTotal: 1 kB\n"), None);
    }

    #[test]
    fn absurd_estimates_are_over_budget_and_small_ones_fit() {
        assert!(over_budget(2.4e16, "points").is_some());
        assert!(over_budget(1e3, "points").is_none());
        assert_eq!(human(1536.0), "1.5 KiB");
        assert_eq!(human(2.4e16), "2.4e16 B");
    }
}
