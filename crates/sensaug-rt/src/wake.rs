//! A tick's wake-up: sleep until its deadline, or (`rig.realtime.spin_us`)
//! sleep until shortly before it and busy-wait on the clock for the rest.
//!
//! Two latencies come out of each wake-up, kept apart so that the
//! comparison with cyclictest stays honest: the *wake latency* (the tick's
//! start after its deadline: what the controller sees) and the *sleep
//! latency* (the sleep's return after its own target: the OS timer's
//! latency, what cyclictest measures). Without a spin they are one.
//!
//! [`wake_up`] takes the clock and the sleep as arguments, so the tests
//! drive it with scripted clock readings; the loop passes [`os::now_ns`]
//! and [`os::sleep_until`].
//!
//! [`os::now_ns`]: crate::os::now_ns
//! [`os::sleep_until`]: crate::os::sleep_until

/// When a tick was due, what its sleep aimed at, and when each ended (ns,
/// `CLOCK_MONOTONIC`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Wake {
    /// The tick's deadline.
    pub deadline_ns: u64,
    /// The sleep's target: the deadline less the spin.
    pub sleep_target_ns: u64,
    /// The first clock reading after the sleep returned.
    pub slept_ns: u64,
    /// The tick's start: the first clock reading at or after the deadline
    /// (`slept_ns` itself when the sleep returned that late).
    pub woke_ns: u64,
}

impl Wake {
    /// The tick's start after its deadline (ns): what the controller sees.
    pub fn wake_latency_ns(&self) -> u64 {
        self.woke_ns.saturating_sub(self.deadline_ns)
    }

    /// The sleep's return after its own target (ns): the OS timer's
    /// latency. Equal to [`Wake::wake_latency_ns`] without a spin.
    pub fn sleep_latency_ns(&self) -> u64 {
        self.slept_ns.saturating_sub(self.sleep_target_ns)
    }
}

/// Waits for `deadline_ns`: `sleep_until(deadline_ns - spin_ns)`, then
/// reads `now` until a reading is at or after the deadline; no spinning when
/// the sleep returned that late. With `spin_ns = 0` this is a plain sleep
/// until the deadline (and a sleep that returned early, which
/// `clock_nanosleep` with an absolute deadline does not, is made up by
/// spinning). Allocates nothing; the spin yields the pipeline
/// ([`std::hint::spin_loop`]) between readings.
pub fn wake_up(
    deadline_ns: u64,
    spin_ns: u64,
    sleep_until: impl FnOnce(u64),
    mut now: impl FnMut() -> u64,
) -> Wake {
    let sleep_target_ns = deadline_ns.saturating_sub(spin_ns);
    sleep_until(sleep_target_ns);
    let slept_ns = now();
    let mut woke_ns = slept_ns;
    while woke_ns < deadline_ns {
        std::hint::spin_loop();
        woke_ns = now();
    }
    Wake {
        deadline_ns,
        sleep_target_ns,
        slept_ns,
        woke_ns,
    }
}

#[cfg(test)]
mod tests {
    use super::{wake_up, Wake};
    use std::cell::Cell;

    /// A clock that returns `readings` in order (and panics past them: a
    /// test that reads more than it scripted is wrong), and the sleeps asked
    /// for.
    struct Script {
        readings: Vec<u64>,
        next: Cell<usize>,
        slept_until: Cell<Option<u64>>,
    }

    impl Script {
        fn new(readings: &[u64]) -> Self {
            Script {
                readings: readings.to_vec(),
                next: Cell::new(0),
                slept_until: Cell::new(None),
            }
        }

        fn run(&self, deadline_ns: u64, spin_ns: u64) -> Wake {
            wake_up(
                deadline_ns,
                spin_ns,
                |t| self.slept_until.set(Some(t)),
                || {
                    let i = self.next.get();
                    self.next.set(i + 1);
                    self.readings[i]
                },
            )
        }

        fn reads(&self) -> usize {
            self.next.get()
        }
    }

    const DEADLINE: u64 = 5_000_000;

    #[test]
    fn with_a_spin_the_tick_starts_at_the_first_reading_at_the_deadline() {
        // Sleep until 100 us early; it returns 20 us after that target,
        // then the spin reads the clock until it reaches the deadline.
        let s = Script::new(&[4_920_000, 4_960_000, 4_999_999, 5_000_300, 5_000_900]);
        let w = s.run(DEADLINE, 100_000);
        assert_eq!(s.slept_until.get(), Some(4_900_000));
        assert_eq!(w.sleep_target_ns, 4_900_000);
        assert_eq!(w.slept_ns, 4_920_000);
        assert_eq!(w.woke_ns, 5_000_300, "the first reading >= the deadline");
        assert_eq!(s.reads(), 4, "no reading after the one that ended the spin");
        assert_eq!(w.sleep_latency_ns(), 20_000);
        assert_eq!(w.wake_latency_ns(), 300);
    }

    #[test]
    fn a_reading_exactly_at_the_deadline_starts_the_tick() {
        let s = Script::new(&[4_950_000, 5_000_000, 5_000_001]);
        let w = s.run(DEADLINE, 100_000);
        assert_eq!((w.woke_ns, w.wake_latency_ns()), (5_000_000, 0));
        assert_eq!(s.reads(), 2);
    }

    #[test]
    fn a_sleep_that_returns_after_the_deadline_does_not_spin() {
        // The timer was 130 us late on a 100 us spin: the tick starts at
        // once, 30 us late; the OS's part is the whole 130 us.
        let s = Script::new(&[5_030_000, 5_050_000]);
        let w = s.run(DEADLINE, 100_000);
        assert_eq!(s.reads(), 1, "one reading, no spin");
        assert_eq!(w.woke_ns, w.slept_ns);
        assert_eq!(w.sleep_latency_ns(), 130_000);
        assert_eq!(w.wake_latency_ns(), 30_000);
    }

    #[test]
    fn without_a_spin_both_latencies_are_one() {
        let s = Script::new(&[5_012_345, 5_050_000]);
        let w = s.run(DEADLINE, 0);
        assert_eq!(s.slept_until.get(), Some(DEADLINE));
        assert_eq!(s.reads(), 1);
        assert_eq!(w.sleep_latency_ns(), 12_345);
        assert_eq!(w.wake_latency_ns(), w.sleep_latency_ns());
    }

    #[test]
    fn a_sleep_that_returns_early_is_made_up_by_spinning() {
        // clock_nanosleep does not return early, but if it did (spin 0) the
        // tick still starts at its deadline, not before.
        let s = Script::new(&[4_999_000, 5_000_004]);
        let w = s.run(DEADLINE, 0);
        assert_eq!(w.woke_ns, 5_000_004);
        assert_eq!(w.sleep_latency_ns(), 0, "early is no latency");
    }

    #[test]
    fn a_spin_longer_than_the_time_since_zero_sleeps_until_zero() {
        let s = Script::new(&[10, 60_000]);
        let w = s.run(50_000, 100_000);
        assert_eq!(w.sleep_target_ns, 0);
        assert_eq!((w.sleep_latency_ns(), w.wake_latency_ns()), (10, 10_000));
    }
}
