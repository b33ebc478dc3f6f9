//! Intel AMX (Advanced Matrix Extensions) bf16 tile products for the bf16 dense
//! layers ([`crate::bf16`]): `tdpbf16ps` multiplies a 16 × 32 bf16 tile by a
//! 32 × 16 one into 16 × 16 f32 sums, the same bf16-products-f32-sums arithmetic
//! as `vdpbf16ps`, on the core's matrix unit (Xeon Sapphire Rapids and later).
//!
//! The operands are the layouts [`crate::bf16`] already packs: activations as
//! rows of bf16 pairs along k (an A tile is 16 rows × 16 pairs), weights as
//! pairs along k per output column (a B tile is 16 pairs × 16 columns, the
//! "VNNI" layout AMX expects). Rust has no stable AMX intrinsics, so the five
//! instructions are inline assembly; Linux hands a process the 8 KiB tile state
//! only after `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`, asked once.
#![allow(unsafe_code)]
// Elsewhere only `available()` is reachable (false): the kernels are x86-64 code.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

use std::sync::OnceLock;

/// k pairs per A/B tile (16 pairs = 32 bf16 = 64 bytes per tile row).
pub(crate) const K_PAIRS: usize = 16;
/// Rows of the output block (two A tiles).
pub(crate) const M_BLOCK: usize = 32;
/// Columns of the output block (two B tiles).
pub(crate) const N_BLOCK: usize = 32;
/// Rows and columns of one f32 accumulator tile.
pub(crate) const TILE: usize = 16;

/// True when this CPU has AMX-BF16 and the OS granted this process the tile
/// state (checked once per process).
pub(crate) fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(detect)
}

#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn detect() -> bool {
    use std::arch::x86_64::__cpuid_count;
    /// `arch_prctl` code asking for an extended state component (asm/prctl.h).
    const ARCH_REQ_XCOMP_PERM: libc::c_ulong = 0x1023;
    /// The AMX tile data state component (XTILEDATA, asm/fpu/types.h).
    const XFEATURE_XTILEDATA: libc::c_ulong = 18;
    // CPUID.(EAX=7, ECX=0):EDX bit 22 = AMX-BF16, bit 24 = AMX-TILE.
    let edx = __cpuid_count(7, 0).edx;
    if edx & (1 << 22) == 0 || edx & (1 << 24) == 0 {
        return false;
    }
    // SAFETY: a plain system call with two integer arguments; it only changes
    // which xsave components this process may use.
    let granted = unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        )
    };
    granted == 0
}

#[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
fn detect() -> bool {
    false
}

/// The `ldtilecfg` operand: palette 1, eight 16-row × 64-byte tiles.
#[repr(C, align(64))]
struct TileConfig {
    palette: u8,
    start_row: u8,
    reserved: [u8; 14],
    colsb: [u16; 16],
    rows: [u8; 16],
}

impl TileConfig {
    fn all_full() -> Self {
        let mut cfg = Self {
            palette: 1,
            start_row: 0,
            reserved: [0; 14],
            colsb: [0; 16],
            rows: [0; 16],
        };
        for t in 0..8 {
            cfg.colsb[t] = 64;
            cfg.rows[t] = TILE as u8;
        }
        cfg
    }
}

/// Loads the tile configuration every kernel here uses (palette 1, eight 16-row × 64-byte
/// tiles: tmm0–1 the A tiles, tmm2–3 the B tiles, tmm4–7 the four 16 × 16 f32 sums of a
/// 32 × 32 block) on this thread.
///
/// # Safety
/// [`available`] must have returned true; pair with [`release`] on the same thread.
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) unsafe fn configure() {
    let cfg = TileConfig::all_full();
    // SAFETY: `cfg` is a valid palette-1 configuration; AMX by the caller's contract.
    unsafe { std::arch::asm!("ldtilecfg [{}]", in(reg) &cfg, options(nostack, readonly)) };
}

/// Releases this thread's tile state ([`configure`] again before the next product).
///
/// # Safety
/// [`available`] must have returned true.
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) unsafe fn release() {
    // SAFETY: AMX by the caller's contract.
    unsafe { std::arch::asm!("tilerelease", options(nostack, nomem)) };
}

/// Sets the four sums of the 32 × 32 block to zero.
///
/// # Safety
/// Tiles [`configure`]d on this thread.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn zero_block() {
    // SAFETY: configured tiles, by the caller's contract.
    unsafe {
        std::arch::asm!(
            "tilezero tmm4",
            "tilezero tmm5",
            "tilezero tmm6",
            "tilezero tmm7",
            options(nostack, nomem)
        );
    }
}

/// Adds one k-step of 16 pairs to the 32 × 32 block: rows 0–15 of the block from the A tile at
/// `a0`, rows 16–31 from `a1` (16 rows of 16 bf16 pairs each, `sa` bytes apart), columns 0–15
/// from the B tile at `b0`, 16–31 from `b1` (16 rows of pairs along k × 16 columns, `sb` bytes
/// apart).
///
/// # Safety
/// Tiles [`configure`]d on this thread; 16 rows of 64 readable bytes at each pointer's stride.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn dot_block(
    [a0, a1]: [*const u32; 2],
    sa: usize,
    [b0, b1]: [*const u32; 2],
    sb: usize,
) {
    // SAFETY: the caller's contract.
    unsafe {
        std::arch::asm!(
            "tileloadd tmm0, [{a0} + {sa}*1]",
            "tileloadd tmm1, [{a1} + {sa}*1]",
            "tileloadd tmm2, [{b0} + {sb}*1]",
            "tileloadd tmm3, [{b1} + {sb}*1]",
            "tdpbf16ps tmm4, tmm0, tmm2",
            "tdpbf16ps tmm5, tmm0, tmm3",
            "tdpbf16ps tmm6, tmm1, tmm2",
            "tdpbf16ps tmm7, tmm1, tmm3",
            a0 = in(reg) a0,
            a1 = in(reg) a1,
            b0 = in(reg) b0,
            b1 = in(reg) b1,
            sa = in(reg) sa,
            sb = in(reg) sb,
            options(nostack, readonly)
        );
    }
}

/// Adds one k-step of 16 pairs to a 64 × 16 block (the shape for 16 output columns or fewer):
/// rows `16i..16i + 16` from the A tile at `a[i]` (`sa` bytes between rows), every column from
/// the B tile at `b` (`sb` bytes between rows). Its sums are tmm4–7 as in [`dot_block`]; sum `i`
/// holds rows `16i..16i + 16` ([`COLUMN_SUMS`]).
///
/// # Safety
/// As [`dot_block`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn dot_column(
    [a0, a1, a2, a3]: [*const u32; 4],
    sa: usize,
    b: *const u32,
    sb: usize,
) {
    // SAFETY: the caller's contract.
    unsafe {
        std::arch::asm!(
            "tileloadd tmm2, [{b} + {sb}*1]",
            "tileloadd tmm0, [{a0} + {sa}*1]",
            "tileloadd tmm1, [{a1} + {sa}*1]",
            "tdpbf16ps tmm4, tmm0, tmm2",
            "tdpbf16ps tmm5, tmm1, tmm2",
            "tileloadd tmm0, [{a2} + {sa}*1]",
            "tileloadd tmm1, [{a3} + {sa}*1]",
            "tdpbf16ps tmm6, tmm0, tmm2",
            "tdpbf16ps tmm7, tmm1, tmm2",
            a0 = in(reg) a0,
            a1 = in(reg) a1,
            a2 = in(reg) a2,
            a3 = in(reg) a3,
            b = in(reg) b,
            sa = in(reg) sa,
            sb = in(reg) sb,
            options(nostack, readonly)
        );
    }
}

/// The sums of a [`dot_column`] block in [`store_sum`] order: (row offset, column offset).
pub(crate) const COLUMN_SUMS: [(usize, usize); 4] =
    [(0, 0), (TILE, 0), (2 * TILE, 0), (3 * TILE, 0)];

/// The block's sums in [`store_sum`] order: (row offset, column offset) of each 16 × 16 tile.
pub(crate) const SUMS: [(usize, usize); 4] = [(0, 0), (0, TILE), (TILE, 0), (TILE, TILE)];

/// Stores sum `t` of the block ([`SUMS`]`[t]`) as 16 rows of 16 f32 at `dst`, `stride` bytes
/// apart.
///
/// # Safety
/// Tiles [`configure`]d on this thread; 16 rows of 64 writable bytes at `dst`'s stride.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn store_sum(t: usize, dst: *mut f32, stride: usize) {
    use std::arch::asm;
    // SAFETY: the caller's contract.
    unsafe {
        match t {
            0 => {
                asm!("tilestored [{p} + {s}*1], tmm4", p = in(reg) dst, s = in(reg) stride, options(nostack))
            }
            1 => {
                asm!("tilestored [{p} + {s}*1], tmm5", p = in(reg) dst, s = in(reg) stride, options(nostack))
            }
            2 => {
                asm!("tilestored [{p} + {s}*1], tmm6", p = in(reg) dst, s = in(reg) stride, options(nostack))
            }
            _ => {
                asm!("tilestored [{p} + {s}*1], tmm7", p = in(reg) dst, s = in(reg) stride, options(nostack))
            }
        }
    }
}

/// `y[r, o] = act(Σ_p a[r, p] · w[p, o])` for `r < m`, `o < out`, with bf16
/// pairs `a` (`m_pad × kp` u32, `m_pad` a multiple of [`M_BLOCK`], `kp` of
/// [`K_PAIRS`], rows past `m` zero) and `w` (`kp × out_pad` u32, `out_pad` a
/// multiple of [`N_BLOCK`]); `act` maps each f32 sum (the LeakyReLU).
///
/// # Safety
/// [`available`] must have returned true; the slices must have the sizes above.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn matmul(
    m: usize,
    kp: usize,
    a: &[u32],
    out: usize,
    out_pad: usize,
    w: &[u32],
    y: &mut [f32],
    ldy: usize,
    act: impl Fn(f32) -> f32,
) {
    // Checked once per call: every tile load below stays inside `a` and `w`.
    assert!(kp.is_multiple_of(K_PAIRS) && out_pad.is_multiple_of(N_BLOCK) && out <= out_pad);
    assert!(a.len() >= m.div_ceil(M_BLOCK) * M_BLOCK * kp && w.len() >= kp * out_pad);
    let (sa, sw) = (kp * 4, out_pad * 4);
    let mut c = [[0.0f32; TILE]; TILE];
    // SAFETY (all calls below): AMX by this fn's contract; every tile load reads 16 rows of 64
    // bytes inside `a` or `w` by the size checks; stores go to the 1 KiB `c`.
    unsafe { configure() };
    for i0 in (0..m).step_by(M_BLOCK) {
        for j0 in (0..out.min(out_pad)).step_by(N_BLOCK) {
            unsafe { zero_block() };
            for p0 in (0..kp).step_by(K_PAIRS) {
                let a0 = a[i0 * kp + p0..].as_ptr();
                let a1 = a[(i0 + TILE) * kp + p0..].as_ptr();
                let b0 = w[p0 * out_pad + j0..].as_ptr();
                let b1 = w[p0 * out_pad + j0 + TILE..].as_ptr();
                unsafe { dot_block([a0, a1], sa, [b0, b1], sw) };
            }
            for (t, (di, dj)) in SUMS.into_iter().enumerate() {
                unsafe { store_sum(t, c.as_mut_ptr().cast::<f32>(), 4 * TILE) };
                let (r0, o0) = (i0 + di, j0 + dj);
                if r0 >= m || o0 >= out {
                    continue;
                }
                let cols = (out - o0).min(TILE);
                for (r, row) in c.iter().enumerate().take(m - r0) {
                    let dst = &mut y[(r0 + r) * ldy + o0..(r0 + r) * ldy + o0 + cols];
                    for (d, &v) in dst.iter_mut().zip(row) {
                        *d = act(v);
                    }
                }
            }
        }
    }
    unsafe { release() };
}
