//! Small dense matrices of fixed size, for the Kalman filter's covariance (15×15 at most): plain
//! arrays on the stack, rows first. A filter step is a few thousand multiplications; no library needed.

use std::ops::{Add, Mul, Sub};

/// An `R × C` matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matrix<const R: usize, const C: usize>(pub [[f64; C]; R]);

impl<const R: usize, const C: usize> Matrix<R, C> {
    /// All zeros.
    pub fn zeros() -> Self {
        Matrix([[0.0; C]; R])
    }

    /// The transpose.
    pub fn transpose(&self) -> Matrix<C, R> {
        let mut out = Matrix::<C, R>::zeros();
        for (r, row) in self.0.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                out.0[c][r] = *value;
            }
        }
        out
    }

    /// Copies `block` in with its top-left corner at (`row`, `column`).
    pub fn set_block<const BR: usize, const BC: usize>(
        &mut self,
        row: usize,
        column: usize,
        block: &Matrix<BR, BC>,
    ) {
        for (r, values) in block.0.iter().enumerate() {
            self.0[row + r][column..column + BC].copy_from_slice(values);
        }
    }

    /// The `BR × BC` block whose top-left corner is (`row`, `column`).
    pub fn block<const BR: usize, const BC: usize>(&self, row: usize, column: usize) -> Matrix<BR, BC> {
        let mut out = Matrix::<BR, BC>::zeros();
        for (r, values) in out.0.iter_mut().enumerate() {
            values.copy_from_slice(&self.0[row + r][column..column + BC]);
        }
        out
    }

    /// Whether every entry is a finite number.
    pub fn is_finite(&self) -> bool {
        self.0.iter().flatten().all(|v| v.is_finite())
    }
}

impl<const N: usize> Matrix<N, N> {
    /// The identity.
    pub fn identity() -> Self {
        let mut out = Self::zeros();
        for i in 0..N {
            out.0[i][i] = 1.0;
        }
        out
    }

    /// A diagonal matrix.
    pub fn diagonal(values: [f64; N]) -> Self {
        let mut out = Self::zeros();
        for (i, value) in values.into_iter().enumerate() {
            out.0[i][i] = value;
        }
        out
    }

    /// `(M + Mᵀ) / 2`: keeps a covariance symmetric against rounding.
    #[must_use]
    pub fn symmetrised(&self) -> Self {
        let mut out = *self;
        for r in 0..N {
            for c in r + 1..N {
                let mean = 0.5 * (self.0[r][c] + self.0[c][r]);
                out.0[r][c] = mean;
                out.0[c][r] = mean;
            }
        }
        out
    }
}

impl<const R: usize, const K: usize, const C: usize> Mul<&Matrix<K, C>> for &Matrix<R, K> {
    type Output = Matrix<R, C>;

    fn mul(self, other: &Matrix<K, C>) -> Matrix<R, C> {
        let mut out = Matrix::<R, C>::zeros();
        for (r, row) in self.0.iter().enumerate() {
            for (k, a) in row.iter().enumerate() {
                if *a == 0.0 {
                    // Transition matrices are mostly zeros.
                    continue;
                }
                for (value, b) in out.0[r].iter_mut().zip(&other.0[k]) {
                    *value += a * b;
                }
            }
        }
        out
    }
}

impl<const R: usize, const C: usize> Add for Matrix<R, C> {
    type Output = Self;

    fn add(mut self, other: Self) -> Self {
        for (row, other) in self.0.iter_mut().zip(&other.0) {
            for (a, b) in row.iter_mut().zip(other) {
                *a += b;
            }
        }
        self
    }
}

impl<const R: usize, const C: usize> Sub for Matrix<R, C> {
    type Output = Self;

    fn sub(mut self, other: Self) -> Self {
        for (row, other) in self.0.iter_mut().zip(&other.0) {
            for (a, b) in row.iter_mut().zip(other) {
                *a -= b;
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::Matrix;

    #[test]
    fn products_blocks_and_transposes_agree_with_hand_results() {
        let a = Matrix([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]);
        let b = Matrix([[1.0, 0.0, 2.0], [0.0, 1.0, 3.0]]);
        assert_eq!((&a * &b).0, [[1.0, 2.0, 8.0], [3.0, 4.0, 18.0], [5.0, 6.0, 28.0]]);
        assert_eq!(a.transpose().0, [[1.0, 3.0, 5.0], [2.0, 4.0, 6.0]]);
        let mut big = Matrix::<4, 4>::identity();
        big.set_block(1, 2, &Matrix([[7.0, 8.0]]));
        assert_eq!(big.block::<1, 2>(1, 2).0, [[7.0, 8.0]]);
        assert_eq!((&Matrix::<3, 3>::identity() * &a).0, a.0);
    }
}
