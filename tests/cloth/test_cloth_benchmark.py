"""Speed of one coupled frame (wind sampling, §3 aerodynamics, XPBD cloth with collisions).

pytest-benchmark figures, marked slow (outside CI): run with
``pytest -m slow tests/cloth/test_cloth_benchmark.py --benchmark-only``. The targets
(40x25 flag >= 300 frames/s, 64x64 >= 60, 100x60 >= 30) are recorded, not
asserted; ``experiments/bench_cloth.py`` writes the same figures to a CSV.
"""

import pytest

from windbench.cli import compose_config
from windbench.simulate import Simulation, prepare


@pytest.mark.slow
@pytest.mark.parametrize("resolution", [(40, 25), (64, 64), (100, 60)], ids=str)
def test_benchmark_flag_frame(benchmark, resolution):
    nu, nv = resolution
    cfg = compose_config(
        ["scene=flag", "wind=global", f"scene.cloths.0.resolution=[{nu},{nv}]", "sim.duration=100"]
    )
    sim = Simulation(prepare(cfg))
    for n in range(10):  # compile and leave the start-up transient
        sim.step(n)
    counter = iter(range(10, 10**9))
    benchmark.extra_info["target_frames_per_second"] = {40: 300, 64: 60, 100: 30}[nu]
    benchmark.pedantic(lambda: sim.step(next(counter)), rounds=60, iterations=1)
    assert sim.cloth_solver.stats(sim.state)["max_penetration"] <= 1e-3
