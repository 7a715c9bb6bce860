//! Sorting of short `u32` lists: the neighbourhood lists are sorted before
//! they are stored (one list of about 56 entries per vertex), which a
//! general-purpose sort does at about 300 ns a list. A bitonic sorting
//! network over 64 lanes in AVX2 registers does it in a fraction of that.

/// Sorts `list` ascending: lists of 17 to 64 entries with a sorting network
/// in AVX2 registers where the CPU has it, the others with
/// `sort_unstable` (the same result: sorting is sorting).
#[inline]
pub fn sort_short(list: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if (17..=64).contains(&list.len()) && std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { avx2::sort64(list) };
        return;
    }
    list.sort_unstable();
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    /// Eight registers of eight lanes: 64 entries.
    type Block = [__m256i; 8];

    /// Sorts `list` (at most 64 entries): padded with `u32::MAX` to 64,
    /// each lane across the eight registers sorted by an 8-input network,
    /// the 8 x 8 block transposed so that each register holds a sorted run,
    /// then the runs merged pairwise by bitonic merges (8 + 8, 16 + 16,
    /// 32 + 32).
    #[target_feature(enable = "avx2")]
    pub(super) fn sort64(list: &mut [u32]) {
        debug_assert!(list.len() <= 64);
        let mut buf = [u32::MAX; 64];
        buf[..list.len()].copy_from_slice(list);
        let mut r: Block = [_mm256_setzero_si256(); 8];
        for (i, x) in r.iter_mut().enumerate() {
            // SAFETY: `buf` holds 64 u32: eight unaligned loads of 8 lanes.
            *x = unsafe { _mm256_loadu_si256(buf.as_ptr().add(8 * i).cast()) };
        }
        // An optimal 19-comparator network for 8 inputs, on every lane.
        for layer in NETWORK_8 {
            for &(a, b) in layer {
                (r[a], r[b]) = exchange(r[a], r[b]);
            }
        }
        transpose(&mut r);
        // Runs of 8 -> 16.
        for k in [0, 2, 4, 6] {
            let (lo, hi) = exchange(r[k], reverse(r[k + 1]));
            (r[k], r[k + 1]) = (clean8(lo), clean8(hi));
        }
        // Runs of 16 -> 32.
        for k in [0, 4] {
            let (lo0, hi0) = exchange(r[k], reverse(r[k + 3]));
            let (lo1, hi1) = exchange(r[k + 1], reverse(r[k + 2]));
            let (a, b) = exchange(lo0, lo1);
            let (c, d) = exchange(hi0, hi1);
            r[k] = clean8(a);
            r[k + 1] = clean8(b);
            r[k + 2] = clean8(c);
            r[k + 3] = clean8(d);
        }
        // Runs of 32 -> 64.
        let mut lo = [r[0]; 4];
        let mut hi = [r[0]; 4];
        for i in 0..4 {
            (lo[i], hi[i]) = exchange(r[i], reverse(r[7 - i]));
        }
        for half in [&mut lo, &mut hi] {
            for (a, b) in [(0, 2), (1, 3), (0, 1), (2, 3)] {
                (half[a], half[b]) = exchange(half[a], half[b]);
            }
            for x in half.iter_mut() {
                *x = clean8(*x);
            }
        }
        for i in 0..4 {
            // SAFETY: `buf` holds 64 u32: eight unaligned stores of 8 lanes.
            unsafe {
                _mm256_storeu_si256(buf.as_mut_ptr().add(8 * i).cast(), lo[i]);
                _mm256_storeu_si256(buf.as_mut_ptr().add(8 * (i + 4)).cast(), hi[i]);
            }
        }
        let n = list.len();
        list.copy_from_slice(&buf[..n]);
    }

    /// Layers of an optimal sorting network for 8 inputs (19 comparators).
    const NETWORK_8: [&[(usize, usize)]; 6] = [
        &[(0, 2), (1, 3), (4, 6), (5, 7)],
        &[(0, 4), (1, 5), (2, 6), (3, 7)],
        &[(0, 1), (2, 3), (4, 5), (6, 7)],
        &[(2, 4), (3, 5)],
        &[(1, 4), (3, 6)],
        &[(1, 2), (3, 4), (5, 6)],
    ];

    /// Lane-wise (min, max).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn exchange(a: __m256i, b: __m256i) -> (__m256i, __m256i) {
        (_mm256_min_epu32(a, b), _mm256_max_epu32(a, b))
    }

    /// The lanes in reverse order.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn reverse(x: __m256i) -> __m256i {
        _mm256_permutevar8x32_epi32(x, _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0))
    }

    /// Sorts a bitonic sequence of 8 lanes: exchanges at distances 4, 2, 1.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn clean8(x: __m256i) -> __m256i {
        let t = _mm256_permute2x128_si256::<0x01>(x, x);
        let x = _mm256_blend_epi32::<0b1111_0000>(_mm256_min_epu32(x, t), _mm256_max_epu32(x, t));
        let t = _mm256_shuffle_epi32::<0b0100_1110>(x);
        let x = _mm256_blend_epi32::<0b1100_1100>(_mm256_min_epu32(x, t), _mm256_max_epu32(x, t));
        let t = _mm256_shuffle_epi32::<0b1011_0001>(x);
        _mm256_blend_epi32::<0b1010_1010>(_mm256_min_epu32(x, t), _mm256_max_epu32(x, t))
    }

    /// Transposes the 8 x 8 block (register `i`, lane `j`) -> (register
    /// `j`, lane `i`).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn transpose(r: &mut Block) {
        let t0 = _mm256_unpacklo_epi32(r[0], r[1]);
        let t1 = _mm256_unpackhi_epi32(r[0], r[1]);
        let t2 = _mm256_unpacklo_epi32(r[2], r[3]);
        let t3 = _mm256_unpackhi_epi32(r[2], r[3]);
        let t4 = _mm256_unpacklo_epi32(r[4], r[5]);
        let t5 = _mm256_unpackhi_epi32(r[4], r[5]);
        let t6 = _mm256_unpacklo_epi32(r[6], r[7]);
        let t7 = _mm256_unpackhi_epi32(r[6], r[7]);
        let u0 = _mm256_unpacklo_epi64(t0, t2);
        let u1 = _mm256_unpackhi_epi64(t0, t2);
        let u2 = _mm256_unpacklo_epi64(t1, t3);
        let u3 = _mm256_unpackhi_epi64(t1, t3);
        let u4 = _mm256_unpacklo_epi64(t4, t6);
        let u5 = _mm256_unpackhi_epi64(t4, t6);
        let u6 = _mm256_unpacklo_epi64(t5, t7);
        let u7 = _mm256_unpackhi_epi64(t5, t7);
        r[0] = _mm256_permute2x128_si256::<0x20>(u0, u4);
        r[1] = _mm256_permute2x128_si256::<0x20>(u1, u5);
        r[2] = _mm256_permute2x128_si256::<0x20>(u2, u6);
        r[3] = _mm256_permute2x128_si256::<0x20>(u3, u7);
        r[4] = _mm256_permute2x128_si256::<0x31>(u0, u4);
        r[5] = _mm256_permute2x128_si256::<0x31>(u1, u5);
        r[6] = _mm256_permute2x128_si256::<0x31>(u2, u6);
        r[7] = _mm256_permute2x128_si256::<0x31>(u3, u7);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_lists_sort_like_sort_unstable() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for len in 0..=80 {
            for round in 0..200 {
                // Wide values, narrow values (many repeats) and the extremes.
                let list: Vec<u32> = (0..len)
                    .map(|_| match round % 4 {
                        0 => next() as u32,
                        1 => (next() % 8) as u32,
                        2 => [0, u32::MAX, 1, u32::MAX - 1][(next() % 4) as usize],
                        _ => 100_000 + (next() % 3000) as u32,
                    })
                    .collect();
                let mut expected = list.clone();
                expected.sort_unstable();
                let mut got = list.clone();
                sort_short(&mut got);
                assert_eq!(got, expected, "length {len}, input {list:?}");
            }
        }
    }
}
