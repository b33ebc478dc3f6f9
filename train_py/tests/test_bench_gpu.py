"""scripts/gpu-bench's parsing and validation (train_py.bench_gpu), on hand-written inputs; the
end-to-end run is a step of scripts/test."""

import json

import pytest

from train_py import bench_gpu

HEADER = (
    "GPU: llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu), f32, size 16², best of 1 interleaved rounds"
    " after a warm-up round; FMA peak (shaders/fma_peak.wgsl) 23.1 GFLOP/s"
)
TABLE = f"""
{HEADER}

| path | pixels | ms | GFLOP/s | × general (same backend) | GPU/CPU speed |
|---|---:|---:|---:|---:|---:|
| GPU general point relight 16² | 256 | 40.00 | 8.6 | 1.00 | 0.13 |
| GPU directional + orthographic 16² | 256 | 5.00 | 7.2 | 8.00 | 0.14 |
| CPU general point relight 16² | 256 | 5.20 | 64.1 | 1.00 | — |
| CPU directional + orthographic 16² | 256 | 0.70 | 51.3 | 7.43 | — |
| GPU estimate (M_est) 16² | 256 | 30.00 | 3.7 | — | 0.14 |
| CPU estimate (M_est) 16² | 256 | 4.20 | 26.3 | — | — |
"""


def test_the_nam_table_parses_into_six_rows_with_the_peak():
    t = bench_gpu.parse_nam_table(TABLE)
    assert t["adapter"].startswith("llvmpipe") and t["fma_peak_gflops"] == 23.1
    assert [r["path"].split(" 16²")[0] for r in t["rows"]][4:] == ["GPU estimate (M_est)", "CPU estimate (M_est)"]
    assert t["rows"][4]["gpu_over_cpu_speed"] == 0.14 and t["rows"][5]["gpu_over_cpu_speed"] is None
    assert t["rows"][0]["ms"] == 40.0 and t["rows"][0]["pixels"] == 256


def test_a_truncated_table_is_an_error():
    with pytest.raises(ValueError, match="expected 6 rows"):
        bench_gpu.parse_nam_table("\n".join(TABLE.splitlines()[:-2]))
    with pytest.raises(ValueError, match="no GPU table"):
        bench_gpu.parse_nam_table("error: no adapter")


def result(tmp_path, **changes):
    rows = [
        {"job": job, "variant": "eager", "precision": prec, "ms": 1.0, "max_abs_diff": 0.0}
        for job in ["relight 16²", "estimate 16² C=8", "estimate 16² C=16"]
        for prec in ["f32", "bf16"]
    ]
    r = {
        "device": "cpu",
        "sizes": [16],
        "nam": [{"command": "nam-cli bench", **bench_gpu.parse_nam_table(TABLE)}],
        "rates": {"gemm_1024_f32_gflops": 100.0},
        "torch_rows": rows,
        **changes,
    }
    path = tmp_path / "gpu_bench.json"
    path.write_text(json.dumps(r))
    return path, r


def test_check_accepts_a_complete_result_and_names_what_is_missing(tmp_path):
    path, r = result(tmp_path)
    assert bench_gpu.check(path) == []
    path, _ = result(tmp_path, torch_rows=r["torch_rows"][1:])
    assert bench_gpu.check(path) == ["no eager f32 row for relight 16²"]
    path, _ = result(tmp_path, nam=[{"command": "nam-cli bench", "error": "exit 1: no adapter"}], rates={})
    assert bench_gpu.check(path) == ["nam-cli bench: exit 1: no adapter", "no device rates"]
    bad = [dict(r["torch_rows"][0], max_abs_diff=0.5), *r["torch_rows"][1:]]
    path, _ = result(tmp_path, torch_rows=bad)
    assert bench_gpu.check(path) == ["relight 16² [eager]: f32 differs by 0.5 from f32 eager"]
