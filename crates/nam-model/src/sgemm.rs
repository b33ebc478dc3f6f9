//! The one place that calls the `gemm` crate (raw-pointer API) behind a
//! bounds-checked, safe, row-major interface.
#![allow(unsafe_code)]

/// Row-major matrix operand: `data[r * ld + c]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Mat<'a> {
    pub data: &'a [f32],
    pub ld: usize,
}

/// Elements a `rows × cols` operand with leading dimension `ld` spans.
fn span(rows: usize, cols: usize, ld: usize) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * ld + cols
    }
}

/// `dst[i·rs + j·cs] (+)= (A·B)[i, j]` for `i < m`, `j < n`, with `k ≥ 1`.
/// The one unsafe call: every addressed element is bounds-checked first, and
/// `dst` is borrowed mutably so nothing aliases the destination. Callers keep
/// the destination strides injective (`rs ≥ n` with `cs = 1`, or the mirror).
fn gemm_strided(
    (m, n, k): (usize, usize, usize),
    a: Mat<'_>,
    b: Mat<'_>,
    dst: &mut [f32],
    (rs, cs): (usize, usize),
    accumulate: bool,
    threads: usize,
) {
    assert!(m > 0 && n > 0 && k > 0);
    assert!(a.ld >= k && a.data.len() >= span(m, k, a.ld));
    assert!(b.ld >= n && b.data.len() >= span(k, n, b.ld));
    assert!(dst.len() > (m - 1) * rs + (n - 1) * cs);
    let par = if threads > 1 {
        gemm::Parallelism::Rayon(threads)
    } else {
        gemm::Parallelism::None
    };
    // SAFETY: the asserts above bound every element addressed by (m, n, k)
    // and the strides inside the slices; `dst` is an exclusive borrow.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            cs as isize,
            rs as isize,
            accumulate,
            a.data.as_ptr(),
            1,
            a.ld as isize,
            b.data.as_ptr(),
            1,
            b.ld as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            par,
        );
    }
}

/// `C[m×n] = A[m×k] · B[k×n]` (or `C += A·B` when `accumulate`), all row-major
/// with leading dimensions `a.ld`, `b.ld`, `ldc`. `threads > 1` lets the `gemm`
/// crate split the product over rayon.
///
/// # Panics
/// When a slice is too short for its dimensions (an internal bug: every caller
/// sizes its buffers from the same numbers).
#[allow(clippy::too_many_arguments)]
pub(crate) fn sgemm(
    m: usize,
    n: usize,
    k: usize,
    a: Mat<'_>,
    b: Mat<'_>,
    c: &mut [f32],
    ldc: usize,
    accumulate: bool,
    threads: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(ldc >= n && c.len() >= span(m, n, ldc));
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                c[r * ldc..r * ldc + n].fill(0.0);
            }
        }
        return;
    }
    gemm_strided((m, n, k), a, b, c, (ldc, 1), accumulate, threads);
}

/// Like [`sgemm`] but writes `C` transposed: `ct[j·ldct + i] = (A·B)[i, j]`.
/// With few output columns (n < 16) this puts the gemm kernel's SIMD lanes
/// along the long `m` dimension instead of the short `n` one.
pub(crate) fn sgemm_into_transposed(
    m: usize,
    n: usize,
    k: usize,
    a: Mat<'_>,
    b: Mat<'_>,
    ct: &mut [f32],
    ldct: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(ldct >= m);
    gemm_strided((m, n, k), a, b, ct, (1, ldct), false, 1);
}

/// Plain triple loop used to test [`sgemm`].
#[cfg(test)]
fn naive(m: usize, n: usize, k: usize, a: &[f32], b: &[f32]) -> Vec<f32> {
    let mut c = vec![0.0f32; m * n];
    for i in 0..m {
        for j in 0..n {
            let mut s = 0.0f64;
            for p in 0..k {
                s += f64::from(a[i * k + p]) * f64::from(b[p * n + j]);
            }
            c[i * n + j] = s as f32;
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sgemm_matches_naive_product_with_strides_and_accumulation() {
        // Odd sizes exercise the kernel edges.
        let (m, n, k) = (37, 29, 53);
        let a: Vec<f32> = (0..m * k)
            .map(|i| ((i * 7 % 13) as f32 - 6.0) / 7.0)
            .collect();
        let b: Vec<f32> = (0..k * n)
            .map(|i| ((i * 5 % 11) as f32 - 5.0) / 5.0)
            .collect();
        let want = naive(m, n, k, &a, &b);
        let ldc = n + 3;
        let mut c = vec![1.0f32; m * ldc];
        sgemm(
            m,
            n,
            k,
            Mat { data: &a, ld: k },
            Mat { data: &b, ld: n },
            &mut c,
            ldc,
            false,
            1,
        );
        // Tolerance: f32 sum of 53 products of O(1) values.
        const TOL: f32 = 1e-5;
        for i in 0..m {
            for j in 0..n {
                assert!((c[i * ldc + j] - want[i * n + j]).abs() < TOL);
            }
            // Padding columns untouched.
            assert_eq!(c[i * ldc + n..i * ldc + ldc], [1.0; 3]);
        }
        sgemm(
            m,
            n,
            k,
            Mat { data: &a, ld: k },
            Mat { data: &b, ld: n },
            &mut c,
            ldc,
            true,
            2,
        );
        for i in 0..m {
            for j in 0..n {
                assert!((c[i * ldc + j] - 2.0 * want[i * n + j]).abs() < 2.0 * TOL);
            }
        }
    }

    #[test]
    fn transposed_product_matches_naive_and_leaves_padding() {
        let (m, n, k) = (23, 3, 17);
        let a: Vec<f32> = (0..m * k)
            .map(|i| ((i * 3 % 7) as f32 - 3.0) / 3.0)
            .collect();
        let b: Vec<f32> = (0..k * n)
            .map(|i| ((i * 5 % 9) as f32 - 4.0) / 4.0)
            .collect();
        let want = naive(m, n, k, &a, &b);
        let ldct = m + 2;
        let mut ct = vec![7.0f32; n * ldct];
        sgemm_into_transposed(
            m,
            n,
            k,
            Mat { data: &a, ld: k },
            Mat { data: &b, ld: n },
            &mut ct,
            ldct,
        );
        for j in 0..n {
            for i in 0..m {
                assert!((ct[j * ldct + i] - want[i * n + j]).abs() < 1e-5);
            }
            assert_eq!(ct[j * ldct + m..(j + 1) * ldct], [7.0; 2]);
        }
    }
}
