"""The torch GGX renderer against the float64 golden fixture and the DESIGN.md §7 guards."""

import math

import torch
from safetensors.torch import load_file

from train_py import ggx

from .conftest import FIXTURES

#: float64 recomputation of the fixture: only summation-order rounding can differ.
F64_RTOL = 1e-12
F64_ATOL = 1e-15
#: f32 evaluation of the same points: ~1e-7 per op, amplified by the sharp NDF of roughness ≈ 0.01.
F32_RTOL = 2e-3
F32_ATOL = 1e-6
#: Within this of the shading horizon the f32-rounded inputs may flip the sign of NoL/NoV; Smith–Schlick
#: GGX jumps there (G1(x)/x → 1/k ≠ 0), so only finiteness is meaningful for those points.
HORIZON_BAND = 1e-5


def golden():
    return load_file(str(FIXTURES / "ggx_golden.safetensors"))


def test_ggx_float64_reproduces_golden_fixture():
    g = golden()
    r = ggx.ggx_radiance(g["diffuse"], g["specular"], g["roughness"], g["normal"], g["wi"], g["wo"])
    torch.testing.assert_close(r, g["radiance"], rtol=F64_RTOL, atol=F64_ATOL)


def test_ggx_float32_matches_golden_within_tolerance_and_is_finite():
    g = {k: v.float() for k, v in golden().items()}
    r = ggx.ggx_radiance(g["diffuse"], g["specular"], g["roughness"], g["normal"], g["wi"], g["wo"])
    assert torch.isfinite(r).all() and (r >= 0).all()
    g64 = golden()
    away = (ggx.dot(g64["normal"], g64["wi"]).abs() > HORIZON_BAND) & (
        ggx.dot(g64["normal"], g64["wo"]).abs() > HORIZON_BAND
    )
    assert away.sum() > 80
    torch.testing.assert_close(r[away], g["radiance"][away], rtol=F32_RTOL, atol=F32_ATOL)


def test_pixel_geometry_matches_golden_5x7_block():
    g = golden()
    wi, wo, wh = ggx.directions(g["geom_light"], g["geom_view"], 5, 7)
    torch.testing.assert_close(wi, g["geom_wi"], rtol=F64_RTOL, atol=F64_ATOL)
    torch.testing.assert_close(wo, g["geom_wo"], rtol=F64_RTOL, atol=F64_ATOL)
    torch.testing.assert_close(wh, g["geom_wh"], rtol=F64_RTOL, atol=F64_ATOL)


def test_pixel_centres_follow_design_convention():
    pos = ggx.pixel_positions(2, 4, torch.float64)
    assert pos[0, 0].tolist() == [-0.75, 0.5, 0.0]
    assert pos[1, 3].tolist() == [0.75, -0.5, 0.0]


def test_light_or_view_at_or_below_shading_horizon_gives_exact_zero():
    n = torch.tensor([[0.0, 0.0, 1.0]] * 4)
    up = torch.tensor([0.0, 0.6, 0.8])
    wi = torch.stack([torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.6, -0.8]), up, up])
    wo = torch.stack([up, up, torch.tensor([0.0, 1.0, 0.0]), torch.tensor([0.6, 0.0, -0.8])])
    ones = torch.ones(4, 3)
    r = ggx.ggx_radiance(ones, ones, torch.full((4,), 0.01), n, wi, wo)
    assert (r == 0).all()


def test_zero_roughness_normal_incidence_is_finite_in_float32():
    # NoH²(α²-1)+1 evaluated literally cancels to 0 in f32 for α² = 1e-8: the guard must avoid inf.
    n = torch.tensor([[0.0, 0.0, 1.0]])
    r = ggx.ggx_radiance(torch.zeros(1, 3), torch.ones(1, 3), torch.zeros(1), n, n, n)
    alpha = ggx.ALPHA_MIN
    expected = 1.0 / (4.0 * alpha * alpha)  # D = 1/(πα²), G/(4NoLNoV) = 1/4, F = 1, ·π
    assert torch.isfinite(r).all()
    torch.testing.assert_close(r, torch.full((1, 3), expected), rtol=1e-5, atol=0.0)


def test_lambertian_white_surface_returns_cosine():
    n = torch.tensor([0.0, 0.0, 1.0])
    wi = torch.tensor([0.6, 0.0, 0.8])
    wo = torch.tensor([-0.6, 0.0, 0.8])
    r = ggx.ggx_radiance(torch.ones(3), torch.zeros(3), torch.tensor(1.0), n, wi, wo)
    # With F0 = 0 only the 2^(..) Fresnel tail and a rough lobe remain; diffuse part = NoL.
    spec = r - 0.8
    assert (spec > 0).all() and (spec < 0.05).all()


def test_capture_half_z_equals_z_of_colocated_half_vector():
    cam = ggx.capture_position(torch.float64)
    _, _, wh = ggx.directions(cam, cam, 6, 10)
    torch.testing.assert_close(ggx.capture_half_z(6, 10, torch.float64), wh[..., 2], rtol=1e-14, atol=0.0)
    assert math.isclose(ggx.CAPTURE_DISTANCE, 4.010781, abs_tol=1e-6)


def test_log_helpers_invert_and_clamp_negative():
    r = torch.tensor([0.0, 0.5, 3.0, 1e6])
    torch.testing.assert_close(ggx.from_log(ggx.to_log(r)), r)
    assert ggx.from_log(torch.tensor([-0.5])).item() == 0.0


def test_srgb_roundtrip_and_ldr_clamp():
    x = torch.linspace(0, 1, 101, dtype=torch.float64)
    torch.testing.assert_close(ggx.srgb_decode(ggx.srgb_encode(x)), x)
    assert ggx.ldr_capture(torch.tensor([5.0])).item() == 1.0


def test_network_input_clamps_ldr_and_appends_half_z():
    photo = torch.tensor([[[[2.0, -1.0, 0.25]]]])
    inp = ggx.network_input(photo, "ldr")
    assert inp.shape == (1, 4, 1, 1)
    torch.testing.assert_close(inp[0, :3, 0, 0], torch.log1p(torch.tensor([ggx.LDR_MAX, 0.0, 0.25])))
    assert inp[0, 3, 0, 0].item() == 1.0  # a single pixel sits at the centre: wh = +z
    hdr = ggx.network_input(photo, "hdr")
    torch.testing.assert_close(hdr[0, 0, 0, 0], torch.log1p(torch.tensor(2.0)))
