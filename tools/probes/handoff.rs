//! What handing freshly written data from one core to the other costs on
//! this host (docs/scaling.md, 2.6). Not part of the crate:
//!
//!     rustc -O -o /tmp/handoff tools/probes/handoff.rs && /tmp/handoff
//!
//! For buffers of 1, 4 and 16 MiB, thread 0 writes the buffer and then
//! thread 0 itself or thread 1 reads it, in two ways: sequentially (the
//! prefetchers' case) and one dependent load per 64-byte line in a
//! pseudo-random order (a flight's case). Medians of 100 rounds. Last, the
//! round trip of one flag between the two threads (a barrier's cost).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

const ROUNDS: usize = 100;

fn write(buf: &mut [u64], round: u64) {
    for (k, x) in buf.iter_mut().enumerate() {
        *x = x.wrapping_add(k as u64 ^ round);
    }
}

fn read(buf: &[u64], random: bool) -> u64 {
    if !random {
        return buf.iter().fold(0u64, |a, &x| a.wrapping_add(x));
    }
    let lines = (buf.len() / 8) as u64;
    let (mut k, mut acc) = (0u64, 0u64);
    for _ in 0..lines {
        acc = acc.wrapping_add(buf[(k * 8) as usize]);
        // The next line depends on the load: no overlap between loads.
        k = k.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407 ^ (acc & 1)) % lines;
    }
    acc
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Median seconds of one read, by the writing thread or by another one.
fn handoff(mib: usize, random: bool, other: bool) -> f64 {
    let mut buf = vec![0u64; mib << 17];
    let turn = AtomicUsize::new(0);
    let mut times = Vec::with_capacity(ROUNDS);
    if !other {
        for r in 0..ROUNDS {
            write(&mut buf, r as u64);
            let t = Instant::now();
            std::hint::black_box(read(&buf, random));
            times.push(t.elapsed().as_secs_f64());
        }
        return median(times);
    }
    let ptr = buf.as_mut_ptr() as usize;
    let n = buf.len();
    std::thread::scope(|s| {
        let reader = s.spawn(|| {
            // SAFETY: the turn flag orders every write before this read.
            let b = unsafe { std::slice::from_raw_parts(ptr as *const u64, n) };
            let mut times = Vec::with_capacity(ROUNDS);
            for r in 0..ROUNDS {
                while turn.load(Ordering::Acquire) != 2 * r + 1 {
                    std::hint::spin_loop();
                }
                let t = Instant::now();
                std::hint::black_box(read(b, random));
                times.push(t.elapsed().as_secs_f64());
                turn.store(2 * r + 2, Ordering::Release);
            }
            times
        });
        // SAFETY: the reader reads only between the flag's odd and even values.
        let b = unsafe { std::slice::from_raw_parts_mut(ptr as *mut u64, n) };
        for r in 0..ROUNDS {
            while turn.load(Ordering::Acquire) != 2 * r {
                std::hint::spin_loop();
            }
            write(b, r as u64);
            turn.store(2 * r + 1, Ordering::Release);
        }
        times = reader.join().unwrap();
    });
    median(times)
}

fn round_trip_ns() -> f64 {
    const TRIPS: usize = 200_000;
    let flag = AtomicUsize::new(0);
    std::thread::scope(|s| {
        s.spawn(|| {
            for k in 0..TRIPS {
                while flag.load(Ordering::Acquire) != 2 * k + 1 {
                    std::hint::spin_loop();
                }
                flag.store(2 * k + 2, Ordering::Release);
            }
        });
        let t = Instant::now();
        for k in 0..TRIPS {
            flag.store(2 * k + 1, Ordering::Release);
            while flag.load(Ordering::Acquire) != 2 * k + 2 {
                std::hint::spin_loop();
            }
        }
        t.elapsed().as_secs_f64() / TRIPS as f64 * 1e9
    })
}

fn main() {
    println!("| MiB | access | read by the writer (ms) | read by the other core (ms) | extra per 64-byte line (ns) |");
    println!("|---|---|---|---|---|");
    for mib in [1, 4, 16] {
        for random in [false, true] {
            let (own, other) = (handoff(mib, random, false), handoff(mib, random, true));
            let lines = (mib << 20) as f64 / 64.0;
            println!(
                "| {mib} | {} | {:.3} | {:.3} | {:.1} |",
                if random { "dependent, random" } else { "sequential" },
                own * 1e3,
                other * 1e3,
                (other - own) / lines * 1e9
            );
        }
    }
    println!("\nflag round trip between the two threads: {:.0} ns", round_trip_ns());
}
