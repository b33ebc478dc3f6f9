"""Real material sets, their augmentation, and phone-like captures."""

import math
import os
import subprocess
import sys

import pytest
import torch

from train_py import capture, gen, ggx, materials, train
from train_py.train import CaptureStream, DataMix, draw_batch, make_batch

from .conftest import REPO


def test_orientations_turn_the_normals_with_the_image():
    # Rotating/flipping the height field and then deriving normals must equal transforming the
    # normals of the original: a wrong sign would light every augmented crop from the wrong side.
    rng = gen.Rng(3)
    height = gen.fbm(rng, 32, 4, 3)
    maps = {"normal": gen.height_to_normal(height, 0.05), "roughness": height}
    for k in range(4):
        for flip in (False, True):
            h = height.flip(1) if flip else height
            want = gen.height_to_normal(torch.rot90(h, k, dims=(0, 1)), 0.05)
            got = materials.orient(maps, k, flip)["normal"]
            torch.testing.assert_close(got[1:-1, 1:-1], want[1:-1, 1:-1], atol=1e-6, rtol=0)
    assert not torch.allclose(materials.orient(maps, 1, False)["normal"], maps["normal"])


def test_real_crops_are_valid_maps_and_deterministic_per_seed():
    bank = materials.MaterialBank("train", side=64)
    assert len(bank) >= 50
    a = materials.batch(bank, [5, 6, 7], 32)
    b = materials.batch(bank, [5, 6, 7], 32)
    for key, v in a.items():
        torch.testing.assert_close(v, b[key], rtol=0, atol=0)
        assert torch.isfinite(v).all()
    assert a["diffuse"].shape == (3, 32, 32, 3) and a["roughness"].shape == (3, 32, 32)
    assert a["diffuse"].min() >= 0 and a["diffuse"].max() <= 1
    assert a["roughness"].min() >= 0.02 and a["roughness"].max() <= 1
    torch.testing.assert_close(torch.linalg.vector_norm(a["normal"], dim=-1), torch.ones(3, 32, 32))
    assert (a["normal"][..., 2] > 0).all()


def test_test_split_is_disjoint_from_train():
    train = {p.name for p in materials.list_files("train")}
    test = {p.name for p in materials.list_files("test")}
    assert test and not train & test
    # Both tiles of one source asset stay in one split.
    assert not {n.rsplit("_", 2)[0] for n in train} & {n.rsplit("_", 2)[0] for n in test if "_0_" in n or "_1_" in n}


def test_pack_round_trips_at_the_requested_side(tmp_path):
    materials.pack(tmp_path, 16)
    assert len(materials.list_files("test", tmp_path)) == len(materials.list_files("test"))
    packed = materials.load_panels(materials.list_files("train", tmp_path)[0])
    assert packed.shape == (4, 16, 16, 3)


def test_capture_distance_follows_the_field_of_view():
    assert math.isclose(ggx.capture_distance(28.0), ggx.CAPTURE_DISTANCE, rel_tol=0, abs_tol=0)
    d45 = ggx.capture_distance(45.0)
    assert math.isclose(d45, 1 / math.tan(math.radians(22.5)), rel_tol=1e-15)
    hz = ggx.capture_half_z(4, 4, torch.float64, distance=d45)
    x = 2 * 0.5 / 4 - 1  # corner pixel centre
    assert math.isclose(float(hz[0, 0]), d45 / math.sqrt(2 * x * x + d45 * d45), rel_tol=1e-12)
    inp = ggx.network_input(torch.full((1, 4, 4, 3), 0.5), "ldr", d45)
    torch.testing.assert_close(inp[0, 3], hz.float())


def test_phone_capture_clips_quantises_and_keeps_maps_consistent():
    rng = gen.Rng(9)
    maps = gen.batch([1, 2], 32)
    cap = capture.Capture(fov=45.0, flash_x=0.1, flash_y=-0.05)
    exposed, net_input = capture.photograph(maps, cap, rng)
    assert net_input.shape == (2, 4, 32, 32)
    photo = torch.expm1(net_input[:, :3])
    assert photo.max() <= ggx.LDR_MAX + 1e-6 and photo.min() >= 0
    codes = ggx.srgb_encode(photo) * 255
    assert (codes - codes.round()).abs().max() < 1e-3  # 8-bit values
    torch.testing.assert_close(net_input[0, 3], ggx.capture_half_z(32, 32, distance=cap.distance))
    for key in ("diffuse", "specular"):
        assert exposed[key].min() >= 0 and exposed[key].max() <= 1
        ratio = exposed[key].sum() / maps[key].sum()
        assert 1 / capture.EXPOSURE_LIMIT - 1e-4 <= ratio <= capture.EXPOSURE_LIMIT + 1e-4
    assert exposed["roughness"] is maps["roughness"]


def test_exposure_puts_the_photo_median_on_the_asked_grey_within_the_limit():
    maps = gen.batch([3], 32)
    cap = capture.Capture()
    natural = float(capture.render(maps, cap).mean(-1).median())
    assert max(float(maps["diffuse"].max()), float(maps["specular"].max())) * 1.5 < 1  # no clamp at 1
    goal = 1.5 * natural
    exposed = capture.expose(maps, cap, gen.Rng(1), exposure=(goal, goal))
    assert math.isclose(float(capture.render(exposed, cap).mean(-1).median()), goal, rel_tol=1e-3)
    far = 10 * capture.EXPOSURE_LIMIT * natural
    exposed = capture.expose(maps, cap, gen.Rng(1), exposure=(far, far))
    torch.testing.assert_close(exposed["diffuse"], (maps["diffuse"] * capture.EXPOSURE_LIMIT).clamp(max=1))


def test_exposure_median_flag_takes_a_range_of_radiance_and_refuses_others():
    assert train.parse_args(["--phone", "--exposure-median", "0.01,0.8"]).exposure_median == (0.01, 0.8)
    assert train.parse_args([]).exposure_median == capture.EXPOSURE_MEDIAN
    flags = "--real-frac 0.5 --phone --flat-normal-frac 0.25 --exposure-median 0.1,0.2"
    args = train.parse_args(flags.split())
    assert DataMix.from_args(args) == DataMix(0.5, 1.0, 0.25, (0.1, 0.2))
    assert DataMix.from_args(train.parse_args([])) == DataMix()
    for bad in ("0.5", "0.8,0.1", "0,0.5", "0.1,1.5", "a,b"):
        with pytest.raises(SystemExit):
            train.parse_args(["--exposure-median", bad])


def test_random_captures_cover_the_field_of_view_range_and_flash_offsets():
    g = torch.Generator().manual_seed(0)
    caps = [capture.Capture.random(g) for _ in range(200)]
    fovs = torch.tensor([c.fov for c in caps])
    offsets = torch.tensor([math.hypot(c.flash_x, c.flash_y) for c in caps])
    assert fovs.min() >= capture.FOV_RANGE[0] and fovs.max() <= capture.FOV_RANGE[1]
    assert fovs.max() - fovs.min() > 0.8 * (capture.FOV_RANGE[1] - capture.FOV_RANGE[0])
    assert offsets.max() <= capture.FLASH_OFFSET_MAX and offsets.max() > 0.5 * capture.FLASH_OFFSET_MAX


def test_draw_batch_mixes_real_and_procedural_materials():
    bank = materials.MaterialBank("train", side=64)
    maps, net_input, cap = draw_batch([3, 4, 5, 6], 32, "cpu", bank, DataMix(0.5, phone=1.0))
    assert net_input.shape == (4, 4, 32, 32) and maps["normal"].shape == (4, 32, 32, 3)
    assert capture.FOV_RANGE[0] <= cap.fov <= capture.FOV_RANGE[1]
    plain, plain_input, plain_cap = draw_batch([3, 4], 32, "cpu", None, DataMix())
    assert plain_cap == capture.Capture()
    want_maps, want_input = make_batch([3, 4], 32, "cpu")
    torch.testing.assert_close(plain["diffuse"], want_maps["diffuse"])
    torch.testing.assert_close(plain_input, want_input)


def test_flat_normal_frac_flattens_whole_materials_before_their_capture():
    flat, flat_input, _ = draw_batch(list(range(10, 30)), 16, "cpu", None, DataMix(flat_normal_frac=0.5))
    tilted, tilted_input, _ = draw_batch(list(range(10, 30)), 16, "cpu", None, DataMix())
    is_flat = (flat["normal"][..., 2] == 1).flatten(1).all(1)
    assert 0 < int(is_flat.sum()) < 20  # some materials, not all (20 draws at 0.5)
    torch.testing.assert_close(flat["diffuse"], tilted["diffuse"])
    torch.testing.assert_close(flat["normal"][~is_flat], tilted["normal"][~is_flat])
    # The photo is of the flattened material: a flat one's differs from its tilted original's.
    changed = (flat_input - tilted_input).abs().flatten(1).amax(1) > 0
    assert changed[is_flat].any() and not changed[~is_flat].any()


def test_capture_stream_draws_seeded_batches_per_worker_at_the_given_sizes():
    bank = materials.MaterialBank("train", side=64)
    stream = CaptureStream(5, 3, [16, 24], 16, bank, DataMix(0.5, phone=1.0))
    first = [b for b, _ in zip(stream, range(6), strict=False)]
    again = [b for b, _ in zip(stream, range(6), strict=False)]
    assert {b[0] for b in first} == {16, 24}
    for (size, maps, net_input, cap), (size2, _, net_input2, cap2) in zip(first, again, strict=True):
        assert net_input.shape == (3, 4, size, size) and maps["normal"].shape == (3, size, size, 3)
        assert size == size2 and cap == cap2
        torch.testing.assert_close(net_input, net_input2)
    # Two DataLoader workers draw different streams (each its own seed), both at the given sizes.
    loader = torch.utils.data.DataLoader(stream, batch_size=None, num_workers=2)
    batches = [b for b, _ in zip(loader, range(4), strict=False)]
    assert all(b[0] in (16, 24) for b in batches)
    assert not torch.equal(batches[0][1]["diffuse"], batches[1][1]["diffuse"])
    # Two DDP ranks: their own materials, one crop size per step.
    ranks = [CaptureStream(5, 3, [16, 24], 16, bank, DataMix(0.5, phone=1.0), rank, 2) for rank in (0, 1)]
    r0, r1 = ([b for b, _ in zip(r, range(6), strict=False)] for r in ranks)
    assert [b[0] for b in r0] == [b[0] for b in r1] and {b[0] for b in r0} == {16, 24}
    assert not any(torch.equal(a[2], b[2]) for a, b in zip(r0, r1, strict=True))


def test_train_gpu_script_runs_end_to_end_on_the_cpu(tmp_path):
    # scripts/train-gpu is run on a CUDA machine without ../shared: it must work from a pack.
    materials.pack(tmp_path / "pack", 32)
    env = dict(os.environ, NAM_MATERIALS=str(tmp_path / "pack"), OUT=str(tmp_path / "out"), PYTHON=sys.executable)
    # One DataLoader worker, as a GPU run draws its batches (scripts/train-gpu: cores - 2 on CUDA).
    cmd = [str(REPO / "scripts" / "train-gpu"), "--device", "cpu", "--minutes", "0.05", "--batch", "2"]
    cmd += ["--workers", "1", "--quick-eval"]
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    out = tmp_path / "out"
    assert (out / "default.safetensors").stat().st_size > 1_000_000
    for which in ("old", "new"):
        for table in ("eval", "test", "highlights"):
            assert "| model |" in (out / f"{which}.{table}.md").read_text()
    assert "done:" in (out / "train.log").read_text()


def test_phone_share_mixes_ideal_and_phone_steps():
    bank = materials.MaterialBank("train", side=64)
    caps = [draw_batch([s, s + 1], 16, "cpu", bank, DataMix(0.5, phone=0.5))[2] for s in range(0, 40, 2)]
    ideal = sum(c == capture.Capture() for c in caps)
    assert 0 < ideal < len(caps)  # both kinds of step (20 draws at 0.5)
    # An ideal step is the plain capture of the same materials.
    seeds = next([s, s + 1] for s, c in zip(range(0, 40, 2), caps, strict=True) if c == capture.Capture())
    maps, net_input, _ = draw_batch(seeds, 16, "cpu", bank, DataMix(0.5, phone=0.5))
    want_maps, want_input, _ = draw_batch(seeds, 16, "cpu", bank, DataMix(0.5))
    torch.testing.assert_close(maps["diffuse"], want_maps["diffuse"])
    torch.testing.assert_close(net_input, want_input)


def test_shares_outside_zero_to_one_are_refused():
    for flag in ("--phone-frac", "--real-frac", "--flat-normal-frac"):
        with pytest.raises(SystemExit):
            train.parse_args(["--phone", flag, "1.5"])


def test_phone_capture_flags_without_phone_are_refused():
    for extra in (["--phone-frac", "0.5"], ["--exposure-median", "0.1,0.3"]):
        with pytest.raises(SystemExit):
            train.parse_args(extra)
        assert train.parse_args(["--phone", *extra]).phone
