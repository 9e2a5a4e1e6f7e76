"""benchmarks.compare reads the paths table that benchmarks.throughput prints."""

from __future__ import annotations

from benchmarks.compare import paths_header, rates

OUTPUT = """torch 2.13.0+cpu, x86_64, 2 threads, device cpu
| 1,024 | compiled | 2,234,577 [2,134,546] | 1,036,671 [948,820] (0.46) | 9,179x |

| N | mode | step env-steps/s | step_and_maybe_reset env-steps/s (/ step) | step / reference |
|---|---|---|---|---|
| 1,024 | compiled | 2,234,577 [2,134,546] | 1,036,671 [948,820] (0.46) | 9,179x |
| 16,384 | compiled | 3,105,408 [3,031,450] | failed: out of memory | 12,757x |

| N | mode | step ms | reset 0.1 % ms (/ step) |
|---|---|---|---|
| 1,024 | compiled | 0.47 | 0.11 (0.23) |
"""


def test_the_paths_table_is_read_by_n_mode_and_path():
    assert rates(OUTPUT, paths_header(OUTPUT)) == {
        (1024, "compiled", "step"): 2234577.0,
        (1024, "compiled", "step_and_maybe_reset"): 1036671.0,
        (16384, "compiled", "step"): 3105408.0,
    }


def test_a_table_without_the_step_is_read_too():
    output = """| N | mode | collector (fast preset) frames/s | step / reference |
|---|---|---|---|
| 1,024 | compiled | 459,332 [420,698] | - |
"""
    assert rates(output, paths_header(output)) == {
        (1024, "compiled", "collector (fast preset) frames/s"): 459332.0}
