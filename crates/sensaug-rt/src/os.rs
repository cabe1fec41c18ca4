//! Operating-system services of the real-time thread: the monotonic clock,
//! absolute-deadline sleep, SCHED_FIFO, CPU pinning and memory locking.
//! Each set-up call returns an error the caller reports as a warning and
//! continues (a VM or an unprivileged user gets a best-effort loop).

use std::io;
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

/// Nanoseconds on CLOCK_MONOTONIC.
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until the absolute CLOCK_MONOTONIC time `deadline_ns`
/// (`clock_nanosleep` with TIMER_ABSTIME), resuming after signals.
pub fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != libc::EINTR {
            return;
        }
    }
}

/// SCHED_FIFO at `priority` for the calling thread.
pub fn set_fifo(priority: i32) -> io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pid 0 is the calling thread; `param` is valid for the call.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    os_result(rc)
}

/// The time slice the loop asks for under SCHED_OTHER:
/// [`short_fair_slice`].
pub const FAIR_SLICE_NS: u64 = 100_000;

/// Asks the fair scheduler (EEVDF, Linux 6.12+) for a [`FAIR_SLICE_NS`]
/// slice for the calling SCHED_OTHER thread (`sched_setattr` with
/// `sched_runtime`): a thread with a shorter slice gets an earlier virtual
/// deadline, so its wake-up preempts a running thread of the default 3 ms
/// slice instead of waiting for that slice to end. An error on older
/// kernels (they take `sched_runtime` as 0 only).
pub fn short_fair_slice() -> io::Result<()> {
    let attr = libc::sched_attr {
        size: std::mem::size_of::<libc::sched_attr>() as u32,
        sched_policy: libc::SCHED_OTHER as u32,
        sched_flags: 0,
        sched_nice: 0,
        sched_priority: 0,
        sched_runtime: FAIR_SLICE_NS,
        sched_deadline: 0,
        sched_period: 0,
    };
    // SAFETY: pid 0 is the calling thread; `attr` is a valid sched_attr of
    // the size it states, only read by the kernel; flags 0.
    let rc = unsafe { libc::syscall(libc::SYS_sched_setattr, 0, &attr, 0) };
    os_result(rc as libc::c_int)
}

/// Pins the calling thread to `cpu`.
pub fn pin_to_cpu(cpu: usize) -> io::Result<()> {
    check_cpu(cpu)?;
    // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET stays in bounds (checked above).
    let rc = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    os_result(rc)
}

/// Locks current and future pages in RAM (no page faults in the loop).
pub fn lock_memory() -> io::Result<()> {
    // SAFETY: plain system call with constant flags.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    os_result(rc)
}

/// Sets the calling thread's timer slack to 1 ns, so absolute-deadline
/// sleeps are not deferred by the default 50 us slack of normal threads.
pub fn minimal_timer_slack() -> io::Result<()> {
    // SAFETY: PR_SET_TIMERSLACK takes one unsigned long argument; the rest are ignored.
    let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    os_result(rc)
}

/// Ignores SIGXFSZ: a write past RLIMIT_FSIZE then fails with EFBIG (and
/// the loop ramps down) instead of killing the process.
pub fn ignore_file_size_signal() -> io::Result<()> {
    // SAFETY: SIG_IGN for SIGXFSZ installs no handler code.
    if unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) } == libc::SIG_ERR {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// The signals that stop the loop as SIGTERM does (the controlled stop,
/// the statistics, the log's end line): an interrupt (SIGINT), a polite
/// kill (SIGTERM), a closed terminal or a dropped SSH session (SIGHUP),
/// Ctrl-\\ (SIGQUIT, no core dump), the user signals (SIGUSR1, SIGUSR2,
/// whose default action would kill the process without a word) and a
/// reader gone from a pipe (SIGPIPE; a write to it then fails with EPIPE
/// instead).
pub const STOP_SIGNALS: [libc::c_int; 7] = [
    libc::SIGINT,
    libc::SIGTERM,
    libc::SIGHUP,
    libc::SIGQUIT,
    libc::SIGUSR1,
    libc::SIGUSR2,
    libc::SIGPIPE,
];

/// Makes each of [`STOP_SIGNALS`] store its number in `flag` (0: none
/// yet) instead of its default action; the loop reads the flag once per
/// tick.
pub fn register_stop_signals(flag: &Arc<AtomicUsize>) -> io::Result<()> {
    for sig in STOP_SIGNALS {
        signal_hook::flag::register_usize(sig, Arc::clone(flag), sig as usize)?;
    }
    Ok(())
}

/// The name of a signal number (`SIGTERM`), for the stop reason;
/// "(another signal)" for one not in [`STOP_SIGNALS`].
pub fn signal_name(signal: i32) -> &'static str {
    match signal {
        libc::SIGINT => "SIGINT",
        libc::SIGTERM => "SIGTERM",
        libc::SIGHUP => "SIGHUP",
        libc::SIGQUIT => "SIGQUIT",
        libc::SIGUSR1 => "SIGUSR1",
        libc::SIGUSR2 => "SIGUSR2",
        libc::SIGPIPE => "SIGPIPE",
        _ => "(another signal)",
    }
}

/// Keeps the calling thread off `cpu`: its affinity becomes every CPU it may
/// use except `cpu` (threads it spawns afterwards inherit this, so the log
/// writer stays off the loop's CPU). An error if no other CPU is left.
pub fn avoid_cpu(cpu: usize) -> io::Result<()> {
    check_cpu(cpu)?;
    // SAFETY: a zeroed cpu_set_t is a valid empty set; the get call fills it
    // (size passed is its own); CPU_CLR/CPU_COUNT stay in bounds (checked above).
    let rc = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        let size = std::mem::size_of::<libc::cpu_set_t>();
        if libc::sched_getaffinity(0, size, &mut set) != 0 {
            return Err(io::Error::last_os_error());
        }
        libc::CPU_CLR(cpu, &mut set);
        if libc::CPU_COUNT(&set) == 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "no CPU left besides the loop's",
            ));
        }
        libc::sched_setaffinity(0, size, &set)
    };
    os_result(rc)
}

/// Stack the loop may use, touched once before it starts.
pub const PREFAULT_STACK_BYTES: usize = 256 * 1024;

/// Touches [`PREFAULT_STACK_BYTES`] of the calling thread's stack, so that
/// (with `mlockall(MCL_FUTURE)`) those pages are resident before the loop and
/// its first deep calls take no page fault.
pub fn prefault_stack() {
    let mut block = [0u8; PREFAULT_STACK_BYTES];
    // One write per 4 KiB page, kept by black_box.
    for b in block.iter_mut().step_by(4096) {
        *b = 1;
    }
    std::hint::black_box(&mut block);
}

/// Page faults (minor + major) the calling thread has taken so far
/// (`getrusage(RUSAGE_THREAD)`); 0 if the kernel does not say.
pub fn thread_page_faults() -> u64 {
    // SAFETY: an all-zero rusage is a valid value; the call only writes it.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `usage` is a valid, writable rusage for the call.
    if unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut usage) } != 0 {
        return 0;
    }
    (usage.ru_minflt + usage.ru_majflt) as u64
}

/// A system call's return code (0 = success) as a `Result` with `errno`.
fn os_result(rc: libc::c_int) -> io::Result<()> {
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// `cpu` fits a `cpu_set_t` (so `CPU_SET`/`CPU_CLR` stay in bounds).
fn check_cpu(cpu: usize) -> io::Result<()> {
    if cpu < libc::CPU_SETSIZE as usize {
        Ok(())
    } else {
        Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "cpu out of range",
        ))
    }
}
