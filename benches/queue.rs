//! Hold-model benchmark of the event queues.
//!
//! Each iteration is one engine-like event: peek the minimum `(t, i)`, then
//! reschedule `i` and one random particle `j` at `t + Exp(1)`. Random numbers
//! come from a precomputed table so the timing is the queue's own.
//!
//! `calendar-from-empty` is the calendar queue built for no events and then
//! filled, as in a riser that starts empty: its ring must grow to the
//! events to match `calendar`.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use edpm::queue::{CalendarQueue, EventQueue, IndexedHeap, ReferenceQueue};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Length of the random table (a power of two).
const TABLE: usize = 1 << 20;

/// Precomputed `(Exp(1), Exp(1), j)` triples, cycled through.
struct Draws {
    table: Vec<(f64, f64, u32)>,
    next: usize,
}

impl Draws {
    fn new(n: usize, seed: u64) -> Self {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let exp = |rng: &mut Xoshiro256PlusPlus| -(1.0 - rng.random::<f64>()).ln();
        let table = (0..TABLE)
            .map(|_| {
                let a = exp(&mut rng);
                let b = exp(&mut rng);
                (a, b, rng.random_range(0..n as u32))
            })
            .collect();
        Self { table, next: 0 }
    }

    #[inline]
    fn draw(&mut self) -> (f64, f64, u32) {
        let d = self.table[self.next];
        self.next = (self.next + 1) & (TABLE - 1);
        d
    }
}

/// One hold step.
#[inline]
fn step<Q: EventQueue>(q: &mut Q, draws: &mut Draws) {
    if let Some((t, i)) = q.peek_min() {
        let (a, b, j) = draws.draw();
        q.set(i, t + a);
        q.set(j, t + b);
    }
}

/// `capacity(n)`: the size the queue is built for, before `n` events.
fn bench_queue<Q: EventQueue>(c: &mut Criterion, name: &str, capacity: fn(usize) -> usize) {
    let mut group = c.benchmark_group("hold");
    group.throughput(Throughput::Elements(1));
    for n in [10_000usize, 100_000] {
        let mut draws = Draws::new(n, 7);
        let mut q = Q::with_capacity(capacity(n));
        for i in 0..n {
            let (a, _, _) = draws.draw();
            q.set(i as u32, a);
        }
        // Reach the steady-state distribution of pending times.
        for _ in 0..10 * n {
            step(&mut q, &mut draws);
        }
        group.bench_function(BenchmarkId::new(name, n), |b| {
            b.iter(|| step(black_box(&mut q), &mut draws))
        });
    }
    group.finish();
}

fn benches(c: &mut Criterion) {
    let sized = |n| n;
    bench_queue::<ReferenceQueue>(c, "reference", sized);
    bench_queue::<IndexedHeap>(c, "indexed-heap", sized);
    bench_queue::<CalendarQueue>(c, "calendar", sized);
    bench_queue::<CalendarQueue>(c, "calendar-from-empty", |_| 0);
}

criterion_group! {
    name = queue;
    config = Criterion::default()
        .sample_size(20)
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = benches
}
criterion_main!(queue);
