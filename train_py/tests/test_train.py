"""Training pieces: Reflect sampling, pixel selection, loss decrease, DDP with one and two processes, evaluation."""

import dataclasses
import os
import subprocess
import sys

import pytest
import torch

from train_py import ggx, protocols
from train_py.evaluate import evaluate_protocols, ssim
from train_py.export import fold_state_dict, freeze_batchnorm, load_checkpoint, load_model, save_model, unfold_model
from train_py.model import CONFIGS, Conv, NamModel
from train_py.train import (
    RANK_SEED_STRIDE,
    RUN_SEED_STRIDE,
    ActivationExcess,
    MapProbe,
    TrainStep,
    agreed_progress,
    bottleneck_excess,
    capture_clipped,
    chroma_l1,
    display_l1,
    draw_seeds_and_size,
    exemplar_targets,
    gather_rows,
    highlight_weights,
    make_batch,
    maps_l1,
    select_pixels,
    select_shared_pixels,
    specular_share,
    weight_average,
    weighted_mean,
    with_input_skip,
)

from .conftest import REPO


def test_reflect_sampling_puts_mirror_highlight_at_sampled_point():
    g = torch.Generator().manual_seed(1)
    light, view = protocols.reflect(g, 3, 50)
    assert (light[..., 2] > 0).all() and (view[..., 2] >= 0).all()
    torch.testing.assert_close(torch.linalg.vector_norm(view, dim=-1), torch.full((3, 50), ggx.CAPTURE_DISTANCE))
    # p is where the view → mirrored-light line crosses z = 0; there the mirror condition must hold.
    t = view[..., 2] / (view[..., 2] + light[..., 2])
    p = view + t[..., None] * (light - view)
    p[..., 2] = 0.0
    wi, wo = ggx.normalize(light - p), ggx.normalize(view - p)
    torch.testing.assert_close(wi[..., :2], -wo[..., :2], atol=1e-4, rtol=0)
    dist = torch.linalg.vector_norm(light - p, dim=-1)
    assert dist.min() >= protocols.REFLECT_MIN_DIST - 1e-4


def test_hemisphere_protocol_positions_lie_on_radius_4():
    light, view = protocols.hemisphere(torch.Generator().manual_seed(2), 2, 64)
    torch.testing.assert_close(torch.linalg.vector_norm(light, dim=-1), torch.full((2, 64), 4.0))
    assert (view[..., 2] >= 0).all()


def test_pixel_selection_prefers_low_norm_params_without_repeats():
    params = torch.ones(1, 64, 8, 8)
    params[:, :, :4] *= 100.0  # top half: "garbage" high-norm parameters
    idx = select_pixels(params, 4, 0.25, torch.Generator().manual_seed(0))
    assert idx.shape == (1, 4, 16)
    for k in range(4):
        assert len(set(idx[0, k].tolist())) == 16
    assert (idx >= 32).float().mean() > 0.9


def test_a_few_training_steps_beat_predicting_zero_on_a_fixed_batch():
    # Predicting 0 everywhere scores mean|target| (most Reflect pixels are dark); a dead final
    # LeakyReLU converges to exactly that, so "the loss went down" alone proves nothing.
    torch.manual_seed(0)
    model = NamModel(CONFIGS["tiny"])
    step = TrainStep(model)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    maps, net_input = make_batch([11, 12], 32, "cpu")
    g = torch.Generator().manual_seed(0)
    light, view = protocols.reflect(g, 2, 2)
    losses, zero = [], []
    for _ in range(60):
        pred, target = step(net_input, 2, 0.6, torch.Generator().manual_seed(5), maps, light, view)
        loss = (pred - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        zero.append(float(target.abs().mean()))
    assert sum(losses[-4:]) / 4 < 0.2 * losses[0]
    assert sum(losses[-4:]) < 0.85 * sum(zero[-4:])


def test_torchrun_single_process_trains_and_writes_checkpoint(tmp_path):
    env = dict(os.environ, WORLD_SIZE="1", RANK="0", LOCAL_RANK="0", MASTER_ADDR="127.0.0.1", MASTER_PORT="29517")
    cmd = [
        sys.executable,
        "-m",
        "train_py.train",
        "--config",
        "tiny",
        "--steps",
        "2",
        "--size",
        "32",
        "--batch",
        "2",
        "--outputs",
        "2",
        "--out",
        str(tmp_path),
        "--val-every",
        "0",
        "--threads",
        "1",
    ]
    subprocess.run(cmd, cwd=REPO, env=env, check=True, capture_output=True, timeout=120)
    ckpt = torch.load(tmp_path / "ckpt.pt", weights_only=False)
    assert ckpt["step"] == 2
    resumed = subprocess.run(
        [*cmd[:6], "3", *cmd[7:], "--resume"],
        cwd=REPO,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "resumed" in resumed.stdout
    assert torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] == 3


def test_torchrun_two_processes_train_on_a_time_budget_at_drawn_sizes(tmp_path):
    # DDP end to end on the CPU: the ranks agree when their clocks run out (agreed_progress, tested
    # on its own below; a rank that stopped alone would hang the other) and on each step's size.
    env = dict(os.environ, OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    cmd += ["-m", "train_py.train", "--config", "tiny", "--steps", "100000", "--cpu-minutes", "0.03"]
    cmd += ["--size", "32", "--sizes", "32,48", "--batch", "2", "--outputs", "2", "--out", str(tmp_path)]
    cmd += ["--val-every", "0", "--threads", "1"]
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "world=2" in done.stdout and torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] > 1


def _agreed_progress_on_rank(rank: int, port: int, results) -> None:
    import torch.distributed as dist

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=rank, world_size=2)
    results[rank] = agreed_progress([0.25, 1.0][rank], torch.device("cpu"))
    dist.destroy_process_group()


def test_agreed_progress_is_the_largest_over_the_ranks():
    import torch.multiprocessing as mp

    results = mp.Manager().dict()
    mp.spawn(_agreed_progress_on_rank, args=(29533, results), nprocs=2, join=True)
    assert dict(results) == {0: 1.0, 1: 1.0}


def test_ddp_ranks_draw_their_own_materials_at_one_crop_size():
    draws = []
    for rank in (0, 1):
        g = torch.Generator().manual_seed(11 * RUN_SEED_STRIDE + RANK_SEED_STRIDE * rank)
        size_g = torch.Generator().manual_seed(11)
        draws.append([draw_seeds_and_size(g, 4, [32, 48, 64], 32, size_g) for _ in range(12)])
    sizes = [[size for _, size in d] for d in draws]
    assert sizes[0] == sizes[1] and len(set(sizes[0])) > 1
    assert all(a != b for (a, _), (b, _) in zip(draws[0], draws[1], strict=True))


def test_ssim_is_one_for_identical_and_lower_for_noisy_images():
    a = torch.rand(1, 24, 24, 3)
    assert abs(float(ssim(a, a)) - 1.0) < 1e-5
    assert float(ssim(a, (a + 0.3 * torch.rand_like(a)).clamp(0, 1))) < 0.97
    assert float(ssim(a, torch.rand_like(a))) < 0.2


def test_evaluation_baselines_are_exact_where_they_should_be():
    res = evaluate_protocols(None, [1_000_000_123], 24, hemisphere_k=2, reflect_k=2, protocol_names=("identity",))
    # Identity re-creates the capture, so the printout error is only the LDR clamp + 8-bit rounding.
    assert res["identity"]["printout"]["log_l1"] < 0.05


def test_straight_through_output_keeps_values_and_passes_the_gradient_of_negative_outputs():
    model = NamModel(CONFIGS["tiny"])
    params = torch.randn(256, 64)
    dirs = torch.nn.functional.normalize(torch.randn(256, 9), dim=-1)
    plain = model.render_log(params, dirs)
    st = model.render_log(params, dirs, straight_through=True)
    torch.testing.assert_close(st, plain, rtol=0, atol=0)  # inference value unchanged
    assert (plain < 0).any() and (plain > 0).any()
    z = torch.tensor([-50.0, -1.0, 2.0], requires_grad=True)
    target = torch.tensor([0.3, 0.0, 0.1])
    model.render.l6.forward = lambda x: z  # feed chosen pre-activations to the final LeakyReLU
    out = model.render.forward(torch.zeros(3, 96), straight_through=True)
    (out - target).abs().sum().backward()
    # |z - t| gradient: negative outputs with a positive target are pushed up at full strength.
    torch.testing.assert_close(z.grad, torch.tensor([-1.0, -1.0, 1.0]))


def test_training_keeps_the_final_activation_alive():
    """With the true LeakyReLU(0.001) gradient every output goes negative within a few steps on
    Reflect exemplars (mostly dark targets) and the model then learns almost nothing."""
    model = NamModel(CONFIGS["tiny"])
    pre = {}
    model.render.l6.register_forward_hook(lambda mod, inp, out: pre.__setitem__("z", out.detach()))
    step = TrainStep(model)
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    maps, net_input = make_batch([3, 5], 32, "cpu")
    g = torch.Generator().manual_seed(0)
    for _ in range(12):
        light, view = protocols.reflect(g, 2, 4)
        pred, target = step(net_input, 4, 0.6, g, maps, light, view)
        loss = (pred - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float((pre["z"] < 0).float().mean()) < 0.8  # without straight-through: 1.0 (all dead)


@pytest.mark.parametrize(
    "mix",
    [
        protocols.mix_identity,
        protocols.mix_hemisphere,
        lambda g, light, view, frac: protocols.mix_moved_light(g, light, view, frac, torch.zeros(3)),
    ],
)
def test_exemplar_mixes_at_share_zero_keep_the_reflect_geometry(mix):
    light, view = protocols.reflect(torch.Generator().manual_seed(3), 8, 4)
    same_l, same_v = mix(torch.Generator().manual_seed(4), light, view, 0.0)
    assert torch.equal(same_l, light) and torch.equal(same_v, view)


def test_mix_identity_replaces_the_chosen_share_of_exemplars_by_the_capture_geometry():
    g = torch.Generator().manual_seed(3)
    light, view = protocols.reflect(g, 64, 32)
    mixed_l, mixed_v = protocols.mix_identity(g, light, view, 0.25)
    cam = torch.tensor([0.0, 0.0, ggx.CAPTURE_DISTANCE])
    is_cam = (mixed_l == cam).all(-1) & (mixed_v == cam).all(-1)
    assert 0.2 < float(is_cam.float().mean()) < 0.3
    kept = ~is_cam
    assert torch.equal(mixed_l[kept], light[kept]) and torch.equal(mixed_v[kept], view[kept])


def mirror_point_in_frame(light: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
    """Whether the flat surface's mirror point between ``light`` and ``view`` lies in [-1, 1]²."""
    lz, vz = light[..., 2:], view[..., 2:]
    p = (light[..., :2] * vz + view[..., :2] * lz) / (lz + vz)
    return (p.abs() <= 1).all(-1)


def test_moved_light_keeps_the_view_at_the_camera_and_puts_most_highlights_in_the_frame():
    g = torch.Generator().manual_seed(5)
    cam = torch.tensor([0.0, 0.0, ggx.capture_distance(45.0)])
    light, view = protocols.moved_light(g, 32, 64, cam)
    assert torch.equal(view, cam.expand_as(view))
    r = torch.linalg.vector_norm(light[..., :2] - cam[:2], dim=-1)
    assert float(r.min()) >= protocols.MOVED_LIGHT_RADIUS[0] - 1e-6
    assert float(r.max()) <= protocols.MOVED_LIGHT_RADIUS[1] + 1e-6
    assert float(light[..., 2].min()) >= 0.5
    moved_share = float(mirror_point_in_frame(light, view).float().mean())
    ref_l, ref_v = protocols.reflect(g, 32, 64)
    reflect_share = float(mirror_point_in_frame(ref_l, ref_v).float().mean())
    assert moved_share > 0.6 and reflect_share < 0.25, (moved_share, reflect_share)
    mixed_l, mixed_v = protocols.mix_moved_light(g, ref_l, ref_v, 0.3, cam)
    at_cam = (mixed_v == cam).all(-1)
    assert 0.25 < float(at_cam.float().mean()) < 0.35
    assert torch.equal(mixed_l[~at_cam], ref_l[~at_cam])


def test_mix_hemisphere_draws_the_chosen_share_independently_on_the_hemisphere():
    g = torch.Generator().manual_seed(6)
    light, view = protocols.reflect(g, 64, 32)
    mixed_l, mixed_v = protocols.mix_hemisphere(g, light, view, 0.4)
    replaced = (mixed_l != light).any(-1)
    assert 0.35 < float(replaced.float().mean()) < 0.45
    assert torch.equal(mixed_v[~replaced], view[~replaced])
    for pos in (mixed_l[replaced], mixed_v[replaced]):
        r = torch.linalg.vector_norm(pos, dim=-1)
        assert torch.allclose(r, torch.full_like(r, protocols.HEMISPHERE_RADIUS), atol=1e-5)
        assert float(pos[:, 2].min()) >= 0
    # Independent: unlike Reflect (light on the view's mirror path), light and view are uncorrelated.
    hemi_l, hemi_v = mixed_l[replaced], mixed_v[replaced]
    assert abs(float(torch.corrcoef(torch.stack([hemi_l[:, 0], hemi_v[:, 0]]))[0, 1])) < 0.1


def test_shared_geometry_step_is_the_per_material_step_with_one_nd_enc_per_exemplar_pixel():
    torch.manual_seed(0)
    model = NamModel(CONFIGS["tiny"])
    maps, net_input = make_batch([21, 22, 23], 16, "cpu")
    light, view = protocols.reflect(torch.Generator().manual_seed(4), 1, 3)
    pred, target = TrainStep(model, shared_geometry=True)(
        net_input, 3, 0.5, torch.Generator().manual_seed(9), maps, light, view
    )
    idx = select_shared_pixels(3, 16 * 16, 3, 0.5, torch.Generator().manual_seed(9), "cpu")
    assert idx.shape == (3, 3, 128) and torch.equal(idx[0], idx[2])
    assert all(len(set(row.tolist())) == 128 for row in idx[0])
    # The same rows through the per-material path (ND_enc evaluated for every material).
    lv = light.expand(3, 3, 3), view.expand(3, 3, 3)
    want_target, dirs, _ = exemplar_targets(maps, *lv, idx)
    params = model.estimate(net_input).permute(0, 2, 3, 1).reshape(3, -1, 64)
    want = model.render_log(gather_rows(params, idx).reshape(-1, 64), dirs.reshape(-1, 9), True)
    torch.testing.assert_close(target, want_target, rtol=0, atol=0)
    torch.testing.assert_close(pred, want.reshape(pred.shape), rtol=1e-5, atol=1e-6)
    assert not torch.equal(pred[0], pred[1])  # different materials, different radiance


def test_display_term_weighs_dark_colour_errors_and_ignores_what_a_display_clips():
    log = torch.log1p
    same = log(torch.tensor([[0.3, 0.01, 0.0]]))
    assert float(display_l1(same, same)) == 0.0
    # A dark red rendered grey: small in log space, ~3x larger on a display.
    target, grey = log(torch.tensor([[0.05, 0.02, 0.01]])), log(torch.tensor([[0.02, 0.02, 0.02]]))
    assert float(display_l1(grey, target)) > 3 * float((grey - target).abs().mean())
    # Both above display white: no display error (the log term still sees it).
    assert float(display_l1(log(torch.tensor([[5.0] * 3])), log(torch.tensor([[10.0] * 3])))) == 0.0
    black = torch.full((1, 3), 1e-7, requires_grad=True)  # near black
    display_l1(black, log(torch.tensor([[0.01] * 3]))).backward()
    # Bounded by the ε offset (without it d/dx x^(1/2.2) at 1e-7 is ~3e3).
    assert (black.grad < 0).all() and float(black.grad.abs().max()) < 10


def test_chroma_term_sees_colour_only_and_fades_out_on_dark_pixels():
    log = torch.log1p
    red = log(torch.tensor([[0.4, 0.05, 0.05]]))
    assert float(chroma_l1(red, red)) == 0.0
    # Brightness alone costs nothing (up to the ε offset); the same brightness in grey costs a lot.
    assert float(chroma_l1(log(torch.tensor([[0.8, 0.1, 0.1]])), red)) < 0.02
    grey = log(torch.tensor([[0.1667, 0.1667, 0.1667]]))
    assert float(chroma_l1(grey, red)) > 5 * float((grey - red).abs().mean())
    # The same colour error 100x darker weighs far less.
    dark_red, dark_grey = log(torch.tensor([[0.004, 0.0005, 0.0005]])), log(torch.tensor([[0.00167] * 3]))
    assert float(chroma_l1(dark_grey, dark_red)) < 0.5 * float(chroma_l1(grey, red))
    pred = grey.clone().requires_grad_(True)
    chroma_l1(pred, red).backward()
    assert pred.grad[0, 0] < 0 < pred.grad[0, 1]  # more red, less green


def test_training_from_a_model_file_keeps_its_batchnorms_frozen(tmp_path):
    init = tmp_path / "init.safetensors"
    m = NamModel(CONFIGS["tiny"]).eval()
    save_model(fold_state_dict(m), m.config, init, "f32")
    cmd = [sys.executable, "-m", "train_py.train", "--config", "tiny", "--steps", "2", "--size", "32"]
    cmd += ["--batch", "2", "--outputs", "2", "--val-every", "0", "--threads", "1", "--init-from", str(init)]
    run = subprocess.run([*cmd, "--out", str(tmp_path / "run")], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "BatchNorms frozen" in run.stdout
    ckpt = torch.load(tmp_path / "run" / "ckpt.pt", weights_only=False)
    assert ckpt["step"] == 2 and ckpt["frozen_bn"] is True
    start = unfold_model(init).state_dict()
    for name, t in ckpt["model"].items():
        if name.endswith(("running_mean", "running_var")):
            torch.testing.assert_close(t, start[name], rtol=0, atol=0)
    assert any(not torch.equal(t, start[n]) for n, t in ckpt["model"].items() if n.endswith("weight"))
    wrong = subprocess.run(
        [*cmd[:4], "small", *cmd[5:], "--out", str(tmp_path / "wrong")], cwd=REPO, capture_output=True, text=True
    )
    assert wrong.returncode != 0 and "does not match --config small" in wrong.stderr


def test_input_skip_fine_tune_starts_from_what_the_file_computes():
    m = NamModel(CONFIGS["tiny"]).eval()
    state = with_input_skip(m.state_dict(), had=False, wants=True)
    skip = NamModel(dataclasses.replace(CONFIGS["tiny"], input_skip=True)).eval()
    skip.load_state_dict(state)
    x = torch.rand(2, 4, 16, 24)
    with torch.no_grad():
        torch.testing.assert_close(skip.estimate(x), m.estimate(x), rtol=0, atol=0)
    assert with_input_skip(state, had=True, wants=True) is state


def test_bottleneck_penalty_acts_only_above_the_limit_and_only_while_training():
    e4 = torch.tensor([0.0, -100.0, 300.0, -500.0], requires_grad=True)
    loss = bottleneck_excess(e4, 200.0)
    torch.testing.assert_close(loss, torch.tensor((100.0 + 300.0) / 4 / 200.0))
    loss.backward()
    torch.testing.assert_close(e4.grad, torch.tensor([0.0, 0.0, 1.0, -1.0]) / 4 / 200.0)
    m = NamModel(CONFIGS["tiny"])
    x = torch.rand(1, 4, 16, 16)
    m.train()
    m.estimate(x)
    assert m.est.last_bottleneck.shape == (1, 32, 2, 2) and m.est.last_bottleneck.requires_grad
    m.eval()
    with torch.no_grad():
        m.estimate(x)
    assert m.est.last_bottleneck is None


def test_activation_penalty_sees_every_unet_tensor_and_only_while_training():
    torch.manual_seed(0)
    m = NamModel(CONFIGS["tiny"])
    x = torch.rand(1, 4, 16, 16) * 50
    penalty = ActivationExcess(m.est, 1e-3)
    m.train()
    m.estimate(x)
    loss = penalty.take()
    assert loss is not None and float(loss) > 0 and penalty.take() is None
    loss.backward()
    # Every conv of the U-Net gets a gradient from the penalty alone, BatchNorms frozen or not.
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for n, p in m.est.named_parameters() if "weight" in n)
    freeze_batchnorm(m)
    m.estimate(x)
    assert penalty.take() is not None
    m.eval()
    with torch.no_grad():
        m.estimate(x)
    assert penalty.take() is None
    # A limit above every activation costs nothing.
    loose = ActivationExcess(m.est, 1e9)
    m.train()
    m.estimate(x)
    assert float(loose.take()) == 0.0


def test_highlight_weights_find_the_mirror_highlight_and_the_clipped_pixels():
    # A flat glossy material lit and seen along the mirror direction of pixel (8, 8) of 17².
    size = 17
    pos = ggx.pixel_positions(size, size, torch.float32, "cpu").reshape(-1, 3)
    light, view = torch.tensor([0.0, 0.0, 2.0]), torch.tensor([0.0, 0.0, 2.0])
    wi, wo = ggx.normalize(light - pos), ggx.normalize(view - pos)
    n = torch.tensor([0.0, 0.0, 1.0]).expand_as(pos)
    diffuse = torch.full_like(pos, 0.2)
    glossy = ggx.ggx_radiance(diffuse, torch.full_like(pos, 0.04), torch.full((size * size,), 0.1), n, wi, wo)
    share = specular_share(glossy, diffuse, n, wi)
    centre, corner = size * (size // 2) + size // 2, 0
    assert float(share[centre]) > 0.9 and float(share[corner]) < 0.05
    # A rough dielectric is mostly Lambertian everywhere; black and invisible pixels have share 0.
    rough = ggx.ggx_radiance(diffuse, torch.full_like(pos, 0.04), torch.ones(size * size), n, wi, wo)
    assert float(specular_share(rough, diffuse, n, wi).max()) < 0.2
    below = ggx.normalize(torch.tensor([1.0, 0.0, -0.2])).expand_as(pos)
    zero = ggx.ggx_radiance(diffuse, torch.full_like(pos, 0.04), torch.ones(size * size), n, wi, below)
    assert float(specular_share(zero, diffuse, n, wi).abs().max()) == 0.0
    # Clipped capture pixels, read back from the network input, get the full weight too.
    photo = torch.full((1, size, size, 3), 0.3)
    photo[0, 2, 3] = torch.tensor([1.0, 0.5, 0.5])  # one channel at 255
    photo[0, 4, 4] = 0.98  # bright, not clipped (sRGB 253)
    idx = torch.arange(size * size).reshape(1, 1, -1)
    clipped = capture_clipped(ggx.network_input(ggx.ldr_capture(photo)), idx)[0, 0]
    assert clipped.nonzero().flatten().tolist() == [2 * size + 3]
    w = highlight_weights(share[None, None], clipped[None, None], 4.0)[0, 0]
    assert float(w[2 * size + 3]) == 5.0 and float(w[centre]) > 4.6 and float(w[corner]) < 1.2
    assert float(w.min()) >= 1.0
    # The weighted mean: plain mean without weights, and the weights only rescale queries.
    err = torch.rand(1, 1, size * size, 3)
    assert torch.equal(weighted_mean(err, None), err.mean())
    torch.testing.assert_close(weighted_mean(err, torch.full((1, 1, size * size), 3.0)), err.mean())
    focus = torch.ones(1, 1, size * size)
    focus[0, 0, centre] = 1e6
    torch.testing.assert_close(weighted_mean(err, focus), err[0, 0, centre].mean(), rtol=1e-3, atol=0)


def test_map_probe_learns_the_normals_from_params_and_its_run_resumes_only_with_the_flag(tmp_path):
    # The probe reads normals and positive roughness from params; trained on params that hold the
    # maps (here: the maps themselves in the first channels), its dense L1 falls far, also from a
    # start pointing down (through a normalisation that start would get no gradient to turn).
    torch.manual_seed(0)
    maps, _ = make_batch([3, 4], 16, "cpu")
    params = torch.zeros(2, 64, 16, 16)
    params[:, :3] = maps["normal"].permute(0, 3, 1, 2)
    params[:, 3] = maps["roughness"]
    probe = MapProbe()
    normal, rough = probe(params)
    assert normal.shape == (2, 16, 16, 3) and rough.shape == (2, 16, 16) and float(rough.min()) > 0
    with torch.no_grad():
        probe.net[2].bias[2] = -3.0
    opt = torch.optim.Adam(probe.parameters(), lr=1e-2)
    first = float(maps_l1(*probe(params), maps))
    for _ in range(300):
        loss = maps_l1(*probe(params), maps)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss) < 0.1 * first
    assert float((probe(params)[0] - maps["normal"]).abs().sum(-1).mean()) < 0.1
    # A run with --maps-weight keeps the probe in its checkpoint; resuming needs the same flag.
    cmd = [sys.executable, "-m", "train_py.train", "--config", "tiny", "--steps", "2", "--size", "32"]
    cmd += ["--batch", "2", "--outputs", "2", "--val-every", "0", "--threads", "1", "--out", str(tmp_path)]
    subprocess.run([*cmd, "--maps-weight", "1"], cwd=REPO, check=True, capture_output=True, timeout=120)
    assert "probe" in torch.load(tmp_path / "ckpt.pt", weights_only=False)
    cmd[6] = "3"
    again = subprocess.run([*cmd, "--resume"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert again.returncode != 0 and "--maps-weight" in again.stderr
    subprocess.run([*cmd, "--resume", "--maps-weight", "1"], cwd=REPO, check=True, capture_output=True, timeout=120)
    assert torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] == 3


def test_profile_steps_writes_the_busiest_operators_and_log_lines_split_off_the_data_wait(tmp_path):
    cmd = [sys.executable, "-m", "train_py.train", "--config", "tiny", "--steps", "8", "--size", "32"]
    cmd += ["--batch", "2", "--outputs", "2", "--val-every", "0", "--threads", "1", "--log-every", "4"]
    cmd += ["--profile-steps", "2", "--out", str(tmp_path)]
    run = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    text = (tmp_path / "profile.txt").read_text()
    head = text.splitlines()[0]
    assert head.startswith("2 steps in ") and "ms/step" in head, head
    assert "By host time:" in text and "aten::" in text
    # Steps 4 and 8 log the mean over their 4 steps, with the time spent drawing batches.
    logged = [line for line in run.stdout.splitlines() if line.startswith("step ")]
    assert len(logged) == 3 and all("s/step (data " in line for line in logged), logged


def test_activation_penalty_builds_its_graph_only_where_a_tensor_exceeds_the_limit_and_sums_the_same():
    torch.manual_seed(1)
    m = NamModel(CONFIGS["tiny"]).train()
    x = torch.rand(1, 4, 16, 16) * 50
    probe = ActivationExcess(m.est, 0.0)
    m.estimate(x)
    peaks = sorted(float(t.detach().abs().max()) for t in probe.traced)
    limit = peaks[len(peaks) // 2]  # about half the tensors exceed it
    penalty = ActivationExcess(m.est, limit)
    m.estimate(x)
    traced = list(penalty.traced)
    over = [t for t in traced if float(t.detach().abs().max()) > limit]
    assert 0 < len(over) < len(traced)
    want = sum(torch.relu(t.detach().float().abs() - limit).mean() / limit for t in traced)
    got = penalty.take()
    torch.testing.assert_close(got, want, rtol=1e-5, atol=0)


def test_activation_penalty_inside_a_compiled_graph_sums_and_differentiates_the_same():
    # Two bias-free convs stand in for the U-Net (a whole one takes minutes to compile here).
    torch.manual_seed(2)
    net = torch.nn.Sequential(Conv(4, 8, 3), Conv(8, 8, 3)).train()
    x = torch.rand(2, 4, 12, 12) * 50
    eager = ActivationExcess(net, 20.0)
    net(x)
    want = eager.take()
    want.backward()
    want_grads = [p.grad.clone() for p in net.parameters()]
    net.zero_grad()
    compiled = ActivationExcess(net, 20.0)
    torch.compile(net, dynamic=False)(x)
    assert not compiled.traced and len(compiled.computed) == 2  # one penalty per conv, in the graph
    eager.take()  # its hooks ran in the graph too
    got = compiled.take()
    assert compiled.take() is None
    torch.testing.assert_close(got, want.detach(), rtol=1e-5, atol=0)
    got.backward()
    for p, w in zip(net.parameters(), want_grads, strict=True):
        torch.testing.assert_close(p.grad, w, rtol=1e-4, atol=1e-6)


def test_weight_ema_averages_the_trajectory_and_exports_and_resumes_only_with_the_flag(tmp_path):
    # In process: the first update copies the weights, each later one moves d of the way back.
    m = NamModel(CONFIGS["tiny"])
    avg = weight_average(m, 0.75)
    w = m.render.l1.weight
    for value in (1.0, 3.0, -2.0):
        with torch.no_grad():
            w.fill_(value)
        avg.update_parameters(m)
    expected = 0.75 * (0.75 * 1.0 + 0.25 * 3.0) + 0.25 * -2.0
    torch.testing.assert_close(avg.module.render.l1.weight, torch.full_like(w, expected))
    assert weight_average(m, 0.0) is None
    # A run keeps the average in its checkpoint; export --averaged writes it; resuming needs the flag.
    cmd = [sys.executable, "-m", "train_py.train", "--config", "tiny", "--steps", "3", "--size", "32"]
    cmd += ["--batch", "2", "--outputs", "2", "--val-every", "0", "--threads", "1", "--out", str(tmp_path)]
    subprocess.run([*cmd, "--weight-ema", "0.9"], cwd=REPO, check=True, capture_output=True, timeout=120)
    last, _ = load_checkpoint(tmp_path / "ckpt.pt")
    averaged, _ = load_checkpoint(tmp_path / "ckpt.pt", averaged=True)
    w_last, w_avg = last.render.l1.weight, averaged.render.l1.weight
    assert not torch.equal(w_last, w_avg) and torch.isfinite(w_avg).all()
    out = tmp_path / "avg.safetensors"
    subprocess.run(
        [sys.executable, "-m", "train_py.export", str(tmp_path / "ckpt.pt"), "-o", str(out), "--averaged"],
        cwd=REPO,
        check=True,
        capture_output=True,
        timeout=120,
    )
    torch.testing.assert_close(load_model(out).render.l1.weight, w_avg)
    cmd[6] = "4"
    again = subprocess.run([*cmd, "--resume"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert again.returncode != 0 and "--weight-ema" in again.stderr
    subprocess.run([*cmd, "--resume", "--weight-ema", "0.9"], cwd=REPO, check=True, capture_output=True, timeout=120)
    assert torch.load(tmp_path / "ckpt.pt", weights_only=False)["step"] == 4
