//! Small dense linear algebra on `[[f64; N]; N]`: Cholesky factorisation and the symmetric
//! Jacobi eigen-decomposition. Fixed sizes, no allocation, bounded iteration counts.

/// Lower-triangular Cholesky factor `L` of a symmetric positive-definite `a = L Lᵀ`.
///
/// Returns `None` when a pivot is not positive relative to `rel_tol × max diagonal`
/// (singular or indefinite within the precision of the data).
pub(crate) fn cholesky<const N: usize>(a: &[[f64; N]; N], rel_tol: f64) -> Option<[[f64; N]; N]> {
    let scale = (0..N).fold(0.0_f64, |m, i| m.max(a[i][i].abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let mut l = [[0.0; N]; N];
    for j in 0..N {
        let mut d = a[j][j];
        for k in 0..j {
            d -= l[j][k] * l[j][k];
        }
        if !(d > rel_tol * scale) {
            return None;
        }
        let d = libm::sqrt(d);
        l[j][j] = d;
        for i in j + 1..N {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / d;
        }
    }
    Some(l)
}

/// Solves `L Lᵀ x = b` for a Cholesky factor `L`.
pub(crate) fn cholesky_solve<const N: usize>(l: &[[f64; N]; N], b: &[f64; N]) -> [f64; N] {
    let mut y = [0.0; N];
    for i in 0..N {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; N];
    for i in (0..N).rev() {
        let mut s = y[i];
        for k in i + 1..N {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// Inverse of `L Lᵀ` from its Cholesky factor.
pub(crate) fn cholesky_inverse<const N: usize>(l: &[[f64; N]; N]) -> [[f64; N]; N] {
    let mut inv = [[0.0; N]; N];
    for j in 0..N {
        let mut e = [0.0; N];
        e[j] = 1.0;
        let col = cholesky_solve(l, &e);
        for i in 0..N {
            inv[i][j] = col[i];
        }
    }
    inv
}

/// Eigenvalues (ascending) and unit eigenvectors (columns, same order) of a symmetric matrix,
/// by cyclic Jacobi rotations (at most 50 sweeps; converges quadratically).
pub(crate) fn sym_eigen<const N: usize>(a: &[[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut m = *a;
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let mut off = 0.0;
        let mut diag = 0.0;
        for i in 0..N {
            diag += m[i][i] * m[i][i];
            for j in i + 1..N {
                off += m[i][j] * m[i][j];
            }
        }
        if off <= 1e-30 * diag || off == 0.0 {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                if m[p][q] == 0.0 {
                    continue;
                }
                let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
                let t = theta.signum() / (theta.abs() + libm::sqrt(theta * theta + 1.0));
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / libm::sqrt(t * t + 1.0);
                let s = t * c;
                for k in 0..N {
                    let mkp = m[k][p];
                    let mkq = m[k][q];
                    m[k][p] = c * mkp - s * mkq;
                    m[k][q] = s * mkp + c * mkq;
                }
                for k in 0..N {
                    let mpk = m[p][k];
                    let mqk = m[q][k];
                    m[p][k] = c * mpk - s * mqk;
                    m[q][k] = s * mpk + c * mqk;
                }
                for row in v.iter_mut() {
                    let vkp = row[p];
                    let vkq = row[q];
                    row[p] = c * vkp - s * vkq;
                    row[q] = s * vkp + c * vkq;
                }
            }
        }
    }
    // Sort ascending (selection sort: N ≤ 9).
    let mut vals = [0.0; N];
    for (i, val) in vals.iter_mut().enumerate() {
        *val = m[i][i];
    }
    for i in 0..N {
        let mut best = i;
        for j in i + 1..N {
            if vals[j] < vals[best] {
                best = j;
            }
        }
        if best != i {
            vals.swap(i, best);
            for row in v.iter_mut() {
                row.swap(i, best);
            }
        }
    }
    (vals, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_spd_system() {
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let l = cholesky(&a, 1e-12).unwrap();
        let x = cholesky_solve(&l, &[1.0, 2.0, 3.0]);
        for i in 0..3 {
            let r: f64 = (0..3).map(|j| a[i][j] * x[j]).sum();
            assert!((r - [1.0, 2.0, 3.0][i]).abs() < 1e-12);
        }
        let inv = cholesky_inverse(&l);
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| a[i][k] * inv[k][j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn cholesky_rejects_singular_and_indefinite() {
        assert!(cholesky(&[[1.0, 1.0], [1.0, 1.0]], 1e-12).is_none());
        assert!(cholesky(&[[1.0, 2.0], [2.0, 1.0]], 1e-12).is_none());
        assert!(cholesky(&[[0.0, 0.0], [0.0, 0.0]], 1e-12).is_none());
    }

    #[test]
    fn jacobi_finds_eigenpairs() {
        let a = [[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]];
        let (vals, vecs) = sym_eigen(&a);
        assert!((vals[0] - 1.0).abs() < 1e-12 && (vals[1] - 3.0).abs() < 1e-12);
        assert!((vals[2] - 5.0).abs() < 1e-12);
        for k in 0..3 {
            for i in 0..3 {
                let av: f64 = (0..3).map(|j| a[i][j] * vecs[j][k]).sum();
                assert!((av - vals[k] * vecs[i][k]).abs() < 1e-12);
            }
        }
    }
}
