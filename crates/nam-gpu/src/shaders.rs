//! WGSL sources (`shaders/`, one kernel family per file) and their precision variants.
//!
//! Every source declares its storage type with the line [`STORAGE_ALIAS_F32`]; the f16 variant
//! replaces it with `alias st = f16;` and prepends `enable f16;`. Kernels load `f32(x)` and
//! store `st(v)`, so arithmetic and accumulation stay f32 in both variants. Storage textures
//! are declared `rgba32float` and become `rgba16float` in the f16 variant.

use std::borrow::Cow;

/// Storage (and transfer) precision of activations and weights on the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Precision {
    /// 32-bit floats everywhere.
    F32,
    /// 16-bit storage, f32 arithmetic; needs `Features::SHADER_F16`.
    F16,
}

impl Precision {
    /// Bytes per stored element.
    pub fn elem_bytes(self) -> u64 {
        match self {
            Precision::F32 => 4,
            Precision::F16 => 2,
        }
    }
}

/// The multiply-add snippet appended to `matmul_tex.wgsl` and `conv_tex.wgsl` (see
/// [`Family::base_source`]; named for the tests that walk `shaders/`).
#[cfg(test)]
pub(crate) const SUBGROUP_MAC: &str = "subgroup_mac.wgsl";

/// The line every precision-generic shader starts its declarations with.
pub const STORAGE_ALIAS_F32: &str = "alias st = f32;";

/// Storage-texture format of the f32 sources and of the f16 variant.
const TEXEL_F32: &str = "rgba32float";
const TEXEL_F16: &str = "rgba16float";

/// A kernel family: one WGSL file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Family {
    /// `conv2d.wgsl`: direct convolution, replicate padding.
    Conv2d,
    /// `conv_transpose.wgsl`: transposed convolution.
    ConvTranspose,
    /// `instance_norm.wgsl`: statistics and application.
    InstanceNorm,
    /// `ha_gate.wgsl`: HA-Conv gating + folded BN + block tail.
    HaGate,
    /// `elementwise.wgsl`: affine, add+relu, activations, copy.
    Elementwise,
    /// `pos_enc.wgsl`: positional encoding with exact range reduction.
    PosEnc,
    /// `matmul.wgsl`: tiled matmul with fused activation.
    Matmul,
    /// `matmul_tex.wgsl`: texture-operand, subgroup-broadcast matmul for CPU adapters.
    MatmulTex,
    /// `tex_pack.wgsl`: NCHW buffer tensor into a channel-block texture.
    TexPack,
    /// `conv_tex.wgsl`: implicit-GEMM convolutions on textures for CPU adapters.
    ConvTex,
    /// `fma_peak.wgsl`: FMA throughput probe (f32 only).
    FmaPeak,
    /// `smoke.wgsl`: one-line smoke test (f32 only).
    Smoke,
}

/// Kind of one binding of a family's bind group 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Binding {
    Uniform,
    Read,
    ReadWrite,
    /// `texture_2d<f32>` read with `textureLoad` (unfilterable float).
    Texture,
    /// `texture_storage_2d<rgba32float | rgba16float, write>` (by precision).
    StorageTexture,
}

impl Family {
    /// Every family, for validation tests.
    pub const ALL: [Family; 12] = [
        Family::Conv2d,
        Family::ConvTranspose,
        Family::InstanceNorm,
        Family::HaGate,
        Family::Elementwise,
        Family::PosEnc,
        Family::Matmul,
        Family::MatmulTex,
        Family::TexPack,
        Family::ConvTex,
        Family::FmaPeak,
        Family::Smoke,
    ];

    /// File name under `shaders/`.
    pub fn file_name(self) -> &'static str {
        match self {
            Family::Conv2d => "conv2d.wgsl",
            Family::ConvTranspose => "conv_transpose.wgsl",
            Family::InstanceNorm => "instance_norm.wgsl",
            Family::HaGate => "ha_gate.wgsl",
            Family::Elementwise => "elementwise.wgsl",
            Family::PosEnc => "pos_enc.wgsl",
            Family::Matmul => "matmul.wgsl",
            Family::MatmulTex => "matmul_tex.wgsl",
            Family::TexPack => "tex_pack.wgsl",
            Family::ConvTex => "conv_tex.wgsl",
            Family::FmaPeak => "fma_peak.wgsl",
            Family::Smoke => "smoke.wgsl",
        }
    }

    /// The f32 source as stored in `shaders/`; the two subgroup-broadcast families get
    /// `subgroup_mac.wgsl` (their shared multiply-add) appended.
    pub fn base_source(self) -> &'static str {
        match self {
            Family::Conv2d => include_str!("../../../shaders/conv2d.wgsl"),
            Family::ConvTranspose => include_str!("../../../shaders/conv_transpose.wgsl"),
            Family::InstanceNorm => include_str!("../../../shaders/instance_norm.wgsl"),
            Family::HaGate => include_str!("../../../shaders/ha_gate.wgsl"),
            Family::Elementwise => include_str!("../../../shaders/elementwise.wgsl"),
            Family::PosEnc => include_str!("../../../shaders/pos_enc.wgsl"),
            Family::Matmul => include_str!("../../../shaders/matmul.wgsl"),
            Family::MatmulTex => concat!(
                include_str!("../../../shaders/matmul_tex.wgsl"),
                include_str!("../../../shaders/subgroup_mac.wgsl")
            ),
            Family::TexPack => include_str!("../../../shaders/tex_pack.wgsl"),
            Family::ConvTex => concat!(
                include_str!("../../../shaders/conv_tex.wgsl"),
                include_str!("../../../shaders/subgroup_mac.wgsl")
            ),
            Family::FmaPeak => include_str!("../../../shaders/fma_peak.wgsl"),
            Family::Smoke => include_str!("../../../shaders/smoke.wgsl"),
        }
    }

    /// Whether the family has an f16 storage variant.
    pub fn has_f16(self) -> bool {
        !matches!(self, Family::FmaPeak | Family::Smoke)
    }

    /// Source for `precision`; `None` when the family has no such variant.
    pub fn source(self, precision: Precision) -> Option<Cow<'static, str>> {
        let base = self.base_source();
        match precision {
            Precision::F32 => Some(Cow::Borrowed(base)),
            Precision::F16 if self.has_f16() => Some(Cow::Owned(format!(
                "enable f16;\n{}",
                base.replacen(STORAGE_ALIAS_F32, "alias st = f16;", 1)
                    .replace(TEXEL_F32, TEXEL_F16)
            ))),
            Precision::F16 => None,
        }
    }

    /// Bind group 0 of every entry point of the family, in binding order.
    pub(crate) fn bindings(self) -> &'static [Binding] {
        use Binding::{
            Read as R, ReadWrite as W, StorageTexture as ST, Texture as T, Uniform as U,
        };
        match self {
            Family::Conv2d => &[U, R, R, R, R, W],
            Family::ConvTranspose => &[U, R, R, R, W],
            Family::InstanceNorm => &[U, R, W],
            Family::HaGate => &[U, R, R, R, R, R, W],
            Family::Elementwise => &[U, R, R, W],
            Family::PosEnc => &[U, R, W, ST],
            Family::Matmul => &[U, R, R, W],
            Family::MatmulTex => &[U, T, T, ST, W],
            Family::TexPack => &[U, R, R, ST],
            Family::ConvTex => &[U, T, T, R, W],
            Family::FmaPeak => &[U, W],
            Family::Smoke => &[W],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn validate(family: Family, precision: Precision) -> Result<(), String> {
        let src = family
            .source(precision)
            .ok_or_else(|| format!("{family:?} has no {precision:?} variant"))?;
        let module = naga::front::wgsl::parse_str(&src)
            .map_err(|e| format!("{}: {}", family.file_name(), e.emit_to_string(&src)))?;
        // Subgroup operations are only used by `matmul_tex.wgsl` and `conv_tex.wgsl`, which the
        // host selects only when the device has `Features::SUBGROUP`.
        let caps = match precision {
            Precision::F32 => naga::valid::Capabilities::SUBGROUP,
            Precision::F16 => {
                naga::valid::Capabilities::SHADER_FLOAT16 | naga::valid::Capabilities::SUBGROUP
            }
        };
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
            .subgroup_stages(naga::valid::ShaderStages::COMPUTE)
            .subgroup_operations(naga::valid::SubgroupOperationSet::all())
            .validate(&module)
            .map_err(|e| format!("{}: {}", family.file_name(), e.emit_to_string(&src)))?;
        Ok(())
    }

    #[test]
    fn every_shader_parses_and_validates_with_naga_f32() {
        for family in Family::ALL {
            if let Err(e) = validate(family, Precision::F32) {
                panic!("{e}");
            }
        }
    }

    #[test]
    fn every_f16_variant_parses_and_validates_with_naga() {
        for family in Family::ALL.into_iter().filter(|f| f.has_f16()) {
            if let Err(e) = validate(family, Precision::F16) {
                panic!("{e}");
            }
        }
    }

    #[test]
    fn precision_generic_shaders_declare_the_storage_alias_once() {
        for family in Family::ALL.into_iter().filter(|f| f.has_f16()) {
            let n = family.base_source().matches(STORAGE_ALIAS_F32).count();
            assert_eq!(
                n,
                1,
                "{} declares `{STORAGE_ALIAS_F32}` {n} times",
                family.file_name()
            );
            let f16 = family.source(Precision::F16).unwrap_or_default();
            assert!(f16.contains("alias st = f16;") && !f16.contains(STORAGE_ALIAS_F32));
            assert!(!f16.contains(TEXEL_F32), "{}", family.file_name());
        }
    }

    #[test]
    fn bindings_match_the_shader_declarations() {
        for family in Family::ALL {
            let src = family.base_source();
            let declared = src.matches("@binding(").count();
            assert_eq!(declared, family.bindings().len(), "{}", family.file_name());
            let read_write = src.matches("read_write>").count();
            let kinds = |b: Binding| family.bindings().iter().filter(|x| **x == b).count();
            assert_eq!(
                src.matches(": texture_2d<f32>;").count(),
                kinds(Binding::Texture),
                "{} textures",
                family.file_name()
            );
            assert_eq!(
                src.matches(": texture_storage_2d<").count(),
                kinds(Binding::StorageTexture),
                "{} storage textures",
                family.file_name()
            );
            let expected = family
                .bindings()
                .iter()
                .filter(|b| **b == Binding::ReadWrite)
                .count();
            assert_eq!(
                read_write,
                expected,
                "{} read_write bindings",
                family.file_name()
            );
        }
    }
}
