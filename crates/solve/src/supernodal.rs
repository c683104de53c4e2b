//! Triangular solves with faer's supernodal Cholesky factor, reading the factor in its
//! storage order at the memory's rate.
//!
//! A crush's factor (nested dissection, ~22 million entries at 10⁵ people) is far larger
//! than any cache, so a solve is a read of the factor twice. faer's own solve takes a
//! matrix–vector product and a triangular solve per supernode, the backward one with its
//! supernodes taken from the last to the first and each one's columns read from the front:
//! every supernode starts a new stream of memory the processor has not prefetched
//! (benches/README.md, session 24: 40 ms a solve of the pressed crush of 10⁵, ~9 GB/s).
//! Here the forward solve reads each supernode's columns in storage order, one
//! multiply–subtract along each; the backward one reads them in exactly the reverse order,
//! each dot product from its end, so that the whole backward solve is one decreasing
//! stream: 22 ms a solve. Where the multifrontal factorization split the tree in two
//! ([`crate::frontal`]), the solves split the same way on two threads, with the same bits.

use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;

use moreau_core::Helper;

use crate::products::Index;

/// A supernode's place in faer's arrays: its first column, its width, the rows of its
/// pattern below, and where its rows and values start.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Supernode {
    pub(crate) begin: usize,
    pub(crate) width: usize,
    pub(crate) below: usize,
    pub(crate) rows_at: usize,
    pub(crate) values_at: usize,
}

impl Supernode {
    /// Supernode `s` of `symbolic`.
    pub(crate) fn of(symbolic: &SymbolicSupernodalCholesky<Index>, s: usize) -> Self {
        let begin = symbolic.supernode_begin()[s] as usize;
        let end = symbolic.supernode_end()[s] as usize;
        let rows = symbolic.col_ptr_for_row_idx();
        Self {
            begin,
            width: end - begin,
            below: (rows[s + 1] - rows[s]) as usize,
            rows_at: rows[s] as usize,
            values_at: symbolic.col_ptr_for_val()[s] as usize,
        }
    }

    /// Its rows below its columns (its pattern).
    pub(crate) fn pattern<'a>(
        &self,
        symbolic: &'a SymbolicSupernodalCholesky<Index>,
    ) -> &'a [Index] {
        &symbolic.row_idx()[self.rows_at..self.rows_at + self.below]
    }

    /// Its values in `l`: column-major, `width + below` rows, `width` columns.
    pub(crate) fn values<'a>(&self, l: &'a [f64]) -> &'a [f64] {
        &l[self.values_at..self.values_at + (self.width + self.below) * self.width]
    }
}

/// Solves `L Lᵀ x = b` in place (`x` holds `b` in the factor's order), `L` in faer's
/// supernodal layout (its values, `len_val` of them); `y` is scratch.
///
/// One pass over the factor each way. Forward, supernode after supernode, its part of `x`
/// and the updates of its rows below in one buffer, each column one multiply–subtract
/// along it. Backward, supernode before supernode, each column's rows below one dot
/// product, the columns from the last, then the diagonal block (now in cache) the same
/// way. The same bits with or without AVX (no fused multiply–add, the same order).
pub(crate) fn solve_in_place(
    symbolic: &SymbolicSupernodalCholesky<Index>,
    l: &[f64],
    x: &mut [f64],
    y: &mut Vec<f64>,
) {
    let (factor, n) = (Factor { symbolic, l }, x.len());
    let all = 0..symbolic.n_supernodes();
    let none = &mut InPlace {
        rows: &mut [],
        at: n,
    };
    forward_range(factor.part(all.clone(), x, 0), none, y);
    backward_range(factor.part(all, x, 0), (&[], n), y);
}

/// Scratch of [`solve_in_place_split`]: each thread's buffer, and the second part's updates
/// of the rest's rows in the order it made them.
#[derive(Debug, Default)]
pub(crate) struct SplitScratch {
    y: [Vec<f64>; 2],
    later: Vec<f64>,
}

/// [`solve_in_place`] on two threads, where supernodes `[0, at)` and `[at, fork)` are two
/// disjoint unions of subtrees (their rows below are their own or the rest's `[fork, ns)`,
/// [`crate::frontal`]'s split): forward, the two parts at once, the second keeping its
/// updates of the rest's rows, which are then added in the order one thread adds them;
/// then the rest. Backward, the rest, then the two parts at once (each reads the rest's
/// rows and writes its own). The same operations in the same order: the same bits as
/// [`solve_in_place`].
pub(crate) fn solve_in_place_split(
    symbolic: &SymbolicSupernodalCholesky<Index>,
    l: &[f64],
    x: &mut [f64],
    (at, fork): (usize, usize),
    scratch: &mut SplitScratch,
    helper: &Helper,
) {
    let (ns, n) = (symbolic.n_supernodes(), x.len());
    let factor = Factor { symbolic, l };
    let begin = |s: usize| Supernode::of(symbolic, s).begin;
    let (mid, top) = (begin(at), begin(fork));
    let [y0, y1] = &mut scratch.y;
    let later = &mut scratch.later;
    {
        let (x0, rest) = x.split_at_mut(mid);
        let (x1, x_top) = rest.split_at_mut(top - mid);
        later.clear();
        helper.join_once(
            || {
                let here = &mut InPlace {
                    rows: x_top,
                    at: top,
                };
                forward_range(factor.part(0..at, x0, 0), here, y0);
            },
            || {
                let keep = &mut Kept {
                    at: top,
                    values: later,
                };
                forward_range(factor.part(at..fork, x1, mid), keep, y1);
            },
        );
        let mut kept = later.iter();
        for s in at..fork {
            for &r in Supernode::of(symbolic, s).pattern(symbolic) {
                let r = r as usize;
                if r >= top {
                    x_top[r - top] += kept.next().expect("one value kept per row of the rest");
                }
            }
        }
        debug_assert!(kept.next().is_none());
        let none = &mut InPlace {
            rows: &mut [],
            at: n,
        };
        forward_range(factor.part(fork..ns, x_top, top), none, y0);
        backward_range(factor.part(fork..ns, x_top, top), (&[], n), y0);
    }
    let (x0, rest) = x.split_at_mut(mid);
    let (x1, x_top) = rest.split_at_mut(top - mid);
    let x_top = &*x_top;
    helper.join_once(
        || backward_range(factor.part(0..at, x0, 0), (x_top, top), y0),
        || backward_range(factor.part(at..fork, x1, mid), (x_top, top), y1),
    );
}

/// Where a forward part's updates of the rows from `at()` on go.
trait Later {
    fn at(&self) -> usize;
    fn add(&mut self, row: usize, v: f64);
}

/// Added into `rows` (row `at` first).
struct InPlace<'a> {
    rows: &'a mut [f64],
    at: usize,
}

impl Later for InPlace<'_> {
    #[inline(always)]
    fn at(&self) -> usize {
        self.at
    }

    #[inline(always)]
    fn add(&mut self, row: usize, v: f64) {
        self.rows[row - self.at] += v;
    }
}

/// Kept in the order they come, to be added later.
struct Kept<'a> {
    at: usize,
    values: &'a mut Vec<f64>,
}

impl Later for Kept<'_> {
    #[inline(always)]
    fn at(&self) -> usize {
        self.at
    }

    #[inline(always)]
    fn add(&mut self, _row: usize, v: f64) {
        self.values.push(v);
    }
}

/// The factor: faer's supernodal symbolic factor and the values.
#[derive(Clone, Copy)]
struct Factor<'a> {
    symbolic: &'a SymbolicSupernodalCholesky<Index>,
    l: &'a [f64],
}

impl<'a> Factor<'a> {
    /// The part of a solve that takes `supernodes`, whose columns `own` holds (row `own_at`
    /// first).
    fn part<'x>(
        self,
        supernodes: std::ops::Range<usize>,
        own: &'x mut [f64],
        own_at: usize,
    ) -> Part<'a, 'x> {
        Part {
            factor: self,
            supernodes,
            own,
            own_at,
        }
    }
}

/// A part of a solve: the supernodes it takes (forward in order, backward from the last),
/// and the part of `x` that holds their columns (`own`, row `own_at` first).
struct Part<'a, 'x> {
    factor: Factor<'a>,
    supernodes: std::ops::Range<usize>,
    own: &'x mut [f64],
    own_at: usize,
}

/// `L z = b` on a part whose rows below are its own, but for those from `later.at()` on.
fn forward_range(part: Part<'_, '_>, later: &mut impl Later, y: &mut Vec<f64>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[target_feature(enable = "avx")]
        fn avx(part: Part<'_, '_>, later: &mut impl Later, y: &mut Vec<f64>) {
            forward(part, later, y)
        }
        // SAFETY: the processor has AVX (just checked), all `avx` asks for.
        #[allow(unsafe_code)]
        return unsafe { avx(part, later, y) };
    }
    forward(part, later, y)
}

/// [`forward_range`] (no dot products: the same code with or without AVX).
#[inline(always)]
fn forward(part: Part<'_, '_>, later: &mut impl Later, y: &mut Vec<f64>) {
    let Part {
        factor: Factor { symbolic, l },
        supernodes,
        own,
        own_at,
    } = part;
    let later_at = later.at();
    for s in supernodes {
        let sn = Supernode::of(symbolic, s);
        let (w, f) = (sn.width, sn.width + sn.below);
        let (ls, pattern) = (sn.values(l), sn.pattern(symbolic));
        let b = sn.begin - own_at;
        y.clear();
        y.extend_from_slice(&own[b..b + w]);
        y.resize(f, 0.0);
        for k in 0..w {
            let col = &ls[k * f..(k + 1) * f];
            let yk = y[k] / col[k];
            y[k] = yk;
            axpy_neg(&mut y[k + 1..f], &col[k + 1..f], yk);
        }
        own[b..b + w].copy_from_slice(&y[..w]);
        for (&r, &v) in pattern.iter().zip(&y[w..f]) {
            let r = r as usize;
            if r < later_at {
                own[r - own_at] += v;
            } else {
                later.add(r, v);
            }
        }
    }
}

/// `Lᵀ x = z` on a part whose rows below are its own, but for those from `above.1` on,
/// which are read from `above.0`.
fn backward_range(part: Part<'_, '_>, above: (&[f64], usize), y: &mut Vec<f64>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[target_feature(enable = "avx")]
        fn avx(part: Part<'_, '_>, above: (&[f64], usize), y: &mut Vec<f64>) {
            backward::<true>(part, above, y)
        }
        // SAFETY: the processor has AVX (just checked), all `avx` asks for.
        #[allow(unsafe_code)]
        return unsafe { avx(part, above, y) };
    }
    backward::<false>(part, above, y)
}

/// [`backward_range`]; `AVX` only where the processor has it (its dot products use it).
#[inline(always)]
fn backward<const AVX: bool>(
    part: Part<'_, '_>,
    (above, above_at): (&[f64], usize),
    y: &mut Vec<f64>,
) {
    let Part {
        factor: Factor { symbolic, l },
        supernodes,
        own,
        own_at,
    } = part;
    for s in supernodes.rev() {
        let sn = Supernode::of(symbolic, s);
        let (w, f) = (sn.width, sn.width + sn.below);
        let (ls, pattern) = (sn.values(l), sn.pattern(symbolic));
        let b = sn.begin - own_at;
        y.clear();
        y.extend_from_slice(&own[b..b + w]);
        y.extend(pattern.iter().map(|&r| {
            let r = r as usize;
            if r < above_at {
                own[r - own_at]
            } else {
                above[r - above_at]
            }
        }));
        // The rows below first, the columns from the last and each from its end: the
        // memory read as one decreasing stream, which the processor prefetches (a new
        // stream at each supernode doubled the time); then the diagonal block, now in cache.
        for k in (0..w).rev() {
            let col = &ls[k * f..(k + 1) * f];
            y[k] -= dot::<AVX>(&col[w..f], &y[w..f]);
        }
        for k in (0..w).rev() {
            let col = &ls[k * f..(k + 1) * f];
            let d = dot::<AVX>(&col[k + 1..w], &y[k + 1..w]);
            y[k] = (y[k] - d) / col[k];
        }
        own[b..b + w].copy_from_slice(&y[..w]);
    }
}

/// `y −= a·x`, element by element.
#[inline(always)]
fn axpy_neg(y: &mut [f64], x: &[f64], a: f64) {
    for (y, &x) in y.iter_mut().zip(x) {
        *y -= x * a;
    }
}

/// `Σ a_i b_i`, the memory read from the end to the start: the `n mod 8` first elements
/// apart, the rest in two groups of four interleaved partial sums, added lane by lane, then
/// the four lanes in a fixed order: the same bits with or without AVX.
#[inline(always)]
fn dot<const AVX: bool>(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let head = n % 8;
    let t = lanes::<AVX>(&a[head..], &b[head..]);
    let mut tail = 0.0;
    for (&a, &b) in a[..head].iter().zip(&b[..head]).rev() {
        tail += a * b;
    }
    ((t[0] + t[2]) + (t[1] + t[3])) + tail
}

/// [`dot`]'s partial sums over `a` and `b`, both of a multiple of 8 elements.
#[inline(always)]
fn lanes<const AVX: bool>(a: &[f64], b: &[f64]) -> [f64; 4] {
    debug_assert!(a.len() == b.len() && a.len().is_multiple_of(8));
    #[cfg(target_arch = "x86_64")]
    if AVX {
        // SAFETY: `AVX` is true only where the processor has AVX ([`backward_range`] checks);
        // `a` and `b` hold the same multiple of 8 elements (asserted), all `dot_avx` reads.
        #[allow(unsafe_code)]
        return unsafe { dot_avx(a.as_ptr(), b.as_ptr(), a.len()) };
    }
    dot_lanes(a, b)
}

/// [`dot`]'s partial sums, lane by lane.
#[inline(always)]
fn dot_lanes(a: &[f64], b: &[f64]) -> [f64; 4] {
    let (mut s0, mut s1) = ([0.0f64; 4], [0.0f64; 4]);
    for (a, b) in a.chunks_exact(8).zip(b.chunks_exact(8)).rev() {
        for lane in 0..4 {
            s0[lane] += a[lane] * b[lane];
            s1[lane] += a[4 + lane] * b[4 + lane];
        }
    }
    let mut t = [0.0f64; 4];
    for lane in 0..4 {
        t[lane] = s0[lane] + s1[lane];
    }
    t
}

/// [`dot_lanes`] in two 4-lane registers (the same operations, the same bits): `body`
/// elements (a multiple of 8) from each of `a` and `b`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[allow(unsafe_code)]
unsafe fn dot_avx(a: *const f64, b: *const f64, body: usize) -> [f64; 4] {
    use std::arch::x86_64::{
        _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    };
    let (mut s0, mut s1) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    let mut k = body;
    while k > 0 {
        k -= 8;
        // SAFETY: `k + 8 <= body`, and the caller's `a` and `b` hold `body` elements.
        unsafe {
            s0 = _mm256_add_pd(
                s0,
                _mm256_mul_pd(_mm256_loadu_pd(a.add(k)), _mm256_loadu_pd(b.add(k))),
            );
            s1 = _mm256_add_pd(
                s1,
                _mm256_mul_pd(_mm256_loadu_pd(a.add(k + 4)), _mm256_loadu_pd(b.add(k + 4))),
            );
        }
    }
    let mut t = [0.0f64; 4];
    // SAFETY: `t` holds four lanes.
    unsafe { _mm256_storeu_pd(t.as_mut_ptr(), _mm256_add_pd(s0, s1)) };
    t
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::cholesky::llt::factor::LltRegularization;
    use faer::sparse::linalg::SupernodalThreshold;
    use faer::sparse::linalg::cholesky::{
        CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
        factorize_symbolic_cholesky,
    };
    use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
    use faer::{Conj, MatMut, Par, Side};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The lower triangle of `I + Σ w_e (e_a − e_b)(e_a − e_b)ᵀ` over the edges of a
    /// `k × k` grid with its diagonals (a contact network's kind of pattern), random weights.
    fn grid(k: usize, rng: &mut ChaCha8Rng) -> (Vec<u32>, Vec<u32>, Vec<f64>) {
        let n = k * k;
        let mut cols: Vec<Vec<(u32, f64)>> = (0..n).map(|c| vec![(c as u32, 1.0)]).collect();
        for i in 0..k {
            for j in 0..k {
                let a = i * k + j;
                for (di, dj) in [(0, 1), (1, 0), (1, 1), (1, usize::MAX)] {
                    let (i2, j2) = (i + di, j.wrapping_add(dj));
                    if i2 < k && j2 < k {
                        let b = i2 * k + j2;
                        let w = rng.random_range(0.01..100.0);
                        cols[a][0].1 += w;
                        cols[b][0].1 += w;
                        let (lo, hi) = (a.min(b), a.max(b));
                        cols[lo].push((hi as u32, -w));
                    }
                }
            }
        }
        compressed(cols)
    }

    /// `A x`, `A` symmetric given by its lower triangle in compressed columns (read both
    /// ways).
    pub(crate) fn symmetric_times(ptr: &[u32], idx: &[u32], val: &[f64], x: &[f64]) -> Vec<f64> {
        let mut ax = vec![0.0; x.len()];
        for c in 0..x.len() {
            for p in ptr[c] as usize..ptr[c + 1] as usize {
                let (r, v) = (idx[p] as usize, val[p]);
                ax[r] += v * x[c];
                if r != c {
                    ax[c] += v * x[r];
                }
            }
        }
        ax
    }

    /// Columns of `(row, value)` entries, in compressed columns (rows sorted).
    pub(crate) fn compressed(cols: Vec<Vec<(u32, f64)>>) -> (Vec<u32>, Vec<u32>, Vec<f64>) {
        let (mut ptr, mut idx, mut val) = (vec![0u32], Vec::new(), Vec::new());
        for mut c in cols {
            c.sort_by_key(|e| e.0);
            idx.extend(c.iter().map(|e| e.0));
            val.extend(c.iter().map(|e| e.1));
            ptr.push(idx.len() as u32);
        }
        (ptr, idx, val)
    }

    /// faer's supernodal symbolic factor of `pattern` (one triangle, `side`), forced
    /// supernodal, and its numeric factor of `a` (the lower triangle, the same pattern's
    /// matrix) by faer: none when faer refuses it.
    pub(crate) fn faer_supernodal(
        pattern: SymbolicSparseColMatRef<'_, u32>,
        side: Side,
        ordering: SymmetricOrdering<'_, u32>,
        a: SparseColMatRef<'_, u32, f64>,
    ) -> (SymbolicCholesky<u32>, Option<Vec<f64>>) {
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            side,
            ordering,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .unwrap();
        let mut l = vec![0.0; symbolic.len_val()];
        let mut mem = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        let ok = symbolic
            .factorize_numeric_llt(
                &mut l,
                a,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .is_ok();
        (symbolic, ok.then_some(l))
    }

    #[test]
    fn the_supernodal_solve_solves_what_faers_solves() {
        let mut rng = ChaCha8Rng::seed_from_u64(24);
        // (faer factorizes a 1 × 1 matrix simplicially whatever it is asked.)
        for k in [2, 3, 7, 30] {
            let n = k * k;
            let (ptr, idx, val) = grid(k, &mut rng);
            let pattern = SymbolicSparseColMatRef::new_checked(n, n, &ptr, None, &idx);
            let a = SparseColMatRef::new(pattern, &val);
            // AMD's ordering: supernodes of every width, rows below scattered.
            let (symbolic, l) = faer_supernodal(pattern, Side::Lower, SymmetricOrdering::Amd, a);
            let l = l.expect("positive definite");
            let SymbolicCholeskyRaw::Supernodal(s) = symbolic.raw() else {
                panic!("k = {k}: supernodal forced");
            };
            let mut mem = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
            let b: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            // faer's: permutes, solves, permutes back.
            let mut expected = b.clone();
            LltRef::new(&symbolic, &l).solve_in_place_with_conj(
                Conj::No,
                MatMut::from_column_major_slice_mut(&mut expected, n, 1),
                Par::Seq,
                MemStack::new(&mut mem),
            );
            // Ours, in the factor's order.
            let (fwd, _) = symbolic.perm().expect("AMD ordered").arrays();
            let mut x: Vec<f64> = fwd.iter().map(|&p| b[p as usize]).collect();
            let mut y = Vec::new();
            solve_in_place(s, &l, &mut x, &mut y);
            let mut got = vec![0.0; n];
            for (k, &p) in fwd.iter().enumerate() {
                got[p as usize] = x[k];
            }
            let scale = expected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (g, e) in got.iter().zip(&expected) {
                assert!(
                    (g - e).abs() <= 1e-12 * scale,
                    "k = {k}: {g} against faer's {e}"
                );
            }
            // And it solves the system.
            let ax = symmetric_times(&ptr, &idx, &val, &got);
            let big = val.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (r, (ax, b)) in ax.iter().zip(&b).enumerate() {
                assert!(
                    (ax - b).abs() <= 1e-11 * big * scale,
                    "k = {k}, row {r}: {ax} ≠ {b}"
                );
            }
        }
    }

    #[test]
    fn the_dot_product_gives_the_same_bits_with_and_without_avx() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let avx = cfg!(target_arch = "x86_64") && {
            #[cfg(target_arch = "x86_64")]
            let has = std::arch::is_x86_feature_detected!("avx");
            #[cfg(not(target_arch = "x86_64"))]
            let has = false;
            has
        };
        for n in 0..70 {
            let a: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f64> = (0..n).map(|_| rng.random_range(-1e3..1e3)).collect();
            let portable = dot::<false>(&a, &b);
            let naive: f64 = a.iter().zip(&b).map(|(a, b)| a * b).sum();
            let size: f64 = a.iter().zip(&b).map(|(a, b)| (a * b).abs()).sum();
            assert!((portable - naive).abs() <= 1e-14 * size.max(1.0), "n = {n}");
            if avx {
                assert_eq!(dot::<true>(&a, &b).to_bits(), portable.to_bits(), "n = {n}");
            }
        }
    }
}
