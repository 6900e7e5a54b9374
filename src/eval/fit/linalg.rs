//! Small dense least squares for the cost model's fits (a handful of unknowns): weighted ridge regression through
//! the normal equations, and a non-negative variant by active set.

/// Solves `min sum_i w_i (x_i . beta - y_i)^2 + sum_j ridge_j beta_j^2` by the normal equations and Gaussian
/// elimination with partial pivoting. `None` when the system is singular or the input is inconsistent.
pub fn weighted_ridge(rows: &[Vec<f64>], y: &[f64], w: &[f64], ridge: &[f64]) -> Option<Vec<f64>> {
    let p = ridge.len();
    if rows.len() != y.len() || rows.len() != w.len() || rows.iter().any(|r| r.len() != p) || p == 0 {
        return None;
    }
    let mut a = vec![vec![0.0f64; p + 1]; p];
    for ((r, &yi), &wi) in rows.iter().zip(y).zip(w) {
        for j in 0..p {
            for k in 0..p {
                a[j][k] += wi * r[j] * r[k];
            }
            a[j][p] += wi * r[j] * yi;
        }
    }
    for (j, &l) in ridge.iter().enumerate() {
        a[j][j] += l;
    }
    solve(a)
}

/// Gaussian elimination on an augmented `p x (p + 1)` matrix.
fn solve(mut a: Vec<Vec<f64>>) -> Option<Vec<f64>> {
    let p = a.len();
    let scale = a.iter().flat_map(|r| r[..p].iter()).fold(0.0f64, |m, v| m.max(v.abs())).max(f64::MIN_POSITIVE);
    for c in 0..p {
        let piv = (c..p).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[piv][c].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(c, piv);
        for r in 0..p {
            if r != c {
                let f = a[r][c] / a[c][c];
                if f != 0.0 {
                    let pivot_row = a[c].clone();
                    for (x, y) in a[r][c..=p].iter_mut().zip(&pivot_row[c..=p]) {
                        *x -= f * y;
                    }
                }
            }
        }
    }
    let x: Vec<f64> = (0..p).map(|i| a[i][p] / a[i][i]).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Weighted least squares with `beta >= 0` for the columns flagged in `nonneg`: solve, drop (fix at zero) the most
/// negative flagged coefficient, repeat. Columns that are zero in every row are fixed at zero. Small `p` only.
pub fn weighted_nonneg(rows: &[Vec<f64>], y: &[f64], w: &[f64], nonneg: &[bool]) -> Option<Vec<f64>> {
    let p = nonneg.len();
    let mut active: Vec<bool> = (0..p).map(|j| rows.iter().any(|r| r.get(j).is_some_and(|&v| v != 0.0))).collect();
    loop {
        let cols: Vec<usize> = (0..p).filter(|&j| active[j]).collect();
        if cols.is_empty() {
            return Some(vec![0.0; p]);
        }
        let sub: Vec<Vec<f64>> = rows.iter().map(|r| cols.iter().map(|&j| r[j]).collect()).collect();
        // Where the plain system is singular, a tiny ridge keeps duplicate columns (e.g. coherent and incoherent prices when only one kind of rays was
        // measured) solvable: the fit is then shared between them.
        let diag: f64 = sub.iter().zip(w).map(|(r, wi)| r.iter().map(|v| wi * v * v).sum::<f64>()).sum();
        let tiny = 1e-9 * diag / cols.len() as f64;
        let beta = weighted_ridge(&sub, y, w, &vec![0.0; cols.len()])
            .or_else(|| weighted_ridge(&sub, y, w, &vec![tiny; cols.len()]))?;
        let worst = cols.iter().zip(&beta).filter(|(&j, &b)| nonneg[j] && b < 0.0).min_by(|a, b| a.1.total_cmp(b.1));
        match worst {
            Some((&j, _)) => active[j] = false,
            None => {
                let mut full = vec![0.0; p];
                for (&j, &b) in cols.iter().zip(&beta) {
                    full[j] = b;
                }
                return Some(full);
            }
        }
    }
}
