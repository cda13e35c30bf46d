import math
import os
import subprocess
import sys

import control
import numpy as np
import pytest

from frictiongym.plants.sensors import (
    FilteredDerivative,
    ir_distance,
    ir_readout,
    last_normal_draw,
    normal_draw,
    quantize_angle,
)

Q = 2 * math.pi / 2048


def test_encoder_quantisation_error_is_at_most_half_a_count():
    angle = np.linspace(-7.0, 7.0, 100_001)
    measured = quantize_angle(angle)
    assert np.all(np.abs(measured - angle) <= Q / 2 + 1e-15)
    counts = measured / Q
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    assert np.all(np.diff(measured) >= 0)
    assert quantize_angle(0.0) == 0.0
    assert quantize_angle(0.49 * Q) == 0.0
    assert quantize_angle(0.51 * Q) == pytest.approx(Q)


def test_filtered_derivative_is_the_ramp_invariant_discretisation():
    w, dt = 50.0, 0.002
    ref = control.sample_system(control.tf([w, 0.0], [1.0, w]), dt, method="foh")
    rng = np.random.default_rng(0)
    y = np.cumsum(rng.normal(size=400)) * 1e-3
    t = np.arange(y.size) * dt
    expected = np.asarray(control.forced_response(ref, t, y - y[0]).outputs).ravel()
    filt = FilteredDerivative(w, dt)
    filt.reset(position=y[0])
    ours = np.array([float(filt.update(v)) for v in y])
    np.testing.assert_allclose(ours, expected, atol=1e-9)


def test_filtered_derivative_tracks_a_ramp_and_is_batched():
    filt = FilteredDerivative(50.0, 0.002, shape=(3,))
    slopes = np.array([1.0, -2.0, 0.5])
    for k in range(1, 2000):
        est = filt.update(slopes * k * 0.002)
    np.testing.assert_allclose(est, slopes, rtol=1e-12)
    with pytest.raises(ValueError, match="cutoff"):
        FilteredDerivative(-1.0, 0.002)
    with pytest.raises(ValueError, match="dt"):
        FilteredDerivative(50.0, 0.0)


def test_ir_readout_inverts_the_papers_equation():
    d = np.linspace(1.5, 20.0, 500)
    x = ir_readout(d)
    assert x.dtype == np.int64
    # rounding the readout costs at most half a count of distance
    half_count = 0.5 * d**2 / 966.0
    assert np.all(np.abs(ir_distance(x) - d) <= half_count * 1.01 + 1e-12)
    assert ir_readout(5.0) == round(966 / 5 - 45)
    assert np.all(np.diff(x) <= 0)  # farther wall, weaker signal


def test_ir_readout_saturates_at_both_ends():
    assert ir_readout(30.0) == 0
    assert ir_readout(966 / 45 + 0.5) == 0
    assert ir_readout(1.0) == 800
    assert ir_distance(0) == pytest.approx(966 / 45)
    assert ir_distance(800) == pytest.approx(966 / 845)


def test_ir_gain_offset_and_noise():
    base = ir_readout(5.0)
    assert ir_readout(5.0, gain=1.2) > base  # more reflective wall reads nearer
    assert ir_distance(ir_readout(5.0, gain=1.2)) < 5.0
    assert ir_readout(5.0, offset=10.0) == base + 10
    noisy = ir_readout(np.full(1000, 5.0), noise=np.random.default_rng(1).normal(0, 3, 1000))
    assert noisy.std() == pytest.approx(3.0, rel=0.15)


def test_ir_rejects_contact_with_the_wall():
    with pytest.raises(ValueError, match="touching the wall"):
        ir_readout(0.0)
    with pytest.raises(ValueError, match="touching the wall"):
        ir_readout(np.array([5.0, float("nan")]))


def test_last_normal_draw_gives_the_last_draw_again_and_draws_nothing():
    # the env kernel draws a block's noise in loops of its own, then observes a just-reset env
    # again with its draw recomputed from the generator's state
    golden = 0x9E3779B97F4A7C15
    states = np.array([0, 2**64 - 1, golden, 12345], dtype=np.uint64)  # wrap-arounds included
    draws = []
    for i in range(states.size):
        for _ in range(3):
            drawn = normal_draw(states, i)
            kept = states.copy()
            assert last_normal_draw(states, i) == drawn
            np.testing.assert_array_equal(states, kept)
            draws.append(drawn)
    assert len(set(draws)) == len(draws)  # every draw a new value


PURE_PYTHON_UFUNCS = """
import sys
import numpy as np
from frictiongym.friction import ROTARY_PAPER
from frictiongym.plants.sensors import FilteredDerivative, ir_distance, ir_readout, quantize_angle

x = np.linspace(-3.0, 40.0, 57)
values = [quantize_angle(x), ir_readout(np.abs(x) + 0.5), ir_distance(np.arange(0, 800, 13)),
          ROTARY_PAPER.force(x)]
derivative = FilteredDerivative(50.0, 0.002, shape=(2,), resolution=0.003)
values += [derivative.update(np.array([v, 2 * v])) for v in x]
np.save(sys.argv[1], np.concatenate([np.ravel(v).astype(np.float64) for v in values]))
"""


def test_the_sensor_and_friction_ufuncs_run_without_numba_and_agree(tmp_path):
    # NUMBA_DISABLE_JIT=1 with an empty cache: numba's vectorize could not compile functions
    # that call njit functions left as plain Python (the import failed)
    script = tmp_path / "ufuncs.py"
    script.write_text(PURE_PYTHON_UFUNCS)
    results = []
    for mode, extra in (("py", {"NUMBA_DISABLE_JIT": "1"}), ("jit", {})):
        env = {key: val for key, val in os.environ.items() if key != "NUMBA_DISABLE_JIT"}
        env |= {"NUMBA_CACHE_DIR": str(tmp_path / f"cache-{mode}"), **extra}
        out = tmp_path / f"{mode}.npy"
        subprocess.run([sys.executable, str(script), str(out)], env=env, check=True, timeout=300)
        results.append(np.load(out))
    np.testing.assert_array_equal(results[0], results[1])
