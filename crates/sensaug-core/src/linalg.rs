//! Small allocation-free linear-algebra helpers on fixed-size matrices.
//!
//! nalgebra's own LU needs `Const<N>: DimMin<Const<N>>`, which generic code
//! over `const N: usize` cannot name without typenum where-clauses, so the
//! one factorisation the Riccati solvers need is written out here.

use nalgebra::{Cholesky, Complex, SMatrix};

/// LU factorisation with partial (row) pivoting, `P A = L U`.
///
/// `L` (unit lower triangle, diagonal not stored) and `U` share one matrix.
/// Built once, then used for any number of right-hand sides. Runs in
/// `O(N^3)`; never allocates, never panics.
#[derive(Clone, Copy, Debug)]
pub struct Lu<const N: usize> {
    lu: SMatrix<f64, N, N>,
    /// `perm[i]` is the row of the original matrix stored in row `i`.
    perm: [usize; N],
}

impl<const N: usize> Lu<N> {
    /// Factorises `a`. Returns `None` when a pivot is exactly zero or
    /// non-finite (singular matrix or bad input); callers map that to their
    /// own error.
    pub fn new(a: &SMatrix<f64, N, N>) -> Option<Self> {
        let mut lu = *a;
        let mut perm = [0usize; N];
        for (i, p) in perm.iter_mut().enumerate() {
            *p = i;
        }
        for k in 0..N {
            // Pivot: the largest |entry| in column k at or below the diagonal.
            let mut p = k;
            let mut best = lu[(k, k)].abs();
            for i in (k + 1)..N {
                let v = lu[(i, k)].abs();
                if v > best {
                    best = v;
                    p = i;
                }
            }
            if best == 0.0 || !best.is_finite() {
                return None;
            }
            if p != k {
                lu.swap_rows(p, k);
                perm.swap(p, k);
            }
            let pivot = lu[(k, k)];
            for i in (k + 1)..N {
                // l_ik = a_ik / u_kk ; a_ij -= l_ik u_kj
                let l = lu[(i, k)] / pivot;
                lu[(i, k)] = l;
                for j in (k + 1)..N {
                    lu[(i, j)] -= l * lu[(k, j)];
                }
            }
        }
        Some(Self { lu, perm })
    }

    /// Solves `A X = B` for `X` by forward then back substitution.
    pub fn solve<const K: usize>(&self, b: &SMatrix<f64, N, K>) -> SMatrix<f64, N, K> {
        let mut x = SMatrix::<f64, N, K>::zeros();
        for c in 0..K {
            // Forward: L y = P b.
            for i in 0..N {
                let mut s = b[(self.perm[i], c)];
                for j in 0..i {
                    s -= self.lu[(i, j)] * x[(j, c)];
                }
                x[(i, c)] = s;
            }
            // Back: U x = y.
            for i in (0..N).rev() {
                let mut s = x[(i, c)];
                for j in (i + 1)..N {
                    s -= self.lu[(i, j)] * x[(j, c)];
                }
                x[(i, c)] = s / self.lu[(i, i)];
            }
        }
        x
    }
}

/// `(M + M') / 2`: removes the rounding asymmetry of a symmetric iterate.
pub fn symmetrize<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    (m + m.transpose()) * 0.5
}

/// A weight or covariance `W` counts as symmetric when
/// `||W - W'||_F <= SYMMETRY_TOL ||W||_F`.
pub const SYMMETRY_TOL: f64 = 1e-10;

/// Definiteness margin, relative to `||W||_F`: a symmetric `W` counts as
/// positive semidefinite when `lambda_min(W) > -DEFINITENESS_TOL ||W||_F`
/// and as positive definite when `lambda_min(W) > DEFINITENESS_TOL ||W||_F`
/// (both tested with a Cholesky factorisation of the shifted matrix, no
/// eigenvalues).
pub const DEFINITENESS_TOL: f64 = 1e-10;

/// `||W - W'||_F <= SYMMETRY_TOL ||W||_F`.
pub fn is_symmetric<const K: usize>(w: &SMatrix<f64, K, K>) -> bool {
    (w - w.transpose()).norm() <= SYMMETRY_TOL * w.norm()
}

/// `lambda_min(W) > -DEFINITENESS_TOL ||W||_F` for a symmetric `W`: the
/// Cholesky factorisation of `W + (DEFINITENESS_TOL ||W||_F) I` exists
/// (`f64::MIN_POSITIVE` more keeps `W = 0`, which is PSD, factorisable).
pub fn is_positive_semidefinite<const K: usize>(w: &SMatrix<f64, K, K>) -> bool {
    let shift = DEFINITENESS_TOL * w.norm() + f64::MIN_POSITIVE;
    Cholesky::new(w + SMatrix::<f64, K, K>::identity() * shift).is_some()
}

/// `lambda_min(W) > DEFINITENESS_TOL ||W||_F` for a symmetric `W`: the
/// Cholesky factorisation of `W - (DEFINITENESS_TOL ||W||_F) I` exists.
pub fn is_positive_definite<const K: usize>(w: &SMatrix<f64, K, K>) -> bool {
    let shift = DEFINITENESS_TOL * w.norm();
    Cholesky::new(w - SMatrix::<f64, K, K>::identity() * shift).is_some()
}

/// True when every entry is finite (no NaN, no infinity).
#[inline]
pub fn all_finite<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> bool {
    // A value is NaN or infinite exactly when its 11 exponent bits are all
    // set; adding 1 to that field then carries into the sign bit. Integer
    // and/add/or over the contiguous slice, no early exit: the compiler
    // vectorises it (the UKF runs this a dozen times per tick, and the
    // answer is almost always yes).
    const EXPONENT: u64 = 0x7ff0_0000_0000_0000;
    const EXPONENT_ONE: u64 = 0x0010_0000_0000_0000;
    let bad = m.as_slice().iter().fold(0u64, |acc, v| {
        acc | ((v.to_bits() & EXPONENT) + EXPONENT_ONE)
    });
    bad >> 63 == 0
}

/// True when the Hermitian matrix `h` is positive definite: every pivot of
/// its `L D L^H` elimination (no pivoting) has a real part `> 0`.
///
/// Written out because nalgebra's complex `Cholesky::new` takes the complex
/// square root of a negative pivot instead of failing. Only the lower
/// triangle and the real part of the diagonal are trusted.
pub fn hermitian_positive_definite<const N: usize>(h: &SMatrix<Complex<f64>, N, N>) -> bool {
    let mut a = *h;
    for k in 0..N {
        let d = a[(k, k)].re;
        if d.is_nan() || d <= 0.0 {
            return false;
        }
        // Schur complement: a_ij -= a_ik conj(a_jk) / d  for i, j > k.
        for j in (k + 1)..N {
            let ajk = a[(j, k)].conj();
            for i in j..N {
                let v = a[(i, k)] * ajk / d;
                a[(i, j)] -= v;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::all_finite;
    use nalgebra::SMatrix;

    #[test]
    fn all_finite_refuses_exactly_nan_and_infinities() {
        let finite = [
            0.0,
            -0.0,
            1.0,
            -1.5e-300,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            f64::MIN_POSITIVE / 4.0,
        ];
        let bad = [f64::NAN, -f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
        let m = SMatrix::<f64, 2, 4>::from_row_slice(&finite);
        assert!(all_finite(&m));
        for b in bad {
            for k in 0..8 {
                let mut m = m;
                m[k] = b;
                assert!(!all_finite(&m), "{b} at {k} passed");
            }
        }
    }
}
