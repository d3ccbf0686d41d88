//! The process's allocator: the system's, asking the kernel for transparent huge pages
//! (2 MiB) on every allocation of 4 MiB and more. The DNS's fields, the sampler's tables
//! and the fibre groups' arrays are tens of MB read in strides over planes; with 4 KiB
//! pages nearly every stride is a TLB miss. Where the host's THP mode is `madvise` (the
//! common default) nothing is huge unless asked for. Results do not change: only where
//! the memory sits does. `FIBERFLOW_HUGE_PAGES=0` (or `off`, `false`) turns it off.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};

/// Allocations from this size on are advised.
const MIN_BYTES: usize = 4 << 20;
const HUGE_PAGE_BYTES: usize = 2 << 20;

static ENABLED: AtomicBool = AtomicBool::new(true);

/// The environment variable that turns the advice on or off.
pub const ENV: &str = "FIBERFLOW_HUGE_PAGES";

/// A setting of [`ENV`]: `1`, `on`, `true` or `0`, `off`, `false` (any case).
pub fn parse_setting(v: &str) -> Result<bool, String> {
    match v.trim().to_ascii_lowercase().as_str() {
        "1" | "on" | "true" => Ok(true),
        "0" | "off" | "false" => Ok(false),
        _ => Err(format!(
            "{ENV}={v:?} is not a setting (1, on, true or 0, off, false); huge pages stay on"
        )),
    }
}

/// Reads [`ENV`] (unset: on); call first thing in `main`, before large allocations.
/// Returns what to warn about once logging is set up.
pub fn configure_from_env() -> Option<String> {
    let v = std::env::var(ENV).ok()?;
    match parse_setting(&v) {
        Ok(on) => {
            ENABLED.store(on, Ordering::Relaxed);
            None
        }
        Err(why) => Some(why),
    }
}

/// The system allocator with `MADV_HUGEPAGE` on large blocks.
pub struct HugePageAlloc;

/// Advises the whole 2 MiB pages inside `[p, p + len)`.
fn advise(p: *mut u8, len: usize) {
    if p.is_null() || len < MIN_BYTES || !ENABLED.load(Ordering::Relaxed) {
        return;
    }
    let start = (p as usize).next_multiple_of(HUGE_PAGE_BYTES);
    let end = (p as usize + len) & !(HUGE_PAGE_BYTES - 1);
    if end > start {
        // SAFETY: the range lies inside a block this process just obtained; MADV_HUGEPAGE
        // changes how it is backed, never its contents, and a refusal is harmless.
        unsafe {
            libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
        }
    }
}

// SAFETY: every call forwards to `System` with the caller's arguments; `advise` only adds
// a hint on memory `System` returned.
unsafe impl GlobalAlloc for HugePageAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as given.
        let p = unsafe { System.alloc(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as given.
        let p = unsafe { System.alloc_zeroed(layout) };
        advise(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as given.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded as given.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        advise(p, new_size);
        p
    }
}

#[cfg(test)]
mod tests {
    /// The kernel's flags (`VmFlags` of /proc/self/smaps) of the mapping holding `addr`.
    fn vm_flags_at(addr: usize) -> Vec<String> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").expect("smaps");
        let mut inside = false;
        for line in smaps.lines() {
            let first = line.split_whitespace().next().unwrap_or("");
            if let Some((lo, hi)) = first.split_once('-') {
                if let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
                {
                    inside = (lo..hi).contains(&addr);
                    continue;
                }
            }
            if inside {
                if let Some(flags) = line.strip_prefix("VmFlags:") {
                    return flags.split_whitespace().map(str::to_string).collect();
                }
            }
        }
        panic!("no mapping holds {addr:#x}");
    }

    /// The variable's settings, and a clear refusal of anything else.
    #[test]
    fn settings_parse_and_nonsense_is_named() {
        for on in ["1", "on", "TRUE", " true "] {
            assert_eq!(super::parse_setting(on), Ok(true), "{on}");
        }
        for off in ["0", "off", "False"] {
            assert_eq!(super::parse_setting(off), Ok(false), "{off}");
        }
        let e = super::parse_setting("maybe").unwrap_err();
        assert!(
            e.contains("FIBERFLOW_HUGE_PAGES") && e.contains("\"maybe\""),
            "{e}"
        );
    }

    /// A 16 MB vector (through the global allocator) lies in memory advised for huge pages
    /// (`hg` in its mapping's flags, which only `madvise` sets).
    #[test]
    fn large_blocks_are_advised_for_huge_pages() {
        if !std::path::Path::new("/sys/kernel/mm/transparent_hugepage").exists() {
            // a kernel built without THP refuses the advice (the allocator goes on)
            eprintln!("no transparent huge pages in this kernel: nothing to check");
            return;
        }
        let big = vec![1.0f64; 2 << 20];
        let middle = big.as_ptr() as usize + big.len() * 4;
        assert!(
            vm_flags_at(middle).iter().any(|f| f == "hg"),
            "{:?}",
            vm_flags_at(middle)
        );
    }
}
