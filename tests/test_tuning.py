import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from frictiongym.cli import tool_main
from frictiongym.controllers import PID, LoopSpec, PIDGains
from frictiongym.friction import ROTARY_PAPER
from frictiongym.metrics import step_metrics, step_metrics_batch
from frictiongym.plants.presets import ROTARY_PLANT
from frictiongym.tuning import (
    RULES,
    GainBounds,
    StepSpecs,
    TuningModel,
    random_search,
    reference,
    rule_scores,
    simulate,
)

SPECS = StepSpecs()
DT = 0.002
#: Around the feasible set of the nominal model (docs/tuning.md): most draws are near a spec.
NEAR = GainBounds(kp=(8.5, 10.0), ki=(0.0, 5.0), kd=(0.17, 0.27))
#: The linear loop: a command limit no candidate reaches, so python-control's loop is exact.
LINEAR = TuningModel(plant=dataclasses.replace(ROTARY_PLANT, command_limit=1e9), name="linear")


def _mixed(seed: int, n_uniform: int, n_near: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.vstack([GainBounds().sample(rng, n_uniform), NEAR.sample(rng, n_near)])


# --- batched building blocks ------------------------------------------------------------------


def test_batch_metrics_equal_step_metrics_column_by_column():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 2.0 + 1e-9, 0.01)
    columns = []
    for zeta, wn, gain in zip(
        rng.uniform(0.1, 1.5, 40),
        rng.uniform(2.0, 30.0, 40),
        rng.uniform(0.5, 1.1, 40),
        strict=True,
    ):
        wd = wn * math.sqrt(abs(1.0 - zeta**2)) + 1e-9
        y = gain * (1.0 - np.exp(-zeta * wn * t) * np.cos(wd * t))
        columns.append(y + rng.normal(0.0, 0.004, t.size) * (len(columns) % 2))
    y = np.column_stack(columns)
    for kwargs in ({}, {"y0": 0.0}, {"y0": 0.0, "final_value": 1.05, "settling_band": 0.05}):
        batch = step_metrics_batch(t, y, 1.0, **kwargs)
        for j in range(y.shape[1]):
            assert batch[j] == step_metrics(t, y[:, j], 1.0, **kwargs)
    assert len(batch) == y.shape[1]


def test_batch_metrics_reject_bad_shapes():
    with pytest.raises(ValueError, match=r"shape \(len\(t\), N\)"):
        step_metrics_batch([0.0, 1.0, 2.0], np.zeros((2, 3)), 1.0)
    with pytest.raises(ValueError, match="finite"):
        step_metrics_batch([0.0, 1.0], np.array([[0.0], [np.nan]]), 1.0)


def test_array_gains_drive_a_batch_exactly_like_scalar_pids():
    rng = np.random.default_rng(1)
    gains = rng.uniform(0.0, 3.0, size=(5, 3))
    for anti_windup in ("clamping", "back-calculation", "none"):
        spec = LoopSpec(dt=0.01, limit=1.5)
        batch = PID(spec, PIDGains(*gains.T.copy()), anti_windup=anti_windup)
        singles = [PID(spec, PIDGains(*g), anti_windup=anti_windup) for g in gains]
        for _ in range(30):
            y, v = rng.normal(size=5), rng.normal(size=5)
            u = batch.update(1.0, y, v)
            expected = [float(p.update(1.0, y[i], v[i])) for i, p in enumerate(singles)]
            np.testing.assert_array_equal(u, expected)
        # take() continues the selected entries exactly
        part = batch.take(np.array([True, False, True, False, True]))
        y, v = rng.normal(size=5), rng.normal(size=5)
        np.testing.assert_array_equal(
            part.update(1.0, y[::2], v[::2]), batch.update(1.0, y, v)[::2]
        )


def test_array_gains_are_validated():
    with pytest.raises(ValueError, match=r"PIDGains.ki must be >= 0"):
        PIDGains(np.ones(3), -np.ones(3))
    with pytest.raises(ValueError, match="broadcast"):
        PIDGains(np.ones(3), np.ones(2))
    with pytest.raises(ValueError, match="finite"):
        PIDGains(np.array([1.0, np.inf]))
    g = PIDGains(np.array([1.0, 2.0]), 0.5)
    assert g.batched
    assert g.shape == (2,)
    assert not g.kp.flags.writeable
    assert not PIDGains(1.0).batched
    assert PIDGains(1.0).shape == ()


# --- the tuner's simulation ---------------------------------------------------------------------


#: Looser specs whose early stops include settling failures and whose survivors include
#: infeasible candidates (the paper's specs stop every infeasible candidate at 0.1 s).
LOOSE = StepSpecs(rise_time=0.1, peak_time=0.3, settling_time=0.3, overshoot_pct=40.0)


@pytest.mark.parametrize(
    ("model", "specs"),
    [
        (TuningModel(), SPECS),
        (TuningModel.paper(with_friction=True), SPECS),
        (TuningModel(), LOOSE),
        (TuningModel.paper(with_friction=True).replace(velocity="filtered"), SPECS),
    ],
    ids=["nominal", "friction", "nominal-loose-specs", "friction-filtered-velocity"],
)
def test_early_stop_gives_exactly_the_full_evaluation(model, specs):
    gains = _mixed(2, 400, 400)
    fast = simulate(gains, model, specs, 3.0, early_stop=True)
    full = simulate(gains, model, specs, 3.0, early_stop=False)
    assert fast.feasible.sum() > 20  # the comparison covers many feasible candidates
    assert (~fast.complete).sum() > 300  # ... and many early stops
    if specs is LOOSE:
        assert set(fast.stop_reason) == {0, 1, 2, 3}  # every kind of stop
        assert (fast.complete & ~fast.feasible).any()  # and infeasible survivors
    np.testing.assert_array_equal(fast.feasible, full.feasible)
    assert not full.feasible[~fast.complete].any()  # every stopped candidate is infeasible
    done = fast.complete
    for name in ("rise_time", "peak_time", "settling_time", "overshoot_pct", "steady_state_error"):
        np.testing.assert_array_equal(
            getattr(fast.metrics, name)[done], getattr(full.metrics, name)[done]
        )
    np.testing.assert_array_equal(fast.itae, full.itae)
    np.testing.assert_array_equal(fast.peak_command[done], full.peak_command[done])


def _near_boundary(metrics, index: int) -> bool:
    """A metric within one sample (times) or 1e-6 % (overshoot) of its spec."""
    m = metrics[index]
    return (
        any(
            abs(getattr(m, name) - getattr(SPECS, name)) <= DT + 1e-12
            for name in ("rise_time", "peak_time", "settling_time")
        )
        or abs(m.overshoot_pct - SPECS.overshoot_pct) <= 1e-6
    )


def test_feasibility_agrees_with_python_control_on_the_same_sampled_data_loop():
    control = pytest.importorskip("control")
    del control
    gains = _mixed(3, 60, 120)
    ours = simulate(gains, LINEAR, SPECS, 3.0, early_stop=False)
    systems = [reference.sampled_data_loop(tuple(g), LINEAR.plant, DT) for g in gains]
    theirs = reference.step_info_metrics(systems, ours.t, SPECS)
    feasible = SPECS.feasible(theirs)
    differ = np.flatnonzero(feasible != ours.feasible)
    boundary = [i for i in differ if _near_boundary(ours.metrics, i) or _near_boundary(theirs, i)]
    assert list(differ) == boundary  # disagreements only on a spec's boundary
    assert ours.feasible.sum() >= 10
    assert len(differ) <= 2
    both = ours.feasible | feasible
    for name in ("rise_time", "peak_time", "settling_time"):
        np.testing.assert_allclose(
            getattr(ours.metrics, name)[both], getattr(theirs, name)[both], atol=DT + 1e-12
        )
    np.testing.assert_allclose(
        ours.metrics.overshoot_pct[both], theirs.overshoot_pct[both], atol=1e-8
    )
    # With the real ±10 V limit, candidates that never reach it give the same verdicts.
    real = simulate(gains, TuningModel(), SPECS, 3.0, early_stop=False)
    linear = real.peak_command < ROTARY_PLANT.command_limit
    assert linear.sum() > 150
    np.testing.assert_array_equal(real.feasible[linear], ours.feasible[linear])


def test_continuous_loop_is_close_but_not_equal():
    pytest.importorskip("control")
    gains = np.array([[7.8, 1.5, 0.275], [9.5, 2.0, 0.22], [9.9, 0.5, 0.24]])
    ours = simulate(gains, TuningModel(), SPECS, 3.0, early_stop=False)
    cont = reference.step_info_metrics(
        [reference.continuous_loop(tuple(g), ROTARY_PLANT) for g in gains], ours.t, SPECS
    )
    # The 2 ms sampled loop is a few ms faster than the continuous one (docs/tuning.md).
    np.testing.assert_allclose(ours.metrics.rise_time, cont.rise_time, atol=3 * DT)
    np.testing.assert_allclose(ours.metrics.peak_time, cont.peak_time, atol=3 * DT)


def test_filtered_velocity_is_the_demo_loop_up_to_the_envs_float32_observations():
    from frictiongym.loops import rotary_step

    gains = (7.8, 1.5, 0.275)
    model = TuningModel.paper(with_friction=True).replace(velocity="filtered")
    ours = simulate([gains], model, SPECS, 3.0, early_stop=False, keep_traces=True)
    demo = rotary_step(ROTARY_PAPER, PIDGains(*gains), 1.0, 3.0, encoder=False)
    assert ours.traces is not None
    # The demo's PID reads the env's float32 observation; the tuning loop keeps float64. One
    # float32 rounding of an angle within 1 rad is at most 2**-24 rad.
    np.testing.assert_allclose(ours.traces[:, 0], demo.signal("position"), rtol=0, atol=2**-24)
    metrics = demo.metrics()
    for name in ("rise_time", "peak_time", "settling_time"):
        assert getattr(ours.metrics, name)[0] == getattr(metrics, name), name
    # The same bound on the peak, in % of the 1 rad step.
    assert abs(ours.metrics.overshoot_pct[0] - metrics.overshoot_pct) <= 100 * 2**-24
    assert ours.feasible[0]  # the paper's gains meet the specs with the filtered velocity


def test_paper_gains_fail_rise_and_peak_in_the_nominal_model():
    result = random_search(1, seed=0)
    paper = result.paper_record()
    assert not paper["feasible"]
    assert paper["failing_specs"] == ["rise_time", "peak_time"]
    assert paper["metrics"]["rise_time"] == pytest.approx(0.060)
    assert paper["metrics"]["peak_time"] == pytest.approx(0.126)


# --- search -------------------------------------------------------------------------------------


def test_seeded_search_is_deterministic_and_independent_of_the_chunk_size():
    a = random_search(300, seed=7, chunk=1000)
    b = random_search(300, seed=7, chunk=64)
    np.testing.assert_array_equal(a.gains, b.gains)
    np.testing.assert_array_equal(a.evaluation.feasible, b.evaluation.feasible)
    np.testing.assert_array_equal(a.evaluation.itae, b.evaluation.itae)
    assert a.chosen == b.chosen
    assert not np.array_equal(random_search(300, seed=8).gains, a.gains)
    assert GainBounds().contains(a.gains).all()


@pytest.mark.parametrize("rule", list(RULES))
def test_rule_chooses_the_best_feasible_candidate(rule):
    result = random_search(400, seed=1, bounds=NEAR, rule=rule)
    ev, feasible = result.evaluation, result.evaluation.feasible
    assert feasible.sum() > 10
    assert result.chosen is not None
    assert feasible[result.chosen]
    scores = rule_scores(rule, ev, SPECS)
    assert scores[result.chosen] == np.nanmin(scores)
    assert np.isnan(scores[~feasible]).all()
    if rule == "margin":
        margins = SPECS.margin(ev.metrics)[feasible]
        assert SPECS.margin(ev.metrics)[result.chosen] == margins.max() > 0.0


def test_search_rejects_bad_arguments():
    with pytest.raises(ValueError, match="samples must be a whole number >= 1"):
        random_search(0)
    with pytest.raises(ValueError, match="unknown rule"):
        random_search(10, rule="fastest")
    with pytest.raises(ValueError, match="horizon must be longer"):
        random_search(10, horizon=1.0)
    with pytest.raises(ValueError, match=r"GainBounds\.kp"):
        GainBounds(kp=(5.0, 1.0))
    with pytest.raises(ValueError, match=r"StepSpecs\.rise_time"):
        StepSpecs(rise_time=-1.0)


# --- the command ---------------------------------------------------------------------------------


def test_cli_writes_tune_json_and_figure(tmp_path, capsys):
    out = tmp_path / "run"
    status = tool_main("tune", ["--samples", "300", "--seed", "0", "--out", str(out), "--quiet"])
    assert status == 0
    assert (out / "tune.png").stat().st_size > 10_000
    rec = json.loads((out / "tune.json").read_text())
    for key in (
        "n_samples",
        "n_feasible",
        "feasible",
        "chosen",
        "rule",
        "paper_gains",
        "specs",
        "bounds",
        "model",
        "seed",
        "dt",
        "horizon",
        "software",
        "wall_time_s",
        "command",
    ):
        assert key in rec
    assert rec["n_samples"] == 300
    assert rec["n_feasible"] == len(rec["feasible"])
    expected = {"seed": 0, "dt": DT, "horizon": 3.0}
    assert {k: rec[k] for k in expected} == expected
    assert rec["rule"]["name"] == "itae"
    assert rec["specs"]["rise_time"] == 0.05
    assert rec["bounds"]["kd"] == [0.0, 0.5]
    assert rec["paper_gains"]["kp"] == 7.8
    assert rec["paper_gains"]["feasible"] is False
    assert rec["model"]["friction"]["law"] == "none"
    for cand in rec["feasible"]:
        assert cand["rise_time"] < 0.05
        assert cand["overshoot_pct"] < 20.0
    assert capsys.readouterr().out == ""  # --quiet


def test_cli_friction_model_and_params_file(tmp_path, capsys):
    from frictiongym.params import DeviceParams, save_params

    status = tool_main(
        "tune",
        ["--samples", "200", "--model", "friction", "--out", str(tmp_path / "f"), "--no-figures"],
    )
    assert status == 0
    assert "of 200 candidates feasible" in capsys.readouterr().out
    assert json.loads((tmp_path / "f" / "tune.json").read_text())["model"]["name"] == "friction"
    params = DeviceParams.from_model(
        ROTARY_PAPER.replace(viscous=0.0411), inertia=7.143e-3, damping=0.0446, device="RotaryServo"
    )
    file = save_params(tmp_path / "id", params)
    assert (
        tool_main(
            "tune",
            [
                "--samples",
                "200",
                "--params",
                str(file),
                "--out",
                str(tmp_path / "p"),
                "--no-figures",
                "--quiet",
            ],
        )
        == 0
    )
    model = json.loads((tmp_path / "p" / "tune.json").read_text())["model"]
    assert model["name"] == "params"
    assert model["friction"]["law"] == "paper"
    assert model["friction"]["viscous"] == 0.0  # B already holds it


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--samples", "0"], "--samples must be at least 1"),
        (["--horizon", "-1"], "--horizon must be a number of seconds longer than"),
        (["--horizon", "nan"], "--horizon"),
        (["--chunk", "0"], "--chunk must be at least 1"),
        (["--seed", "-3"], "--seed must be a whole number from 0"),
        (["--params", "missing.json"], "no such file"),
    ],
)
def test_cli_bad_inputs_exit_2_with_a_message(tmp_path, capsys, argv, message):
    assert tool_main("tune", [*argv, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert message in err
    assert not (tmp_path / "o").exists()


def test_cli_rejects_a_file_as_out_and_bad_params_files(tmp_path, capsys):
    file = tmp_path / "taken"
    file.write_text("x")
    assert tool_main("tune", ["--out", str(file), "--quiet"]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert tool_main("tune", ["--params", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    from frictiongym.friction import ALTINO_PAPER
    from frictiongym.params import DeviceParams, save_params

    car = save_params(
        tmp_path / "car",
        DeviceParams.from_model(ALTINO_PAPER, inertia=2.2, damping=10.93, device="AltinoDistance"),
    )
    assert tool_main("tune", ["--params", str(car), "--out", str(tmp_path / "o")]) == 2
    assert "RotaryServo" in capsys.readouterr().err


def test_scripts_explain_their_options():
    scripts = Path(__file__).resolve().parents[1] / "scripts"
    done = subprocess.run(
        [sys.executable, str(scripts / "tune.py"), "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    for option in (
        "--samples",
        "--seed",
        "--out",
        "--model",
        "--params",
        "--rule",
        "--horizon",
        "--no-figures",
        "--quiet",
        "--full",
    ):
        assert option in done.stdout
