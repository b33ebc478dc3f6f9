"""The evaluation's one seeded definition of pairs and materials, shared with nam-eval."""

import math

import torch
from safetensors.torch import load_file

from train_py import eval_agreement, evaluate, protocols
from train_py.evaluate import box_downsample, heldout_sets


def test_splitmix64_gives_the_published_sequence_and_uniforms_from_its_top_53_bits():
    g = protocols.SplitMix64(0)
    assert [g.next_u64() for _ in range(3)] == [0xE220A8397B1DCDAF, 0x6E789E6AA1B965F4, 0x06C45D188009454F]
    assert protocols.SplitMix64(0).uniform() == (0xE220A8397B1DCDAF >> 11) / 2**53


def test_seeded_pairs_follow_their_protocols_and_are_prefixes_of_longer_lists():
    light, view = protocols.seeded_pairs("hemisphere", 500, 7)
    assert torch.allclose(light.norm(dim=-1), torch.full((1, 500), protocols.HEMISPHERE_RADIUS, dtype=torch.float64))
    assert float(view[..., 2].min()) > 0
    short, _ = protocols.seeded_pairs("hemisphere", 10, 7)
    assert torch.equal(short, light[:, :10])
    light, view = protocols.seeded_pairs("reflect", 200, 3)
    # The view and the light mirrored below the surface lie on one line through the highlight point.
    mirrored = light * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
    t = view[..., 2:] / (view[..., 2:] + light[..., 2:])
    p = view + (mirrored - view) * t
    assert float(p[..., 2].abs().max()) < 1e-9
    assert float((light - p).norm(dim=-1).min()) >= protocols.REFLECT_MIN_DIST - 1e-9
    cam = torch.tensor([0.0, 0.0, protocols.CAPTURE_DISTANCE], dtype=torch.float64)
    light, view = protocols.seeded_pairs("identity", 2, 1)
    assert torch.equal(light, cam.expand(1, 2, 3)) and torch.equal(view, light)


def test_box_downsample_averages_linear_values_and_renormalises_normals():
    maps = next(heldout_sets(1, None))[1]
    half = box_downsample(maps, 32)
    assert half["roughness"].shape == (1, 32, 32)
    want = maps["diffuse"][0, :2, :2].mean(dim=(0, 1))
    assert torch.allclose(half["diffuse"][0, 0, 0], want, atol=1e-6)
    assert torch.allclose(half["normal"].norm(dim=-1), torch.ones(1, 32, 32), atol=1e-5)
    assert math.isclose(float(half["roughness"][0, 0, 0]), float(maps["roughness"][0, :2, :2].mean()), rel_tol=1e-6)


#: Scores of the agreement fixture recomputed on another CPU: torch's f32 kernels sum in an
#: order that depends on the machine (measured 8.3e-6 on an SSIM, AMD EPYC against the Intel
#: Xeon that wrote the fixture); the Rust runner is held to 1e-5 on log-L1 by its own test.
AGREEMENT_SCORE_TOL = 2e-5


def test_the_agreement_fixture_is_what_the_generator_writes():
    """The committed golden is reproducible (pairs exactly, scores to float noise)."""
    stored = load_file(eval_agreement.OUT)
    fresh = eval_agreement.compute()
    assert stored.keys() == fresh.keys()
    for k, v in fresh.items():
        if k.startswith("pairs."):
            assert torch.equal(stored[k], v), k
        else:
            assert torch.allclose(stored[k], v, atol=AGREEMENT_SCORE_TOL, rtol=0), k


def test_evaluation_sets_name_what_they_hold():
    sets, side, what, labels = evaluate.evaluation_sets("procedural", 2, 32)
    assert side == 32 and len(sets) == 2 and sets[0][1]["roughness"].shape == (1, 32, 32)
    assert what.startswith("2 held-out procedural") and str(sets[1][0]) in what
    assert labels == [str(seed) for seed, _ in sets]
    sets, side, what, labels = evaluate.evaluation_sets("test", 2, 16)
    assert side == 16 and len(sets) == 2 and sets[0][0] == evaluate.EVAL_SEED and "materials/test" in what
    assert labels == [f.stem for f in evaluate.materials.list_files("test")[:2]]


def test_per_material_rows_average_to_the_table_and_name_each_material():
    from train_py.export import load_model

    from .conftest import FIXTURES

    sets, _, _, labels = evaluate.evaluation_sets("procedural", 3, 16)
    rows: list = []
    model = load_model(FIXTURES / "net_tiny.safetensors")
    res = evaluate.evaluate_maps(model, sets, len(sets), hemisphere_k=4, reflect_k=2, per_material=rows)
    assert len(rows) == 3
    for p, methods in res.items():
        for m, score in methods.items():
            mean = sum(r[p][m]["log_l1"] for r in rows) / 3
            assert math.isclose(score["log_l1"], mean, rel_tol=1e-9), (p, m)
            assert all(r[p][m]["log_l1"] >= abs(r[p][m]["signed"]) for r in rows)
    md = evaluate.per_material_markdown(labels, rows)
    lines = [line for line in md.splitlines() if line.startswith("| 1000002")]
    assert [line.split(" | ")[0][2:] for line in lines] == [str(seed) for seed, _ in sets]
    shares = [float(line.rstrip(" |").rsplit("| ", 1)[1].rstrip("%")) for line in lines]
    assert abs(sum(shares) - 100) <= 2


def test_phone_captures_are_seeded_exposed_and_read_at_their_own_distance():
    from train_py import capture, ggx

    _, maps = next(heldout_sets(1, 16))
    same_maps, ideal, distance = evaluate.photograph(7, maps, phone=False)
    assert same_maps is maps and distance == ggx.CAPTURE_DISTANCE
    torch.testing.assert_close(ideal, ggx.ldr_capture(ggx.render_capture(maps)))
    exposed, photo, d = evaluate.photograph(7, maps, phone=True)
    again = evaluate.photograph(7, maps, phone=True)
    torch.testing.assert_close(photo, again[1])
    assert d == again[2] and d != ggx.CAPTURE_DISTANCE
    lo, hi = ggx.capture_distance(capture.FOV_RANGE[1]), ggx.capture_distance(capture.FOV_RANGE[0])
    assert lo <= d <= hi
    assert photo.shape == ideal.shape and float(photo.min()) >= 0 and float(photo.max()) <= 1
    # Auto-exposure rescales the diffuse and specular maps the truth is rendered from, nothing else.
    k = exposed["diffuse"].mean() / maps["diffuse"].mean()
    assert not torch.isclose(k, torch.tensor(1.0)) and torch.equal(exposed["normal"], maps["normal"])
    # Scored end to end: finite, and a different photo gives a different score.
    res = {
        phone: evaluate.evaluate_maps(None, [(7, maps)], 1, hemisphere_k=4, protocol_names=("hemisphere",), phone=phone)
        for phone in (False, True)
    }
    fit = [res[p]["hemisphere"]["diffuse fit"]["log_l1"] for p in (False, True)]
    assert all(math.isfinite(v) for v in fit) and fit[0] != fit[1]
