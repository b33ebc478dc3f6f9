"""Decoder pretraining (stage 1), the latent regression (stage 2) and the highlight test."""

import torch

from train_py import ggx, highlights, pretrain
from train_py.model import CONFIGS, NamModel
from train_py.train import latent_l1, load_decoder


def test_mirror_queries_sit_near_the_mirror_direction_and_all_are_unit_upper():
    gen = torch.Generator().manual_seed(0)
    maps = pretrain.random_maps(gen, 4000)
    wi, wo = pretrain.random_directions(gen, maps)
    torch.testing.assert_close(torch.linalg.vector_norm(wi, dim=-1), torch.ones(4000))
    assert (wi[:, 2] >= 0).all() and (wo[:, 2] >= 0).all()
    n = maps["normal"]
    mirror = ggx.normalize(2 * ggx.dot(wo, n)[:, None] * n - wo)
    close = ggx.dot(wi, mirror) > 0.95
    share = float(close.float().mean())
    assert pretrain.MIRROR_FRAC * 0.7 < share < pretrain.MIRROR_FRAC + 0.2, share
    assert maps["roughness"].min() >= pretrain.ROUGHNESS_MIN * 0.999


def test_a_few_pretraining_steps_lower_the_held_out_error(tmp_path):
    torch.manual_seed(0)
    decoder = pretrain.Decoder()
    val = pretrain.held_out(2048, seed=3)
    before = pretrain.evaluate(decoder, val)["log_l1"]
    opt = torch.optim.Adam(decoder.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(1)
    for _ in range(40):
        maps, dirs, target = pretrain.queries(gen, 1024)
        loss = (decoder(maps, dirs) - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = pretrain.evaluate(decoder, val)
    assert after["log_l1"] < 0.7 * before, (before, after)
    assert after["diffuse_only"] > 0


def test_exported_decoder_starts_the_model_and_gives_the_latent_target(tmp_path):
    decoder = pretrain.Decoder()
    opt = torch.optim.Adam(decoder.parameters())
    pretrain.save(tmp_path / "ckpt.pt", decoder, opt, {"step": 7, "elapsed": 60.0})
    pretrain.export(tmp_path / "ckpt.pt", str(tmp_path / "decoder.safetensors"))
    model = NamModel(CONFIGS["tiny"])
    encoder = load_decoder(str(tmp_path / "decoder.safetensors"), model)
    for name in ("nd_enc", "render"):
        for key, v in getattr(model, name).state_dict().items():
            torch.testing.assert_close(v, decoder.state_dict()[f"{name}.{key}"])
    maps = {k: v.reshape(1, 4, 4, *v.shape[1:]) for k, v in pretrain.random_maps(torch.Generator(), 16).items()}
    target = encoder(maps).permute(0, 3, 1, 2)
    assert float(latent_l1(target, encoder, maps)) == 0.0
    assert float(latent_l1(target + 0.5, encoder, maps)) == 0.5
    assert not any(p.requires_grad for p in encoder.parameters())


def test_blurred_peak_finds_a_moved_highlight_and_the_clipped_ratio():
    img = torch.zeros(64, 64, 3)
    img[40, 12] = 50.0
    img += 0.1
    assert highlights.blurred_peak(img) == (40, 12)
    clipped = torch.zeros(64, 64, dtype=torch.bool)
    clipped[:4, :4] = True
    dist, bright, ratio = highlights.score(img * 2, img, clipped)
    assert dist == 0 and abs(bright - 2) < 1e-5 and abs(ratio - 2) < 1e-5
    assert highlights.score(img, img, torch.zeros_like(clipped))[2] is None


def test_peak_brightness_fails_a_relight_whose_highlight_is_in_place_but_dim():
    # A diffuse-looking relight: its brightest spot is where the truth's highlight is, at 1/20 of it.
    truth = torch.full((64, 64, 3), 0.1)
    truth[30:34, 20:24] = 20.0
    dim = truth.clone()
    dim[30:34, 20:24] = 1.0
    dist, bright, _ = highlights.score(dim, truth, torch.zeros(64, 64, dtype=torch.bool))
    assert dist == 0
    assert 0.05 < bright < 0.1  # the blur mixes in the 0.1 around the highlight


def test_highlight_oracle_scores_perturbed_true_maps_and_flat_normals_miss_peaks():
    # Two glossy test sets at 64²: every perturbation is scored on the 8 cases; a specular scale
    # leaves every peak in place, while flat normals move some of them.
    table, cases = highlights.oracle(64, 2)
    assert cases == 8
    rows = {name: (share, median) for name, share, median in table}
    assert list(rows) == [name for name, _ in highlights.PERTURBATIONS]
    assert rows["specular × 1.5"][0] == 1.0
    assert rows["normals flat"][0] < 1.0 and rows["normals flat"][1] > 0.0
    md = highlights.oracle_markdown(list((n, s, m) for n, (s, m) in rows.items()), 64, 8, 1.0)
    assert "| normals flat |" in md


def test_scene_queries_are_pixels_of_training_materials_relit_by_ggx():
    # Each query's target must be the GGX radiance of its own pixel's maps under its own
    # directions: an index mix-up between materials, exemplars and pixels breaks this.
    gen = torch.Generator().manual_seed(4)
    maps, dirs, target = pretrain.SceneQueries(None)(gen, 2048)
    assert dirs.shape == (2048, 9) and target.shape == (2048, 3)
    assert torch.isfinite(target).all() and (target >= 0).all()
    wi, wo = dirs[:, 0:3], dirs[:, 3:6]
    radiance = ggx.ggx_radiance(maps["diffuse"], maps["specular"], maps["roughness"], maps["normal"], wi, wo)
    torch.testing.assert_close(ggx.to_log(radiance), target, atol=1e-6, rtol=1e-5)
    # Half the materials have flat normals, the rest the procedural generator's tilted ones.
    assert (maps["normal"][:, 2] == 1).any() and (maps["normal"][:, 2] < 0.999).any()


def test_from_model_fits_only_the_map_encoder_to_a_frozen_decoder(tmp_path):
    from train_py.export import save_model
    from train_py.tests.test_widen import random_folded

    model = random_folded(4, True)
    save_model(dict(model.state_dict()), model.config, tmp_path / "m.safetensors")
    encoders = {}
    for minutes in ("0", "0.05"):  # no step (E as initialised), then a few steps
        out = tmp_path / f"enc{minutes}"
        args = ["--from-model", str(tmp_path / "m.safetensors"), "--queries", "scenes", "--out", str(out)]
        pretrain.main([*args, "--minutes", minutes, "--batch", "512", "--val-every", "1000"])
        pretrain.main([*args, "--export", str(out / "enc.safetensors")])
        saved = pretrain.load_state(out / "enc.safetensors")
        for name in ("nd_enc", "render"):
            for key, v in getattr(model, name).state_dict().items():
                torch.testing.assert_close(saved[f"{name}.{key}"], v)
        encoders[minutes] = saved["enc.l0.weight"]
    assert not torch.equal(encoders["0"], encoders["0.05"])
    # Resuming without the frozen decoder would train a different network: refused.
    try:
        pretrain.main(["--queries", "scenes", "--out", str(out), "--resume", "--minutes", "0.01"])
    except SystemExit as e:
        assert "--from-model" in str(e)
    else:
        raise AssertionError("resume without --from-model was accepted")


def test_anchored_scene_queries_give_the_models_own_params_at_the_drawn_pixels():
    from train_py.train import draw_batch, draw_seeds_and_size

    class PixelIndex(torch.nn.Module):
        """Params whose first channel is each pixel's flat index (material, row, column)."""

        def estimate(self, net_input):
            b, _, h, w = net_input.shape
            return torch.arange(b * h * w, dtype=torch.float64).reshape(b, 1, h, w).expand(-1, 64, -1, -1)

    source = pretrain.SceneQueries(None, model=PixelIndex())
    maps, _, _ = source(torch.Generator().manual_seed(2), 512)
    assert source.anchor.shape == (512, 64)
    # The same materials again: each query's maps must be those of the pixel its anchor names.
    seeds, size = draw_seeds_and_size(
        torch.Generator().manual_seed(2), pretrain.SCENE_MATERIALS, [], pretrain.SCENE_SIZE
    )
    full, _, _ = draw_batch(seeds, size, "cpu", None, source.mix)
    index = source.anchor[:, 0].long()
    assert index.unique().numel() > 100
    for key, v in full.items():
        torch.testing.assert_close(v.reshape(-1, *v.shape[3:])[index], maps[key])


def test_anchor_needs_a_model_and_scene_queries():
    for argv in (["--anchor", "0.1"], ["--anchor", "0.1", "--from-model", "m.safetensors"]):
        try:
            pretrain.parse_args(argv)
        except SystemExit:
            continue
        raise AssertionError(f"{argv} was accepted")
