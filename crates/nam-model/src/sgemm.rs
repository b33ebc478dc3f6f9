//! The one place that calls the `gemm` crate (raw-pointer API) behind a
//! bounds-checked, safe, row-major interface.
#![allow(unsafe_code)]

/// Row-major matrix operand: `data[r * ld + c]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Mat<'a> {
    pub data: &'a [f32],
    pub ld: usize,
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
    let need = |rows: usize, cols: usize, ld: usize| {
        if rows == 0 || cols == 0 {
            0
        } else {
            (rows - 1) * ld + cols
        }
    };
    assert!(a.data.len() >= need(m, k, a.ld) && (k == 0 || a.ld >= k));
    assert!(b.data.len() >= need(k, n, b.ld) && (k == 0 || b.ld >= n));
    assert!(c.len() >= need(m, n, ldc) && ldc >= n);
    if k == 0 {
        if !accumulate {
            for r in 0..m {
                c[r * ldc..r * ldc + n].fill(0.0);
            }
        }
        return;
    }
    let par = if threads > 1 {
        gemm::Parallelism::Rayon(threads)
    } else {
        gemm::Parallelism::None
    };
    // SAFETY: the asserts above guarantee every element addressed by
    // (m, n, k) and the strides lies inside the slices; `c` is borrowed
    // mutably so nothing aliases the destination.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            ldc as isize,
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

/// Like [`sgemm`] but writes `C` transposed: `ct[j·ldct + i] = (A·B)[i, j]`.
/// With few output columns (n < 16) this puts the gemm kernel's SIMD lanes
/// along the long `m` dimension instead of the short `n` one.
#[allow(clippy::too_many_arguments)]
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
    assert!(k > 0 && a.ld >= k && b.ld >= n && ldct >= m);
    assert!(a.data.len() >= (m - 1) * a.ld + k);
    assert!(b.data.len() >= (k - 1) * b.ld + n);
    assert!(ct.len() >= (n - 1) * ldct + m);
    // SAFETY: as in `sgemm`, with the destination strides swapped (row stride 1,
    // column stride ldct); the asserts bound every addressed element.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            ct.as_mut_ptr(),
            ldct as isize,
            1,
            false,
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
            gemm::Parallelism::None,
        );
    }
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
}
