//! Giving freed memory back to the operating system.
//!
//! The C allocator keeps what a process frees for its own reuse, in every thread's arena:
//! after a burst of large allocations (checking large scenes on the blocking threads) the
//! process stays that large for good. [`settle`] fixes the allocator's thresholds at
//! start and [`give_back`] returns the free pages after such a burst. Not an allocator of
//! its own, and a no-op where the C library offers no such calls.

/// Allocations from this size on are mapped on their own, and unmapped when freed.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MAP_FROM: libc::c_int = 256 << 10;

/// Fixes the allocator's mapping threshold at [`MAP_FROM`]; called once, before the
/// runtime's threads start.
///
/// glibc raises its threshold to the size of each mapped block freed (scene bodies of a
/// few megabytes), and its trimming threshold to twice that; from then on a burst of
/// checks leaves the top of every thread's arena free but resident, a few megabytes
/// each, which [`give_back`] cannot return (`malloc_trim` trims only the main arena's
/// top). A fixed threshold turns the adjustment off: large blocks go back to the system
/// when freed, and arena tops are trimmed from 128 KiB.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn settle() {
    // SAFETY: `mallopt` sets an allocator parameter under the allocator's own lock. A
    // refused value (it returns 0) leaves glibc's own adjusting threshold in place, as
    // without this call: the service runs as before, only holding more memory after a
    // burst of checks.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAP_FROM);
    }
}

/// Fixes the allocator's thresholds: nothing to do with this C library.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn settle() {}

/// Returns the allocator's free memory to the operating system, as far as it can.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn give_back() {
    // SAFETY: `malloc_trim` takes a byte count to keep at the top of the heap and touches
    // only the allocator's own free lists, under its own locks; any thread may call it.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Returns the allocator's free memory to the operating system: nothing to do with this C
/// library.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn give_back() {}
