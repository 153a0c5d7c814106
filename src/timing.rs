//! Process and thread CPU time, for the timing fields of `summary.json` and
//! `edpm bench` (never part of a result: the output digests strip them).

/// Process CPU time (s).
pub fn cpu_time() -> f64 {
    clock_seconds(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// CPU time of the calling thread (s): for work that runs beside other
/// work of the same process (the overlapped gas step).
pub fn thread_cpu_time() -> f64 {
    clock_seconds(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// The time of clock `id` (s).
fn clock_seconds(id: libc::clockid_t) -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we pass and has no
    // other effect; both CPU-time clocks used here are supported on Linux.
    unsafe { libc::clock_gettime(id, &mut ts) };
    ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
}
