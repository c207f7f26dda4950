//! Dense kernels for the TPS solve: a cache-blocked Cholesky factorisation and the inverse of its factor, with
//! their O(n³) work in matrix products.
//!
//! # The formulas
//!
//! [`cholesky_in_place`] is the right-looking blocked algorithm (Golub & Van Loan, *Matrix Computations*, 4th ed.,
//! §4.2.9; LAPACK `dpotrf`). For a symmetric positive definite A, split off a panel of `block` columns:
//!
//! ```text
//! A = [A₁₁ A₁₂]    L₁₁ L₁₁ᵀ = A₁₁,   L₂₁ = A₂₁ L₁₁⁻ᵀ,   A₂₂ ← A₂₂ − L₂₁ L₂₁ᵀ,
//!     [A₂₁ A₂₂]
//! ```
//!
//! and go on with the updated A₂₂. The b×b block L₁₁ is factored column by column (`dpotf2`), L₂₁ is the product of
//! A₂₁ with the transposed inverse of L₁₁ (b³/3 flops for the inverse, then a product in column blocks, where
//! `dtrsm` would substitute), and the trailing update, where the n³/3 flops are, is a product of the panel with its
//! transpose (`dsyrk`), done in column blocks of its lower triangle. Every product is nalgebra's `gemm` (the
//! `matrixmultiply` kernels). A pivot that is not
//! positive (or not finite) stops the factorisation, as in nalgebra's `Cholesky::new`.
//!
//! [`lower_triangular_inverse`] solves L X = I by block columns: with Dᵢ = Lᵢᵢ⁻¹ (one small substitution per
//! diagonal block), block column j of X is
//!
//! ```text
//! Xⱼⱼ = Dⱼ,     Xᵢⱼ = −Dᵢ Σ_{j ≤ k < i} Lᵢₖ Xₖⱼ   (i > j),
//! ```
//!
//! two products per block; the block columns are independent, n³/3 flops in all.
//!
//! # Parallelism
//!
//! Each kernel takes a [`Parallelism`]: with [`Parallelism::Rayon`] the column blocks of the panel, of the trailing
//! update and of X are split over rayon's pool; [`Parallelism::Sequential`] stays on the calling thread. The column blocks are the
//! same either way, so both give the same bits.

use nalgebra::{DMatrix, DMatrixView, DMatrixViewMut, Dyn, Matrix, Storage};
use rayon::prelude::*;

use crate::Parallelism;

/// Columns per block: the panel's 64 columns stay in L2 while it is factored and give the trailing products an inner
/// dimension long enough for `matrixmultiply` (the leave-one-out at N = 1000 on a 2-core VM: 48 and 64 cost the same
/// CPU time, 96 and 128 some 5–10% more).
pub const BLOCK: usize = 64;

/// Runs `f` on every (index, chunk) of `data` cut into chunks of `chunk_len` elements (the last may be shorter): on the
/// calling thread in order, or on rayon's pool one chunk per task.
pub(crate) fn for_each_chunk<F>(data: &mut [f64], chunk_len: usize, parallelism: Parallelism, f: F)
where
    F: Fn((usize, &mut [f64])) + Sync + Send,
{
    match parallelism {
        Parallelism::Sequential => data.chunks_mut(chunk_len).enumerate().for_each(f),
        Parallelism::Rayon => data.par_chunks_mut(chunk_len).enumerate().with_max_len(1).for_each(f),
    }
}

/// Tasks per panel of the Cholesky factorisation (its columns split evenly), enough for 2 to 4 threads.
const PANEL_TASKS: usize = 4;

/// The Cholesky factorisation met a pivot that is not positive: the matrix is not (numerically) positive definite.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("not positive definite: pivot {pivot:e} at column {column}")]
pub struct NotPositiveDefinite {
    /// 0-based column of the first failed pivot.
    pub column: usize,
    /// The value under the square root there.
    pub pivot: f64,
}

/// A ← L with A = L Lᵀ for symmetric positive definite A (only its lower triangle is read), in blocks of `block`
/// columns; the strict upper triangle is zeroed. On error A is partly overwritten.
///
/// # Panics
/// When A is not square or `block` is 0.
pub fn cholesky_in_place(
    a: &mut DMatrix<f64>,
    block: usize,
    parallelism: Parallelism,
) -> Result<(), NotPositiveDefinite> {
    let n = a.nrows();
    assert_eq!(n, a.ncols(), "cholesky_in_place: the matrix is not square");
    assert!(block > 0, "cholesky_in_place: block must be positive");
    let data = a.as_mut_slice();
    // Up to two blocks, the inverse of L₁₁ would cost more than the substitution it replaces: column by column.
    let block = if n <= 2 * block { n.max(1) } else { block };
    for k0 in (0..n).step_by(block) {
        let t0 = (k0 + block).min(n);
        let (kb, r) = (t0 - k0, n - t0);
        factor_diagonal_block(data, n, k0, t0)?;
        if r == 0 {
            break;
        }
        let (left, right) = data.split_at_mut(t0 * n);
        // L₂₁ = A₂₁ L₁₁⁻ᵀ, by columns of the panel, from a copy of A₂₁ and the small inverse of L₁₁.
        let panel = &mut left[k0 * n..];
        let l11_inv_t = small_lower_inverse(&DMatrixView::from_slice_with_strides(&panel[k0..], kb, kb, 1, n))
            .ok_or(NotPositiveDefinite { column: k0, pivot: 0.0 })?
            .transpose();
        let a21 = DMatrixView::from_slice_with_strides(&panel[t0..], r, kb, 1, n).clone_owned();
        let panel_width = kb.div_ceil(PANEL_TASKS);
        for_each_chunk(panel, panel_width * n, parallelism, |(c, columns)| {
            let (j0, width) = (c * panel_width, columns.len() / n);
            let mut target = DMatrixViewMut::from_slice_with_strides_mut(&mut columns[t0..], r, width, 1, n);
            target.gemm(1.0, &a21, &l11_inv_t.columns(j0, width), 0.0);
        });
        // A₂₂ ← A₂₂ − L₂₁ L₂₁ᵀ on the lower triangle, in column blocks of `block` (the panel is left of `right`).
        let l21 = DMatrixView::from_slice_with_strides(&left[k0 * n + t0..], r, kb, 1, n);
        let l21_t = DMatrixView::from_slice_with_strides(&left[k0 * n + t0..], kb, r, n, 1);
        for_each_chunk(right, block * n, parallelism, |(c, columns)| {
            let (j0, width) = (c * block, columns.len() / n);
            let rows = r - j0;
            let mut target = DMatrixViewMut::from_slice_with_strides_mut(&mut columns[t0 + j0..], rows, width, 1, n);
            target.gemm(-1.0, &l21.rows(j0, rows), &l21_t.columns(j0, width), 1.0);
        });
    }
    for j in 1..n {
        a.view_mut((0, j), (j, 1)).fill(0.0);
    }
    Ok(())
}

/// Factors the diagonal block k0..t0 of the column-major n×n `data`, which already holds the updates of every earlier
/// panel: column j minus its products with the block's earlier columns, then scaled by the square root of its pivot.
fn factor_diagonal_block(data: &mut [f64], n: usize, k0: usize, t0: usize) -> Result<(), NotPositiveDefinite> {
    for j in k0..t0 {
        let (before, after) = data.split_at_mut(j * n);
        let column = &mut after[j..t0];
        for p in k0..j {
            let earlier = &before[p * n + j..p * n + t0];
            let l_jp = earlier[0];
            for (x, l) in column.iter_mut().zip(earlier) {
                *x -= l_jp * l;
            }
        }
        let pivot = column[0];
        if !(pivot > 0.0 && pivot.is_finite()) {
            return Err(NotPositiveDefinite { column: j, pivot });
        }
        let l_jj = pivot.sqrt();
        column[0] = l_jj;
        for x in &mut column[1..] {
            *x /= l_jj;
        }
    }
    Ok(())
}

/// L⁻¹ of a small lower-triangular block by column-oriented substitution on the columns of I, skipping the zeros
/// above each column's diagonal (b³/6 multiply-adds); `None` when a diagonal entry is zero.
fn small_lower_inverse<S: Storage<f64, Dyn, Dyn>>(l: &Matrix<f64, Dyn, Dyn, S>) -> Option<DMatrix<f64>> {
    let b = l.nrows();
    let l = l.clone_owned();
    let mut x = DMatrix::<f64>::zeros(b, b);
    for (c, column) in x.as_mut_slice().chunks_exact_mut(b.max(1)).enumerate() {
        column[c] = 1.0;
        for (j, l_j) in l.as_slice().chunks_exact(b).enumerate().skip(c) {
            if l_j[j] == 0.0 {
                return None;
            }
            let x_j = column[j] / l_j[j];
            column[j] = x_j;
            for (x_i, l_ij) in column[j + 1..].iter_mut().zip(&l_j[j + 1..]) {
                *x_i -= x_j * l_ij;
            }
        }
    }
    Some(x)
}

/// X = L⁻¹ for lower-triangular L (only its lower triangle is read), by block columns of `block`; the strict upper
/// triangle of X is zero. `None` when a diagonal entry of L is zero.
///
/// # Panics
/// When L is not square or `block` is 0.
#[must_use]
pub fn lower_triangular_inverse(l: &DMatrix<f64>, block: usize, parallelism: Parallelism) -> Option<DMatrix<f64>> {
    let n = l.nrows();
    assert_eq!(n, l.ncols(), "lower_triangular_inverse: the matrix is not square");
    assert!(block > 0, "lower_triangular_inverse: block must be positive");
    let span = |i: usize| (i * block, block.min(n - i * block));
    let diagonal_inverse = |i: usize| {
        let (i0, ib) = span(i);
        small_lower_inverse(&l.view((i0, i0), (ib, ib)))
    };
    let blocks = n.div_ceil(block);
    let d: Vec<DMatrix<f64>> = match parallelism {
        Parallelism::Sequential => (0..blocks).map(diagonal_inverse).collect::<Option<_>>()?,
        Parallelism::Rayon => (0..blocks).into_par_iter().map(diagonal_inverse).collect::<Option<_>>()?,
    };
    let mut x = DMatrix::<f64>::zeros(n, n);
    let block_column = |(j, columns): (usize, &mut [f64])| {
        let (j0, jb) = span(j);
        let mut x_j = DMatrixViewMut::from_slice(columns, n, jb);
        x_j.view_mut((j0, 0), (jb, jb)).copy_from(&d[j]);
        let mut sum = DMatrix::<f64>::zeros(block, jb);
        for (i, d_i) in d.iter().enumerate().skip(j + 1) {
            let (i0, ib) = span(i);
            let mut s = sum.rows_mut(0, ib);
            s.gemm(1.0, &l.view((i0, j0), (ib, i0 - j0)), &x_j.view((j0, 0), (i0 - j0, jb)), 0.0);
            x_j.view_mut((i0, 0), (ib, jb)).gemm(-1.0, d_i, &s, 0.0);
        }
    };
    // The first block columns hold most of the work: one task each, so that rayon balances them.
    for_each_chunk(x.as_mut_slice(), block * n, parallelism, block_column);
    Some(x)
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// A random SPD matrix B Bᵀ + n·I with entries of B in [−1, 1].
    fn random_spd(n: usize, seed: u64) -> DMatrix<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let b = DMatrix::<f64>::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
        &b * b.transpose() + DMatrix::identity(n, n) * n as f64
    }

    /// Backward-error bound for a Cholesky factor of A: c·n·ε·‖A‖ (Higham, *Accuracy and Stability*, Thm 10.3).
    fn factor_tol(a: &DMatrix<f64>) -> f64 {
        8.0 * a.nrows() as f64 * f64::EPSILON * a.norm()
    }

    #[test]
    fn blocked_cholesky_reproduces_a_and_nalgebras_factor() {
        // Sizes below, at and above the block, and not multiples of it; both parallelisms give the same bits.
        for (n, block) in [(1, 4), (7, 4), (8, 4), (33, 8), (130, 16), (200, BLOCK), (257, BLOCK)] {
            let a = random_spd(n, n as u64);
            let mut l = a.clone();
            cholesky_in_place(&mut l, block, Parallelism::Rayon).expect("SPD");
            let mut l_seq = a.clone();
            cholesky_in_place(&mut l_seq, block, Parallelism::Sequential).expect("SPD");
            assert_eq!(l, l_seq, "n = {n}: Rayon and Sequential differ");
            assert_eq!(l, l.lower_triangle(), "n = {n}: the strict upper triangle is not zero");
            let residual = (&a - &l * l.transpose()).norm();
            assert!(residual <= factor_tol(&a), "n = {n}: ‖A − LLᵀ‖ = {residual:e} > {:e}", factor_tol(&a));
            let reference = a.clone().cholesky().expect("SPD").unpack();
            // cond(A) ≤ 7/3 here (A = BBᵀ + nI with ‖BBᵀ‖ ≈ 4n/3), so the two factors agree to a few ulps per entry.
            let diff = (&l - &reference).norm() / reference.norm();
            assert!(diff <= 1e-13, "n = {n}: differs from nalgebra's by {diff:e} (relative)");
        }
    }

    #[test]
    fn blocked_cholesky_solves_like_nalgebra() {
        let (n, block) = (300, 32);
        let a = random_spd(n, 5);
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let y = DMatrix::<f64>::from_fn(n, 3, |_, _| rng.random_range(-10.0..10.0));
        let mut l = a.clone();
        cholesky_in_place(&mut l, block, Parallelism::Rayon).expect("SPD");
        let mut x = y.clone();
        nalgebra::Cholesky::pack_dirty(l).solve_mut(&mut x);
        let reference = a.clone().cholesky().expect("SPD").solve(&y);
        let rel = (&x - &reference).norm() / reference.norm();
        assert!(rel <= 1e-12, "solutions differ by {rel:e} (relative)");
        let backward = (&a * &x - &y).norm() / (a.norm() * x.norm());
        assert!(backward <= 8.0 * n as f64 * f64::EPSILON, "backward error {backward:e}");
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_names_its_pivot() {
        // The pivot of column 5 (in the second panel) becomes −1 after the first panel's update.
        let mut a = DMatrix::<f64>::identity(9, 9);
        a[(5, 5)] = -1.0;
        assert_eq!(
            cholesky_in_place(&mut a.clone(), 4, Parallelism::Sequential),
            Err(NotPositiveDefinite { column: 5, pivot: -1.0 })
        );
        a[(5, 5)] = f64::NAN;
        assert_eq!(cholesky_in_place(&mut a, 4, Parallelism::Rayon).map_err(|e| e.column), Err(5));
        // Indefinite through an off-diagonal entry: [[1, 2], [2, 1]] has eigenvalues 3 and −1.
        let mut b = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        assert_eq!(cholesky_in_place(&mut b, 1, Parallelism::Sequential).map_err(|e| e.column), Err(1));
    }

    #[test]
    fn triangular_inverse_times_l_is_the_identity() {
        for (n, block) in [(1, 4), (9, 4), (64, 16), (250, BLOCK), (301, 32)] {
            let mut l = random_spd(n, 100 + n as u64);
            cholesky_in_place(&mut l, block, Parallelism::Sequential).expect("SPD");
            let x = lower_triangular_inverse(&l, block, Parallelism::Rayon).expect("invertible");
            let x_seq = lower_triangular_inverse(&l, block, Parallelism::Sequential).expect("invertible");
            assert_eq!(x, x_seq, "n = {n}: Rayon and Sequential differ");
            assert_eq!(x, x.lower_triangle(), "n = {n}: X is not lower triangular");
            let residual = (&x * &l - DMatrix::identity(n, n)).norm();
            // ‖XL − I‖ ≤ c·n·ε·cond(L) (Higham §8.3), and cond(L) = √cond(A) ≤ √(7/3) here.
            assert!(residual <= 16.0 * n as f64 * f64::EPSILON, "n = {n}: ‖XL − I‖ = {residual:e}");
            let reference = l.solve_lower_triangular(&DMatrix::identity(n, n)).expect("invertible");
            let diff = (&x - &reference).norm() / reference.norm();
            assert!(diff <= 1e-13, "n = {n}: differs from substitution by {diff:e} (relative)");
        }
    }

    #[test]
    fn a_zero_on_the_diagonal_has_no_inverse() {
        let mut l = DMatrix::<f64>::identity(10, 10);
        l[(7, 7)] = 0.0;
        assert_eq!(lower_triangular_inverse(&l, 4, Parallelism::Sequential), None);
    }
}
