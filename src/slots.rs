//! Slots of a counting sort's scatter, taken a block of keys at a time.
//!
//! A counting sort's scatter puts each element at its key's counter and
//! increments the counter: a load, an add and a store to the same place,
//! which the next element with the same key loads again. Where keys repeat
//! from one element to the next (consecutive triangles under the vertex
//! they share, consecutive vertices in one bucket of x), every element
//! waits for the previous one's store to reach its load: a chain through
//! memory. [`take`] reads the counters of a block of keys at once, counts
//! the block's repeats in registers, and stores the counters after, so
//! that the chain goes from block to block instead of from element to
//! element. Users: the topology's sort of each range's listings by vertex
//! (`topology::sort_range`) and the weld's scatter of vertices into
//! buckets of x (`weld::sort_vertices`); the figures are theirs.

/// Keys a block of [`take`] holds in its two users. Why 4: the topology's
/// sort took 10.47–10.57 ms of the dragon's emit pass with blocks of 2
/// against 10.33–10.50 with 4, and blocks of 6 and 8 took longer than
/// single elements (their arrays went to the stack; `RECYCLE=1
/// RAYON_NUM_THREADS=1 cargo run --release --example stage_probe --
/// passes target/dragon/dragon.glb`, three alternations).
pub(crate) const BLOCK: usize = 4;

/// The slots of `keys`, in order, as a scatter one key at a time would
/// give them: each key's counter plus the number of earlier keys of the
/// block equal to it. Every counter named is then advanced past its
/// block's keys (the counters are stored in order, so the last store of a
/// repeated key holds its count).
///
/// Panics if a key is not an index of `counters`.
#[inline(always)]
pub(crate) fn take<const N: usize>(keys: [usize; N], counters: &mut [u32]) -> [usize; N] {
    let counts = keys.map(|key| counters[key] as usize);
    let mut slots = [0usize; N];
    for k in 0..N {
        let mut slot = counts[k];
        for i in 0..k {
            slot += usize::from(keys[i] == keys[k]);
        }
        slots[k] = slot;
    }
    for k in 0..N {
        counters[keys[k]] = slots[k] as u32 + 1;
    }
    slots
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One key at a time, as the scatter did before blocks.
    fn one_by_one<const N: usize>(keys: [usize; N], counters: &mut [u32]) -> [usize; N] {
        std::array::from_fn(|k| {
            let s = counters[keys[k]] as usize;
            counters[keys[k]] += 1;
            s
        })
    }

    #[test]
    fn blocks_give_the_slots_and_counters_of_one_key_at_a_time() {
        // Every block of 4 keys over 3 values (all patterns of repeats),
        // from counters that already differ.
        for code in 0..81usize {
            let keys: [usize; BLOCK] = std::array::from_fn(|k| code / 3usize.pow(k as u32) % 3);
            let (mut blocked, mut single) = (vec![5u32, 0, 9], vec![5u32, 0, 9]);
            assert_eq!(
                take(keys, &mut blocked),
                one_by_one(keys, &mut single),
                "{keys:?}"
            );
            assert_eq!(blocked, single, "{keys:?}");
        }
    }
}
