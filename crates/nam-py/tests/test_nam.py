"""The Python package `nam` (crates/nam-py): agreement with torch (train_py) and the golden
tensors, the renderer API's conventions, `.nam` files, errors and the GIL.

Run by scripts/test after `pip install ./crates/nam-py` into the project venv."""

import hashlib
import json
import math
import subprocess
import threading
import time
from pathlib import Path

import nam
import numpy as np
import pytest
import torch
from safetensors.numpy import load_file, save_file
from train_py import ggx
from train_py.export import load_model
from train_py.relight import relight as torch_relight

REPO = Path(__file__).resolve().parents[3]
FIXTURES = REPO / "tests" / "fixtures"
REAL_PHOTOS = REPO.parent / "shared" / "real_photos"

#: nam (Rust fast path, f32) against torch f32 on the same photo, log(1 + radiance): the U-Net's
#: fast-path tolerance (1e-4 relative, crates/nam-model/tests/parity.rs) carried through the
#: render MLP, with margin.
TORCH_LOG_TOL = 2e-3
#: The render network against the torch golden (log radiance), as parity.rs's RENDER_LOG_TOL:
#: for the typical query.
RENDER_LOG_TOL = 1e-4
#: ... and for the worst one: the facade recomputes the half vector from ωi and ωo in f32, which
#: the top encoding octave (2^15·π) amplifies (parity.rs's RECOMPUTED_HALF_VECTOR_TOL).
RECOMPUTED_HALF_VECTOR_TOL = 2e-2
#: f16 `.nam` params against the exact ones (f16 rounding, 11 significant bits).
F16_REL_TOL = 4.9e-4


@pytest.fixture(scope="module")
def model():
    return nam.Model.embedded()


def test_info_names_the_embedded_model(model):
    info = model.info()
    sha = hashlib.sha256((REPO / "models" / "default.safetensors").read_bytes()).hexdigest()
    assert info["sha256"] == sha
    # The file's own config (train_py reads it the same way) is the one home of the width.
    width = load_model(REPO / "models" / "default.safetensors").config.width
    assert info["width"] == width and info["param_channels"] == 64
    assert info["parameters"] > 100_000
    assert f"nam.Model(width={width}" in repr(model)


def real_photo(side: int) -> np.ndarray:
    from PIL import Image

    img = Image.open(REAL_PHOTOS / "dark-mush.png").convert("RGB").resize((side, side), Image.BILINEAR)
    return np.asarray(img, dtype=np.uint8)


@pytest.mark.parametrize(("light", "view"), [((1.0, 1.0, 4.0), (0.0, 0.0, 4.01)), ((-2.0, 0.5, 3.0), (1.0, -1.0, 2.0))])
def test_estimate_and_relight_match_torch(model, light, view):
    photo8 = real_photo(64)
    material = model.estimate(photo8)
    ours = nam.relight(model, material, light=light, view=view)
    linear = ggx.srgb_decode(torch.from_numpy(photo8.astype(np.float32) / 255.0))[None]
    theirs = torch_relight(load_model(REPO / "models" / "default.safetensors"), linear, light, view).numpy()
    err = np.abs(np.log1p(ours) - np.log1p(theirs)).max()
    assert ours.shape == (64, 64, 3) and ours.dtype == np.float32
    assert err < TORCH_LOG_TOL, err


def tiny_material_file(tmp_path: Path) -> tuple[Path, dict]:
    """The golden render queries' params as an 8×8 `.nam` material of the tiny model."""
    golden = load_file(str(FIXTURES / "net_tiny_golden.safetensors"))
    params = golden["r_params"].reshape(8, 8, 64)
    sha = hashlib.sha256((FIXTURES / "net_tiny.safetensors").read_bytes()).hexdigest()
    config = {"format": "nam-params", "version": 1, "height": 8, "width": 8, "model_sha256": sha}
    path = tmp_path / "golden.nam"
    save_file({"params": params}, str(path), metadata={"config": json.dumps(config)})
    return path, golden


def test_renderer_api_matches_the_torch_golden(tmp_path):
    path, golden = tiny_material_file(tmp_path)
    tiny = nam.Model.load(FIXTURES / "net_tiny.safetensors")
    material = nam.Material.load(path, model=tiny)
    n = golden["r_dirs"].shape[0]
    # Query q reads texel q: the centre of pixel (q // 8, q % 8).
    q = np.arange(n)
    uv = np.stack([(q % 8 + 0.5) / 8, (q // 8 + 0.5) / 8], axis=1).astype(np.float32)
    wi, wo = golden["r_dirs"][:, 0:3], golden["r_dirs"][:, 3:6]
    f_cos = material.eval(uv, wi, wo)
    # R = π·f_r·cos θi (DESIGN §3).
    ours = np.log1p(np.pi * f_cos)
    theirs = np.log1p(golden["r_radiance"])
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert up.sum() > n // 2
    err = np.abs(ours[up] - theirs[up])
    assert np.median(err) < RENDER_LOG_TOL
    assert err.max() < RECOMPUTED_HALF_VECTOR_TOL
    assert np.all(f_cos[~up] == 0)
    # f_r is eval / cos θi above the horizon (0 where cos θi ≤ 1e-6, the facade's guard).
    fr = material.eval_fr(uv, wi, wo)
    lit = up & (wi[:, 2] > 1e-6)
    np.testing.assert_allclose(fr[lit] * wi[lit, 2:3], f_cos[lit], rtol=1e-5, atol=1e-7)


def test_sampling_is_cosine_weighted_and_consistent_with_eval(model):
    material = model.estimate(real_photo(16))
    rng = np.random.default_rng(5)
    n = 4096
    uv = rng.random((n, 2), dtype=np.float32)
    wo = np.tile(np.array([[0.3, -0.2, 0.9327379]], dtype=np.float32), (n, 1))
    u = rng.random((n, 2), dtype=np.float32)
    wi, weight, pdf = material.sample(uv, wo, u)
    assert wi.shape == (n, 3) and weight.shape == (n, 3) and pdf.shape == (n,)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(pdf, wi[:, 2] / np.pi, rtol=1e-5)
    np.testing.assert_allclose(material.pdf(uv, wi, wo), pdf, rtol=1e-6)
    np.testing.assert_allclose(weight * pdf[:, None], material.eval(uv, wi, wo), rtol=1e-4, atol=1e-7)
    # Mean of cos θi under cosine sampling is 2/3.
    assert abs(wi[:, 2].mean() - 2 / 3) < 0.02
    # A viewer below the horizon gets no sample.
    below = material.sample(uv[:2], -wo[:2], u[:2])
    assert np.all(below[2] == 0) and np.all(below[1] == 0)


def test_relight_equals_eval_at_every_pixel_for_a_directional_light_and_orthographic_view(model):
    material = model.estimate(real_photo(16))
    to_light = np.array([0.4, 0.2, 0.8944272], dtype=np.float32)
    to_view = np.array([-0.3, 0.1, 0.9486833], dtype=np.float32)
    image = nam.relight(
        model, material, light=to_light, view=to_view, directional=True, orthographic=True, intensity=2.0
    )
    rows, cols = np.meshgrid(np.arange(16), np.arange(16), indexing="ij")
    uv = np.stack([(cols.ravel() + 0.5) / 16, (rows.ravel() + 0.5) / 16], axis=1).astype(np.float32)
    f_cos = material.eval(uv, np.tile(to_light, (256, 1)), np.tile(to_view, (256, 1)))
    np.testing.assert_allclose(image.reshape(-1, 3), 2.0 * np.pi * f_cos, rtol=2e-3, atol=1e-6)


def test_materials_round_trip_through_nam_files_and_refuse_other_models(model, tmp_path):
    material = model.estimate(real_photo(16))
    exact = tmp_path / "m_exact.nam"
    material.save(exact, exact=True)
    again = nam.Material.load(exact)
    np.testing.assert_array_equal(again.params, material.params)
    small = tmp_path / "m.nam"
    material.save(small)
    assert small.stat().st_size < exact.stat().st_size * 0.55
    np.testing.assert_allclose(nam.Material.load(small).params, material.params, rtol=F16_REL_TOL, atol=6e-8)
    tiny = nam.Model.load(FIXTURES / "net_tiny.safetensors")
    with pytest.raises(ValueError, match="not by this model"):
        nam.Material.load(exact, model=tiny)


def test_params_are_a_read_only_view_of_the_material(model):
    material = model.estimate(real_photo(16))
    p = material.params
    assert p.shape == (16, 16, 64) and p.dtype == np.float32
    assert not p.flags.writeable and not p.flags.owndata
    with pytest.raises(ValueError):
        p[0, 0, 0] = 1.0
    # The same memory each time: a view, not a copy.
    assert np.shares_memory(material.params, p)
    del material
    assert np.isfinite(p).all()  # the array keeps the material alive


def test_float32_photos_are_linear_and_uint8_photos_srgb(model):
    photo8 = real_photo(16)
    linear = ggx.srgb_decode(torch.from_numpy(photo8.astype(np.float32) / 255.0)).numpy()
    a, b = model.estimate(photo8).params, model.estimate(linear.astype(np.float32)).params
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    # A wider field of view is another geometry: other params.
    assert np.abs(model.estimate(photo8, fov=45.0).params - a).max() > 1e-3


def test_keep_clipped_keeps_the_network_params_where_the_photo_clipped(model, tmp_path):
    from PIL import Image

    photo8 = real_photo(16) // 2
    photo8[4:8, 5:9] = 255
    filled, kept = model.estimate(photo8).params, model.estimate(photo8, keep_clipped=True).params
    clipped = (photo8 == 255).any(-1)
    np.testing.assert_array_equal(filled[~clipped], kept[~clipped])
    assert np.abs(filled[clipped] - kept[clipped]).max() > 1e-3
    path = tmp_path / "blob.png"
    Image.fromarray(photo8).save(path)
    np.testing.assert_array_equal(model.estimate_file(path, keep_clipped=True).params, kept)


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda m, mat: m.estimate(np.zeros((8, 8, 3), np.float64)), TypeError, "uint8.*float32"),
        (lambda m, mat: m.estimate(np.zeros((8, 9, 3), np.uint8)), ValueError, "square"),
        (lambda m, mat: m.estimate(np.zeros((8, 8), np.uint8)), ValueError, "H×W×3"),
        (lambda m, mat: m.estimate(np.full((8, 8, 3), np.nan, np.float32)), ValueError, "not finite"),
        (lambda m, mat: m.estimate(np.zeros((8, 8, 3), np.uint8), fov=500), ValueError, "field of view|fov"),
        (lambda m, mat: mat.eval(np.zeros((3, 2)), np.zeros((3, 3)), np.zeros((2, 3))), ValueError, "rows"),
        (lambda m, mat: mat.eval(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))), ValueError, "N×2"),
        (lambda m, mat: mat.eval(np.zeros(2), np.zeros(3), np.zeros(3)), ValueError, "N×2"),
        (lambda m, mat: mat.eval([[0.5, 0.5]], [[np.nan, 0, 1]], [[0, 0, 1]]), ValueError, "finite"),
        (lambda m, mat: mat.eval([[0.5, 0.5]], [[0, 0, 0]], [[0, 0, 1]]), ValueError, None),
        (lambda m, mat: mat.eval("abc", [[0, 0, 1]], [[0, 0, 1]]), TypeError, "uv"),
        (lambda m, mat: nam.relight(m, mat, light=(0, 0, 1e39), view=(0, 0, 4)), ValueError, None),
        (lambda m, mat: nam.relight(m, mat, light=(0, 0, 4), view=(0, 0, 4), intensity=-1), ValueError, "intensity"),
        (lambda m, mat: nam.Model.load("/nonexistent/model.safetensors"), OSError, "nonexistent"),
        (lambda m, mat: nam.Material.load(FIXTURES / "net_tiny.safetensors"), ValueError, None),
    ],
)
def test_bad_input_is_a_python_error_never_a_crash(model, call, error, message):
    material = model.estimate(np.full((8, 8, 3), 100, np.uint8))
    with pytest.raises(error, match=message):
        call(model, material)


def test_lists_and_float64_are_accepted_and_converted(model):
    material = model.estimate(real_photo(8))
    a = material.eval([[0.5, 0.5]], [[0.0, 0.0, 1.0]], [[0.0, 0.6, 0.8]])
    b = material.eval(np.array([[0.5, 0.5]]), np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.6, 0.8]]))
    np.testing.assert_array_equal(a, b)


def test_the_gil_is_released_while_rust_computes(model):
    material = model.estimate(real_photo(128))
    ticks = 0
    done = threading.Event()

    def count():
        nonlocal ticks
        while not done.is_set():
            ticks += 1
            time.sleep(0)

    counter = threading.Thread(target=count)
    counter.start()
    try:
        start = ticks
        for _ in range(3):
            nam.relight(model, material, light=(1.0, 1.0, 3.0), view=(0.0, 0.0, 4.01))
        during = ticks - start
    finally:
        done.set()
        counter.join()
    # Holding the GIL, the counter could only run between the three calls.
    assert during > 100, during


def srgb8(linear: np.ndarray) -> np.ndarray:
    """What `nam-cli relight -o x.png` stores: sRGB-encoded, clamped, 8 bits."""
    encoded = ggx.srgb_encode(torch.from_numpy(np.clip(linear, 0, 1))).numpy()
    return np.round(encoded * 255).astype(np.int32)


def test_relight_of_the_bundled_photo_equals_nam_cli(model, tmp_path):
    from PIL import Image

    photo = REPO / "assets" / "example_photo.png"
    binary = REPO / "target" / "debug" / "nam-cli"
    if not binary.exists():
        # scripts/test runs `cargo test --workspace` first, which builds it; alone, build it.
        subprocess.run(["cargo", "build", "--locked", "-q", "-p", "nam-cli"], cwd=REPO, check=True)
    out = tmp_path / "cli.png"
    cli = [binary, "relight", photo, "--light", "1.5,1.0,3.5", "--view", "0,0,4.01"]
    subprocess.run([*cli, "-o", out], check=True, capture_output=True)
    theirs = np.asarray(Image.open(out).convert("RGB"), dtype=np.int32)
    ours = srgb8(nam.relight(model, model.estimate_file(photo), light=(1.5, 1.0, 3.5), view=(0.0, 0.0, 4.01)))
    # The same Rust computation: equal up to a code value where encoding rounds differently.
    assert np.abs(ours - theirs).max() <= 1
    assert (ours == theirs).mean() > 0.99


def chi2_p_value(observed: np.ndarray, expected: np.ndarray) -> float:
    """p-value of Pearson's χ² for the binned counts (bins expected below 5 merged), by the
    Wilson–Hilferty normal approximation of the χ² distribution."""
    order = np.argsort(expected)
    obs, exp = observed[order].astype(float), expected[order]
    merged_o, merged_e, acc_o, acc_e = [], [], 0.0, 0.0
    for o, e in zip(obs, exp, strict=True):
        acc_o, acc_e = acc_o + o, acc_e + e
        if acc_e >= 5:
            merged_o.append(acc_o)
            merged_e.append(acc_e)
            acc_o = acc_e = 0.0
    if acc_e > 0:
        merged_o[-1] += acc_o
        merged_e[-1] += acc_e
    o, e = np.array(merged_o), np.array(merged_e)
    stat, dof = float(((o - e) ** 2 / e).sum()), len(o) - 1
    z = ((stat / dof) ** (1 / 3) - (1 - 2 / (9 * dof))) / math.sqrt(2 / (9 * dof))
    return 0.5 * math.erfc(z / math.sqrt(2))


def test_sample_matches_pdf_by_chi_square_and_the_pdf_integrates_to_one(model):
    # As pbrt-v4's BSDF tests: histogram of sampled (cos θ, φ) against the pdf integrated
    # over each bin (midpoint rule on a 4×4 sub-grid per bin).
    material = model.estimate(real_photo(16))
    rng = np.random.default_rng(11)
    n, bins_t, bins_p = 200_000, 10, 20
    uv = np.tile(np.array([[0.3, 0.6]], np.float32), (n, 1))
    wo = np.tile(np.array([[0.5, 0.1, 0.8602325]], np.float32), (n, 1))
    wi, _, _ = material.sample(uv, wo, rng.random((n, 2), dtype=np.float32))
    phi = np.mod(np.arctan2(wi[:, 1], wi[:, 0]), 2 * np.pi)
    observed, _, _ = np.histogram2d(wi[:, 2], phi, bins=[bins_t, bins_p], range=[[0, 1], [0, 2 * np.pi]])
    sub = 4
    ct = (np.arange(bins_t * sub) + 0.5) / (bins_t * sub)
    cp = (np.arange(bins_p * sub) + 0.5) / (bins_p * sub) * 2 * np.pi
    t, p = np.meshgrid(ct, cp, indexing="ij")
    r = np.sqrt(1 - t * t)
    dirs = np.stack([r * np.cos(p), r * np.sin(p), t], axis=-1).reshape(-1, 3).astype(np.float32)
    m = dirs.shape[0]
    pdf = material.pdf(np.tile(uv[:1], (m, 1)), dirs, np.tile(wo[:1], (m, 1))).reshape(bins_t * sub, bins_p * sub)
    # dω = d(cos θ) dφ on the grid.
    cell = (1 / (bins_t * sub)) * (2 * np.pi / (bins_p * sub))
    expected = (pdf * cell).reshape(bins_t, sub, bins_p, sub).sum(axis=(1, 3)) * n
    assert abs(expected.sum() / n - 1) < 1e-3  # the pdf integrates to 1 over the hemisphere
    assert chi2_p_value(observed.ravel(), expected.ravel()) > 0.01
    # Monte Carlo: the mean of pdf / (uniform hemisphere pdf) over uniform directions is 1.
    u = rng.random((n, 2))
    z = u[:, 0]
    s = np.sqrt(1 - z * z)
    uniform = np.stack([s * np.cos(2 * np.pi * u[:, 1]), s * np.sin(2 * np.pi * u[:, 1]), z], axis=1).astype(np.float32)
    mc = material.pdf(uv, uniform, wo).mean() * 2 * np.pi
    assert abs(mc - 1) < 0.01, mc
