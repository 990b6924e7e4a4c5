//! The allocator's own figures (`ServerInfo::allocator`) and the periodic return of its free
//! memory to the system (`memory_trim_s`), for whichever allocator the binary was built with:
//! jemalloc (the default, cfg `jemalloc_allocator` from build.rs) or glibc malloc
//! (`--features glibc`, or without the `jemalloc` feature).

use super::BTreeMap;

#[cfg(jemalloc_allocator)]
pub use jemalloc::{allocator_figures, limit_allocator_arenas, trim_allocator};

#[cfg(all(not(jemalloc_allocator), target_os = "linux", target_env = "gnu"))]
pub use glibc::{allocator_figures, limit_allocator_arenas, trim_allocator};

#[cfg(not(any(jemalloc_allocator, all(target_os = "linux", target_env = "gnu"))))]
pub use unknown::{allocator_figures, limit_allocator_arenas, trim_allocator};

#[cfg(all(not(jemalloc_allocator), target_os = "linux", target_env = "gnu"))]
mod glibc {
    use super::*;

    /// `ServerInfo::allocator`: glibc malloc's own figures (`mallinfo2`, summed over its arenas):
    /// bytes in use by live allocations, free bytes it keeps in its arenas, and bytes in mmapped
    /// chunks. What RSS holds beyond `in_use` is the allocator's retention, not live data.
    pub fn allocator_figures() -> BTreeMap<String, u64> {
        // SAFETY: mallinfo2 only reads the allocator's statistics (it takes each arena's lock);
        // glibc >= 2.33 has it, and Debian 12 ships 2.36.
        let m = unsafe { libc::mallinfo2() };
        [
            ("in_use", m.uordblks + m.hblkhd),
            ("free_retained", m.fordblks),
            ("mmapped", m.hblkhd),
            ("arena", m.arena),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v as u64))
        .collect()
    }

    /// Returns the allocator's free memory to the system: glibc's arenas (one per thread that
    /// allocated, up to 8 per core) otherwise keep the pages that the envs, batches and zenoh
    /// sessions of departed trainers freed. Only whole free pages go back; a page with one live
    /// allocation in it stays (fragmentation; docs/BENCHMARKS.md section 6, the soak).
    pub fn trim_allocator() {
        // SAFETY: malloc_trim only releases free pages of the allocator's own arenas (under their
        // locks); it never touches live allocations.
        unsafe {
            libc::malloc_trim(0);
        }
    }

    /// Caps glibc malloc's arenas at `arenas` (`M_ARENA_MAX`; 0 leaves glibc's limit). Call it
    /// before the runtime's threads start: a thread keeps the arena it first allocated in.
    pub fn limit_allocator_arenas(arenas: u32) {
        if arenas > 0 {
            // SAFETY: mallopt only sets one of the allocator's tunables; M_ARENA_MAX bounds the
            // arenas created from now on and is safe to set at any time.
            unsafe {
                libc::mallopt(libc::M_ARENA_MAX, arenas.min(i32::MAX as u32) as i32);
            }
        }
    }
}

/// jemalloc's figures: `in_use` is what live allocations hold (`stats.allocated`),
/// `free_retained` what jemalloc keeps resident beyond that (`stats.resident` minus
/// `stats.allocated`: dirty pages not yet decayed, partly used pages, its metadata).
#[cfg(jemalloc_allocator)]
mod jemalloc {
    use super::*;
    use tikv_jemalloc_ctl::{epoch, stats};

    pub fn allocator_figures() -> BTreeMap<String, u64> {
        // jemalloc caches its statistics; advancing the epoch refreshes them.
        if epoch::advance().is_err() {
            return BTreeMap::new();
        }
        let read = |r: tikv_jemalloc_ctl::Result<usize>| r.unwrap_or(0) as u64;
        let allocated = read(stats::allocated::read());
        let resident = read(stats::resident::read());
        [
            ("in_use", allocated),
            ("free_retained", resident.saturating_sub(allocated)),
            ("resident", resident),
            ("active", read(stats::active::read())),
            ("metadata", read(stats::metadata::read())),
            ("mapped", read(stats::mapped::read())),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    /// jemalloc returns unused dirty pages by itself (its decay, 10 s by default).
    pub fn trim_allocator() {}

    /// jemalloc's arenas are not glibc's: `malloc_arenas` does not apply.
    pub fn limit_allocator_arenas(_arenas: u32) {}
}

/// An allocator this build cannot ask: no figures, nothing to trim or cap.
#[cfg(not(any(jemalloc_allocator, all(target_os = "linux", target_env = "gnu"))))]
mod unknown {
    use super::*;

    pub fn allocator_figures() -> BTreeMap<String, u64> {
        BTreeMap::new()
    }

    pub fn trim_allocator() {}

    pub fn limit_allocator_arenas(_arenas: u32) {}
}
