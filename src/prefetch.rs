//! A hint to the CPU to start loading memory it will soon read. The
//! engine's hot loops gather candidates first and prefetch their records,
//! so that in large systems, where most of those loads miss the cache,
//! the misses overlap instead of waiting one by one.

/// Starts loading the cache line that holds the start of `value`. Never
/// faults and changes no state (a no-op off x86-64).
#[inline(always)]
pub fn prefetch<T>(value: &T) {
    prefetch_address(value as *const T);
}

/// Starts loading the cache line of `items[i]`, without a bounds check:
/// an index past the end requests a line nobody reads, which is harmless
/// (a prefetch never faults), so the hint costs no compare and branch.
#[inline(always)]
pub fn prefetch_at<T>(items: &[T], i: usize) {
    prefetch_address(items.as_ptr().wrapping_add(i));
}

/// The hint itself, for any address: it is never read.
#[inline(always)]
fn prefetch_address<T>(address: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is a hint: it reads no data into the program and
    // cannot fault, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(address.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = address;
}

/// Size of this CPU's per-core L2 cache in bytes (Linux sysfs), or 2 MiB
/// where it cannot be read. Read once. Whether a system's records fit in
/// it decides whether prefetching pays (`engine::Prefetch::Auto`).
pub fn l2_cache_bytes() -> usize {
    static BYTES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *BYTES.get_or_init(|| {
        l2_cache_bytes_in(std::path::Path::new("/sys/devices/system/cpu/cpu0/cache"))
            .unwrap_or(2 << 20)
    })
}

/// The L2 size in a sysfs cache directory: its `index*` entries each name
/// a cache's `level`, `type` and `size`; other entries (`uevent`) are
/// skipped.
fn l2_cache_bytes_in(dir: &std::path::Path) -> Option<usize> {
    std::fs::read_dir(dir).ok()?.flatten().find_map(|entry| {
        let read = |name: &str| std::fs::read_to_string(entry.path().join(name)).ok();
        let unified_or_data = read("type")?.trim() != "Instruction";
        (read("level")?.trim() == "2" && unified_or_data)
            .then(|| parse_cache_size(&read("size")?))
            .flatten()
    })
}

/// Bytes of a sysfs cache size such as `512K`, `2048K` or `1M`.
fn parse_cache_size(text: &str) -> Option<usize> {
    let text = text.trim();
    let (digits, unit) = if let Some(kib) = text.strip_suffix('K') {
        (kib, 1 << 10)
    } else if let Some(mib) = text.strip_suffix('M') {
        (mib, 1 << 20)
    } else {
        (text, 1)
    };
    let bytes = digits.parse::<usize>().ok()?.checked_mul(unit)?;
    (bytes > 0).then_some(bytes)
}

/// A consumer of candidates (pair partners, shell neighbours) that can
/// request a candidate's data before it takes the candidate in.
pub trait Gather {
    type Item: Copy + Default;
    /// Starts loading what [`Gather::take`] will read for `item`.
    fn prefetch(&self, item: Self::Item);
    /// Takes `item` into account.
    fn take(&mut self, item: Self::Item);
    /// Takes `items` into account, in order: the same as taking each
    /// (a gatherer may work on several at once).
    #[inline(always)]
    fn take_all(&mut self, items: &[Self::Item]) {
        for &item in items {
            self.take(item);
        }
    }
}

/// Candidates to hand to a [`Gather`] in batches of `N`: each batch's data
/// is requested first (when `prefetches`), so that its cache misses are in
/// flight together, then the batch is taken in the order it was offered
/// (the same order, and the same result, as taking each at once).
pub struct Batch<'a, G: Gather, const N: usize> {
    gather: &'a mut G,
    pending: [G::Item; N],
    len: usize,
    prefetches: bool,
}

impl<'a, G: Gather, const N: usize> Batch<'a, G, N> {
    #[inline]
    pub fn new(gather: &'a mut G, prefetches: bool) -> Self {
        Batch {
            gather,
            pending: [G::Item::default(); N],
            len: 0,
            prefetches,
        }
    }

    /// Requests `item`'s data and queues it.
    #[inline(always)]
    pub fn offer(&mut self, item: G::Item) {
        if self.len == N {
            self.take_pending();
        }
        if self.prefetches {
            self.gather.prefetch(item);
        }
        self.pending[self.len] = item;
        self.len += 1;
    }

    /// Takes every queued item.
    #[inline]
    pub fn finish(&mut self) {
        self.take_pending();
    }

    #[inline(always)]
    fn take_pending(&mut self) {
        self.gather.take_all(&self.pending[..self.len]);
        self.len = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records what it is handed, to check the order.
    #[derive(Default)]
    struct Log(Vec<u32>);

    impl Gather for Log {
        type Item = u32;
        fn prefetch(&self, _: u32) {}
        fn take(&mut self, item: u32) {
            self.0.push(item);
        }
    }

    #[test]
    fn a_batch_takes_every_item_in_the_offered_order() {
        // 10 items through batches of 4: two full batches and a partial one.
        let mut log = Log::default();
        let mut batch: Batch<Log, 4> = Batch::new(&mut log, true);
        for k in 0..10 {
            batch.offer(k);
        }
        batch.finish();
        assert_eq!(log.0, (0..10).collect::<Vec<_>>());
    }

    /// A directory laid out as sysfs lays out a CPU's caches, with the
    /// entry that is not a cache first, as `read_dir` lists it on the
    /// development host (the first version gave up at it and fell back).
    #[test]
    fn the_l2_is_found_among_the_other_caches() {
        let dir = std::env::temp_dir().join(format!("edpm-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        std::fs::write(dir.join("uevent"), "").expect("a file");
        for (index, level, kind, size) in [
            ("index0", "1", "Data", "32K"),
            ("index1", "1", "Instruction", "32K"),
            ("index2", "2", "Unified", "512K"),
            ("index3", "3", "Unified", "32768K"),
        ] {
            let cache = dir.join(index);
            std::fs::create_dir(&cache).expect("a cache directory");
            for (name, text) in [("level", level), ("type", kind), ("size", size)] {
                std::fs::write(cache.join(name), format!("{text}\n")).expect("a file");
            }
        }
        let found = l2_cache_bytes_in(&dir);
        std::fs::remove_dir_all(&dir).expect("the directory removed");
        assert_eq!(found, Some(512 << 10));
    }

    #[test]
    fn cache_sizes_parse_as_sysfs_writes_them() {
        assert_eq!(parse_cache_size("512K\n"), Some(512 << 10));
        assert_eq!(parse_cache_size("2048K"), Some(2 << 20));
        assert_eq!(parse_cache_size("1M"), Some(1 << 20));
        assert_eq!(parse_cache_size("65536"), Some(65536));
        assert_eq!(parse_cache_size("0K"), None);
        assert_eq!(parse_cache_size("big"), None);
    }
}
