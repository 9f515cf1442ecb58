//! CPU time of this process and of its finished children, for benchmarks: unlike the wall
//! time, it does not grow when other programs load the machine.

/// CPU time of this process so far (every thread), ms: unlike the wall time, it does not grow
/// when other programs load the machine.
pub fn process_cpu_ms() -> f64 {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `t` is a valid timespec for the call to fill; the clock id is a constant.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) } == 0;
    if ok {
        t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
    } else {
        f64::NAN
    }
}

/// CPU time of the finished child processes so far (every thread), ms.
pub fn children_cpu_ms() -> f64 {
    // SAFETY: an all-zero rusage is a valid value for the call to fill.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `usage` is a valid rusage for the call to fill; the target is a constant.
    let ok = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) } == 0;
    let ms = |t: libc::timeval| t.tv_sec as f64 * 1e3 + t.tv_usec as f64 * 1e-3;
    if ok {
        ms(usage.ru_utime) + ms(usage.ru_stime)
    } else {
        f64::NAN
    }
}
