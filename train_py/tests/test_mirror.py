import torch

from train_py import ggx, materials, mirror
from train_py.evaluate import heldout_sets
from train_py.export import load_model

from .conftest import FIXTURES


def test_bins_split_at_the_edges_and_keep_the_mirror_direction_in_the_last():
    z = torch.tensor([0.0, 0.5, 0.99, 0.995, 0.999, 1.0])
    assert mirror.bin_index(z).tolist() == [0, 0, 1, 1, 2, 2]


def test_breakdown_counts_every_pixel_once_and_finds_the_diffuse_fit_too_dark_at_the_mirror():
    sets = list(heldout_sets(2, 16))
    acc = mirror.breakdown(load_model(FIXTURES / "net_tiny.safetensors"), sets, hemisphere_k=8)
    assert set(acc) == {"model", "diffuse fit", mirror.FLAT}
    for a in acc.values():
        assert int(a["count"].sum()) == 2 * 8 * 16 * 16
        assert torch.all(a["abs"] >= a["signed"].abs() - 1e-4)
    # A Lambertian relight has no highlight: darker than the truth where wh.z ≈ 1, on average.
    fit = acc["diffuse fit"]
    assert fit["signed"][-1] / fit["count"][-1] < 0
    # Flat normals with every other map exact are far closer than the diffuse fit there.
    flat = acc[mirror.FLAT]
    assert flat["abs"][-1] / flat["count"][-1] < 0.5 * fit["abs"][-1] / fit["count"][-1]
    md = mirror.markdown(acc, "two sets", "cmd", 1.0)
    assert md.count("| model |") == 4 and "median truth luminance" in md
    assert " nan " not in md


def test_an_empty_mirror_bin_is_said_so_not_a_nan_median():
    acc = mirror.breakdown(None, list(heldout_sets(1, 8)), hemisphere_k=2)
    for a in acc.values():
        a["truth"], a["relit"] = [torch.zeros(0)], [torch.zeros(0)]
    md = mirror.markdown(acc, "one set", "cmd", 1.0)
    assert " nan " not in md and md.count("no pixel in the bin") == len(acc)


def test_flat_normals_point_up_for_the_picked_materials_and_leave_the_other_maps_alone():
    maps = {k: torch.cat([v, v]) for k, v in next(heldout_sets(1, 16))[1].items()}
    flat = materials.flat_normals(maps)
    assert torch.equal(flat["normal"][..., 2], torch.ones_like(maps["roughness"]))
    assert torch.equal(flat["diffuse"], maps["diffuse"])
    assert torch.allclose(ggx.normalize(flat["normal"]), flat["normal"])
    some = materials.flat_normals(maps, torch.tensor([False, True]))
    assert torch.equal(some["normal"][0], maps["normal"][0])
    assert torch.equal(some["normal"][1], flat["normal"][1])
