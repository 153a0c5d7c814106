//! The three event queues must give identical results on any sequence of
//! operations: earliest time first, ties broken by the smaller index.

use edpm::queue::{CalendarQueue, EventQueue, IndexedHeap, ReferenceQueue};
use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// The three queues driven in lockstep.
struct Trio {
    reference: ReferenceQueue,
    heap: IndexedHeap,
    calendar: CalendarQueue,
}

impl Trio {
    fn new(n: usize) -> Self {
        Self {
            reference: ReferenceQueue::with_capacity(n),
            heap: IndexedHeap::with_capacity(n),
            calendar: CalendarQueue::with_capacity(n),
        }
    }

    fn set(&mut self, i: u32, t: f64) {
        self.reference.set(i, t);
        self.heap.set(i, t);
        self.calendar.set(i, t);
    }

    fn remove(&mut self, i: u32) {
        self.reference.remove(i);
        self.heap.remove(i);
        self.calendar.remove(i);
    }

    fn clear(&mut self) {
        self.reference.clear();
        self.heap.clear();
        self.calendar.clear();
    }

    /// Peeks all three, asserts they agree (and agree on `len`), and returns
    /// the common answer.
    fn peek(&mut self) -> Option<(f64, u32)> {
        let r = self.reference.peek_min();
        assert_eq!(
            self.heap.peek_min(),
            r,
            "indexed heap differs from reference"
        );
        assert_eq!(
            self.calendar.peek_min(),
            r,
            "calendar differs from reference"
        );
        assert_eq!(self.heap.len(), self.reference.len());
        assert_eq!(self.calendar.len(), self.reference.len());
        assert_eq!(self.calendar.is_empty(), self.reference.is_empty());
        r
    }
}

/// Time offset ahead of the current time.
#[derive(Clone, Copy, Debug)]
enum Dt {
    /// `k / 4`: exact binary fractions, so ties are common.
    Tick(u8),
    /// Continuous, within a few bucket widths.
    Fine(f64),
    /// Far ahead, to reach the calendar's overflow.
    Far(f64),
    /// No event.
    Never,
}

impl Dt {
    fn after(self, now: f64) -> f64 {
        match self {
            Dt::Tick(k) => now + f64::from(k) * 0.25,
            Dt::Fine(x) | Dt::Far(x) => now + x,
            Dt::Never => f64::INFINITY,
        }
    }
}

fn dt() -> impl Strategy<Value = Dt> {
    prop_oneof![
        4 => (0u8..12).prop_map(Dt::Tick),
        4 => (0.0..3.0f64).prop_map(Dt::Fine),
        1 => (0.0..1e7f64).prop_map(Dt::Far),
        1 => Just(Dt::Never),
    ]
}

#[derive(Clone, Debug)]
enum Op {
    /// `set(i, now + dt)`.
    Set(u32, Dt),
    Remove(u32),
    Peek,
    /// `clear()`, after which the current time becomes the given base,
    /// possibly earlier than before (as when the engine rebases to 0).
    Clear(f64),
    /// Engine step: `(t, i)` = minimum, `set(i, t + a)`, `set(j, t + b)`.
    Hold(Dt, u32, Dt),
}

fn ops(n: u32) -> impl Strategy<Value = Vec<Op>> {
    let op = prop_oneof![
        8 => (0..n, dt()).prop_map(|(i, d)| Op::Set(i, d)),
        2 => (0..n).prop_map(Op::Remove),
        2 => Just(Op::Peek),
        1 => (-50.0..50.0f64).prop_map(Op::Clear),
        8 => (dt(), 0..n, dt()).prop_map(|(a, j, b)| Op::Hold(a, j, b)),
    ];
    prop::collection::vec(op, 0..400)
}

/// Runs `ops` on all queues. Every `set` respects the engine's contract:
/// its time is at least the last minimum returned (or the base after a
/// clear). With `check_each`, the queues are compared after every operation;
/// otherwise only at `Peek`/`Hold` and at the end, so that runs of `set`s
/// reach the calendar without intervening peeks.
fn run(n: u32, ops: &[Op], check_each: bool) {
    let mut q = Trio::new(n as usize);
    let mut now = 0.0f64;
    for op in ops {
        match *op {
            Op::Set(i, d) => q.set(i, d.after(now)),
            Op::Remove(i) => q.remove(i),
            Op::Peek => {
                if let Some((t, _)) = q.peek()
                    && t.is_finite()
                {
                    now = now.max(t);
                }
            }
            Op::Clear(base) => {
                q.clear();
                now = base;
            }
            Op::Hold(a, j, b) => {
                if let Some((t, i)) = q.peek()
                    && t.is_finite()
                {
                    now = now.max(t);
                    q.set(i, a.after(now));
                    q.set(j, b.after(now));
                }
            }
        }
        if check_each {
            q.peek();
        }
    }
    q.peek();
    drain(&mut q);
}

/// Removes the minimum repeatedly, checking the queues agree each time.
fn drain(q: &mut Trio) {
    while let Some((_, i)) = q.peek() {
        q.remove(i);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn random_ops_checked_each_step(n in 1u32..40, ops in ops(40)) {
        let ops: Vec<Op> = ops.into_iter().map(|op| clamp(op, n)).collect();
        run(n, &ops, true);
    }

    #[test]
    fn random_ops_checked_at_peeks(n in 1u32..40, ops in ops(40)) {
        let ops: Vec<Op> = ops.into_iter().map(|op| clamp(op, n)).collect();
        run(n, &ops, false);
    }

    /// Outside the engine's contract: any time at all, including ones before
    /// the current minimum and -∞. All queues must still agree.
    #[test]
    fn arbitrary_times(
        ops in prop::collection::vec(
            (0u32..30, prop_oneof![
                4 => (-8i8..8).prop_map(|k| f64::from(k) * 0.5),
                4 => -1e3..1e3f64,
                1 => prop_oneof![Just(f64::INFINITY), Just(f64::NEG_INFINITY), Just(-0.0), Just(1e300)],
            ], 0u8..10),
            0..300,
        )
    ) {
        let mut q = Trio::new(30);
        for (i, t, kind) in ops {
            match kind {
                0 => q.remove(i),
                1 => { q.peek(); }
                2 if i == 0 => q.clear(),
                _ => q.set(i, t),
            }
            if kind % 2 == 0 {
                q.peek();
            }
        }
        drain(&mut q);
    }
}

/// Keeps particle indices of an operation below `n`.
fn clamp(op: Op, n: u32) -> Op {
    match op {
        Op::Set(i, d) => Op::Set(i % n, d),
        Op::Remove(i) => Op::Remove(i % n),
        Op::Hold(a, j, b) => Op::Hold(a, j % n, b),
        other => other,
    }
}

/// Exponentially distributed with the given mean.
fn exp(rng: &mut Xoshiro256PlusPlus, mean: f64) -> f64 {
    -mean * (1.0 - rng.random::<f64>()).ln()
}

/// Long seeded runs mixing all operations, with the time scale changing
/// between phases by up to twelve orders of magnitude, so that the calendar
/// must re-tune its bucket width.
#[test]
fn seeded_mixed_phases() {
    for seed in 0..6u64 {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let n = [1u32, 2, 17, 300, 2000, 5000][seed as usize];
        let mut q = Trio::new(n as usize);
        let mut now = 0.0;
        for phase in 0..8 {
            let mean = 10f64.powi(rng.random_range(-6..=6));
            let tick = rng.random_bool(0.5);
            if rng.random_bool(0.5) {
                // Engine rebase: clear, then refill every particle from 0.
                q.clear();
                now = 0.0;
                for i in 0..n {
                    q.set(i, exp(&mut rng, mean));
                }
            }
            for _ in 0..4000 {
                let mut dt = exp(&mut rng, mean);
                if tick {
                    dt = (dt / mean * 4.0).floor() * mean / 4.0;
                }
                let i = rng.random_range(0..n);
                match rng.random_range(0..20) {
                    0 => q.remove(i),
                    1 => q.set(i, f64::INFINITY),
                    2 => q.set(i, now + 1e4 * mean * rng.random::<f64>()),
                    3 if phase % 2 == 0 => {
                        q.peek();
                    }
                    4..=12 => q.set(i, now + dt),
                    _ => {
                        if let Some((t, m)) = q.peek()
                            && t.is_finite()
                        {
                            now = t;
                            q.set(m, now + dt);
                        }
                    }
                }
                // Odd phases compare only when the engine would peek.
                if phase % 2 == 1 {
                    continue;
                }
                q.peek();
            }
        }
        drain(&mut q);
    }
}

/// The engine's workload: peek the minimum `(t, i)`, reschedule `i` and a
/// random `j` at `t + Exp(1)`; 2·10^5 steps, compared at every step.
#[test]
fn hold_model() {
    for (n, seed) in [(1000u32, 1u64), (20_000, 2)] {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut q = Trio::new(n as usize);
        for i in 0..n {
            q.set(i, exp(&mut rng, 1.0));
        }
        let mut last = 0.0;
        for _ in 0..100_000 {
            let (t, i) = q.peek().expect("hold keeps every particle queued");
            assert!(t >= last);
            last = t;
            q.set(i, t + exp(&mut rng, 1.0));
            q.set(rng.random_range(0..n), t + exp(&mut rng, 1.0));
        }
        drain(&mut q);
    }
}

/// Hold model on a coarse time grid, so most comparisons are ties.
#[test]
fn hold_model_with_ties() {
    let n = 500u32;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let mut q = Trio::new(n as usize);
    for i in 0..n {
        q.set(i, f64::from(rng.random_range(0..4u8)));
    }
    for _ in 0..50_000 {
        let (t, i) = q.peek().expect("hold keeps every particle queued");
        q.set(i, t + f64::from(rng.random_range(0..4u8)));
        q.set(
            rng.random_range(0..n),
            t + f64::from(rng.random_range(0..4u8)),
        );
    }
    drain(&mut q);
}

/// All events tied, and all at infinity: smallest index first.
#[test]
fn ties_and_infinity() {
    let mut q = Trio::new(100);
    for i in (0..100).rev() {
        q.set(i, 5.0);
    }
    assert_eq!(q.peek(), Some((5.0, 0)));
    for i in 0..100 {
        q.set(i, f64::INFINITY);
    }
    assert_eq!(q.peek(), Some((f64::INFINITY, 0)));
    q.set(73, 1.0);
    assert_eq!(q.peek(), Some((1.0, 73)));
    q.remove(73);
    q.remove(0);
    assert_eq!(q.peek(), Some((f64::INFINITY, 1)));
    q.clear();
    assert_eq!(q.peek(), None);
    // Indices beyond the initial capacity are accepted.
    q.set(1000, 2.0);
    assert_eq!(q.peek(), Some((2.0, 1000)));
    drain(&mut q);
}
