//! The uniform (bind group 0, binding 0) of every kernel family as a `#[repr(C)]` struct:
//! one per WGSL `var<uniform>` struct in `shaders/`, with the same name, member names, member
//! order and byte layout, uploaded as its bytes ([`bytemuck::bytes_of`]).
//!
//! Every member is a 4-byte scalar (`u32` counts, element offsets, flags and codes; `f32`
//! slopes and epsilons), so the WGSL uniform layout is the C layout: member `i` at byte `4·i`,
//! and each struct is padded by `_padN` members to a multiple of 16 bytes, as uniform buffers
//! require. The test at the bottom reflects every shader with naga and checks that each
//! uniform struct matches its Rust twin (names, offsets, scalar types, size) and that no Rust
//! struct is without a shader.

use bytemuck::{Pod, Zeroable};

/// Defines the uniform structs and, for the test, their layouts as the compiler lays them out.
macro_rules! uniforms {
    ($(
        $(#[doc = $doc:literal])*
        struct $name:ident {
            $($(#[doc = $fdoc:literal])* $field:ident: $ty:ident,)*
        }
    )*) => {
        $(
            $(#[doc = $doc])*
            #[repr(C)]
            #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
            pub(crate) struct $name {
                $($(#[doc = $fdoc])* pub $field: $ty,)*
            }
        )*

        /// Every uniform struct: its name, size in bytes and members (name, byte offset,
        /// scalar type name) in declaration order.
        #[cfg(test)]
        fn layouts() -> Vec<tests::Layout> {
            vec![$(tests::Layout {
                name: stringify!($name),
                size: std::mem::size_of::<$name>(),
                members: vec![$(
                    (stringify!($field), std::mem::offset_of!($name, $field), stringify!($ty)),
                )*],
            },)*]
        }
    };
}

uniforms! {
    /// `shaders/conv2d.wgsl`: a direct convolution with replicate padding.
    struct ConvParams {
        /// Input channels.
        cin: u32,
        /// Input height (pixels).
        h: u32,
        /// Input width (pixels).
        w: u32,
        /// Output channels.
        cout: u32,
        /// Output height (pixels).
        ho: u32,
        /// Output width (pixels).
        wo: u32,
        /// Stride (pixels).
        stride: u32,
        /// Replicate padding on each side (pixels).
        pad: u32,
        /// Element offset of the input tensor in its buffer.
        in_base: u32,
        /// Element offset of the output tensor in its buffer.
        out_base: u32,
        /// Bit 0: add the bias; bit 1: apply the per-input-channel norm on load.
        flags: u32,
        /// Activation code ([`crate::ops::Act`]: 0 none, 2 LeakyReLU).
        act: u32,
        /// LeakyReLU negative slope (unused for other codes).
        slope: f32,
        _pad0: u32,
        _pad1: u32,
        _pad2: u32,
    }

    /// `shaders/conv_transpose.wgsl`: a transposed convolution.
    struct ConvTParams {
        /// Input channels.
        cin: u32,
        /// Input height (pixels).
        h: u32,
        /// Input width (pixels).
        w: u32,
        /// Output channels.
        cout: u32,
        /// Output height (pixels).
        ho: u32,
        /// Output width (pixels).
        wo: u32,
        /// Padding removed from each side of the full output (pixels).
        pad: u32,
        /// Element offset of the input tensor in its buffer.
        in_base: u32,
        /// Element offset of the output tensor in its buffer.
        out_base: u32,
        /// Bit 0: add the bias.
        flags: u32,
        /// 0: no activation; 1: ReLU.
        act: u32,
        _pad0: u32,
    }

    /// `shaders/instance_norm.wgsl`: per-channel statistics of a `[channels, hw]` tensor.
    struct NormParams {
        /// Channels.
        channels: u32,
        /// Elements per channel (height · width).
        hw: u32,
        /// Element offset of the input tensor in its buffer.
        in_base: u32,
        /// Added to the variance before the inverse square root.
        eps: f32,
    }

    /// `shaders/ha_gate.wgsl`: the HA-Conv gate, folded BatchNorm and block tail.
    struct GateParams {
        /// Channels.
        channels: u32,
        /// Elements per channel (height · width).
        hw: u32,
        /// Block tail ([`crate::ops::GateTail`]): 1 ReLU, 2 residual add then ReLU.
        mode: u32,
        /// Element offset of the residual in its buffer (mode 2).
        res_base: u32,
        /// Element offset of the output tensor in its buffer.
        out_base: u32,
        /// LeakyReLU negative slope of the feature branch.
        slope: f32,
        /// 1: vec4 loads and stores (`hw` and both offsets multiples of 4).
        vec4_ok: u32,
        _pad0: u32,
    }

    /// `shaders/elementwise.wgsl`: element-wise entry points.
    struct EwParams {
        /// Elements.
        n: u32,
        /// Element offset of the input in its buffer.
        in_base: u32,
        /// Element offset of the second input in its buffer (0 when unused).
        in2_base: u32,
        /// Element offset of the output in its buffer.
        out_base: u32,
    }

    /// `shaders/pos_enc.wgsl`: positional encoding of direction rows.
    struct PeParams {
        /// Rows.
        n: u32,
        /// Elements between output rows (`pos_enc`) or texel columns per row (`pos_enc_tex`).
        out_stride: u32,
        /// Element offset of the first output row in its buffer (`pos_enc`; 0 for textures).
        out_base: u32,
        _pad0: u32,
    }

    /// `shaders/matmul.wgsl`: `y[m, n] = act(Σ_k x[m, k] · w[n, k])` on buffers.
    struct MatmulParams {
        /// Rows of `x` and `y`.
        rows: u32,
        /// Columns of `y` (rows of `w`).
        cols: u32,
        /// Inner dimension.
        inner: u32,
        /// Elements between rows of `x`.
        x_stride: u32,
        /// Element offset of `x` in its buffer.
        x_base: u32,
        /// Elements between rows of `y`.
        y_stride: u32,
        /// Element offset of `y` in its buffer.
        y_base: u32,
        /// Activation code ([`crate::ops::Act`]: 0 none, 2 LeakyReLU).
        act: u32,
        /// LeakyReLU negative slope (unused for other codes).
        slope: f32,
        _pad0: u32,
        _pad1: u32,
        _pad2: u32,
    }

    /// `shaders/matmul_tex.wgsl`: the same product with texture operands.
    struct TexMatmulParams {
        /// Rows of `x` and `y`.
        rows: u32,
        /// Columns of `y` (rows of `w`).
        cols: u32,
        /// Inner dimension in texels (`⌈inner / 4⌉`).
        inner4: u32,
        /// First texel column of `y` when it is a texture.
        y_texel_base: u32,
        /// 0: `y` is a texture; 1: `y` is a buffer.
        out_buf: u32,
        /// Elements between rows of `y` when it is a buffer.
        y_stride: u32,
        /// Activation code ([`crate::ops::Act`]: 0 none, 2 LeakyReLU).
        act: u32,
        /// LeakyReLU negative slope (unused for other codes).
        slope: f32,
    }

    /// `shaders/tex_pack.wgsl`: an NCHW buffer tensor into a channel-block texture.
    struct PackParams {
        /// Channels of the tensor.
        channels: u32,
        /// Height (pixels).
        h: u32,
        /// Width (pixels).
        w: u32,
        /// Element offset of the tensor in its buffer.
        in_base: u32,
        /// 1: apply the per-channel norm affine on the way.
        use_norm: u32,
        /// 1: 4-pixel vector loads (`w` and `in_base` multiples of 4).
        vec4_ok: u32,
        _pad1: u32,
        _pad2: u32,
    }

    /// `shaders/conv_tex.wgsl`: an implicit-GEMM convolution on texture operands.
    struct ConvTexParams {
        /// Input texels per pixel (`⌈cin / 4⌉`).
        cin4: u32,
        /// Input height (pixels).
        h: u32,
        /// Input width (pixels).
        w: u32,
        /// Output channels.
        cout: u32,
        /// Output height (pixels).
        ho: u32,
        /// Output width (pixels).
        wo: u32,
        /// Stride (pixels; `conv_t_tex`: always 2).
        stride: u32,
        /// Padding (pixels): replicate for `conv_tex`, cropped from the full output for
        /// `conv_t_tex`.
        pad: u32,
        /// Element offset of the output tensor in its buffer.
        out_base: u32,
        /// Bit 0: add the bias.
        flags: u32,
        /// Activation code ([`crate::ops::Act`]: 0 none, 2 LeakyReLU; ReLU is LeakyReLU(0)).
        act: u32,
        /// LeakyReLU negative slope (unused for other codes).
        slope: f32,
        /// `conv_t_tex`: 16-pixel blocks per output phase (`⌈h·w / 16⌉`).
        phase_blocks: u32,
        _pad0: u32,
        _pad1: u32,
        _pad2: u32,
    }

    /// `shaders/fma_peak.wgsl`: the FMA throughput probe.
    struct PeakParams {
        /// Loop iterations per invocation (64 flops each).
        iters: u32,
        /// Start value of the accumulators (each invocation adds `1e-7 · gid.x`).
        seed: f32,
        _pad0: u32,
        _pad1: u32,
    }
}

#[cfg(test)]
mod tests {
    use super::layouts;

    /// A Rust uniform struct as the compiler lays it out.
    #[derive(Debug)]
    pub(super) struct Layout {
        pub name: &'static str,
        /// Bytes.
        pub size: usize,
        /// (member name, byte offset, scalar type name) in declaration order.
        pub members: Vec<(&'static str, usize, &'static str)>,
    }

    /// The Rust name of a 4-byte naga scalar type (`None` for anything else).
    fn scalar_name(inner: &naga::TypeInner) -> Option<&'static str> {
        let naga::TypeInner::Scalar(s) = inner else {
            return None;
        };
        match (s.kind, s.width) {
            (naga::ScalarKind::Uint, 4) => Some("u32"),
            (naga::ScalarKind::Sint, 4) => Some("i32"),
            (naga::ScalarKind::Float, 4) => Some("f32"),
            _ => None,
        }
    }

    #[test]
    fn every_shader_uniform_struct_matches_its_rust_struct() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let rust = layouts();
        let mut used = Vec::new();
        let mut files = 0;
        for entry in std::fs::read_dir(&dir).expect("shaders/ is readable") {
            let path = entry.expect("directory entry").path();
            if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
                continue;
            }
            files += 1;
            let file = path.display();
            let name = path
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or_default();
            if name == crate::shaders::SUBGROUP_MAC {
                continue; // a snippet appended to two families, without a uniform of its own
            }
            // The source as compiled (some families append the shared snippet).
            let src = crate::shaders::Family::ALL
                .iter()
                .find(|f| f.file_name() == name)
                .unwrap_or_else(|| panic!("{file} is the file of no shader family"))
                .base_source();
            let module = naga::front::wgsl::parse_str(src)
                .unwrap_or_else(|e| panic!("{file}: {}", e.emit_to_string(src)));
            for (_, var) in module.global_variables.iter() {
                if var.space != naga::AddressSpace::Uniform {
                    continue;
                }
                let ty = &module.types[var.ty];
                let name = ty.name.as_deref().unwrap_or("(unnamed)");
                let naga::TypeInner::Struct { members, span } = &ty.inner else {
                    panic!("{file}: uniform {name} is not a struct");
                };
                let Some(r) = rust.iter().find(|r| r.name == name) else {
                    panic!("{file}: uniform struct {name} has no #[repr(C)] twin in params.rs");
                };
                let wgsl: Vec<(&str, usize, &str)> = members
                    .iter()
                    .map(|m| {
                        (
                            m.name.as_deref().unwrap_or("(unnamed)"),
                            m.offset as usize,
                            scalar_name(&module.types[m.ty].inner).unwrap_or("(not a scalar)"),
                        )
                    })
                    .collect();
                assert_eq!(wgsl, r.members, "{file}: members of {name} (WGSL left)");
                assert_eq!(*span as usize, r.size, "{file}: size of {name} in bytes");
                assert_eq!(r.size % 16, 0, "{name}: uniform size not a multiple of 16");
                used.push(name.to_string());
            }
        }
        assert!(files > 0, "no .wgsl files in {}", dir.display());
        for r in &rust {
            assert!(
                used.iter().any(|u| u == r.name),
                "{} is used by no shader in {}",
                r.name,
                dir.display()
            );
        }
    }
}
