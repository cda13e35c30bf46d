"""FrictionCompensator: each at-rest variant by hand, level mismatch, batching, closed loop."""

import math

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.controllers import (
    MODES,
    PID,
    Controller,
    FrictionCompensator,
    LoopSpec,
    PIDGains,
    ResidualController,
    rollout,
)
from frictiongym.controllers.residual_core import ResidualConfig
from frictiongym.friction import ROTARY_PAPER, StictionCoulomb
from frictiongym.plants.presets import ALTINO_PAPER_GAINS_COMPENSATED, ROTARY_PAPER_GAINS

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"

#: Asymmetric levels and decay speeds, and a viscous slope the compensator must leave out.
US_POS, US_NEG, UC_POS, UC_NEG, V0_POS, V0_NEG = 0.3, 0.2, 0.1, 0.05, 2.0, 4.0
MODEL = StictionCoulomb(
    us_pos=US_POS,
    us_neg=US_NEG,
    uc_pos=UC_POS,
    uc_neg=UC_NEG,
    v0_pos=V0_POS,
    v0_neg=V0_NEG,
    viscous=0.7,
)
REST = 0.1
SLIDING_MODES = ("command", "error", "deadband")


class Constant(Controller):
    """A base controller returning a fixed command (one per env if ``value`` is an array)."""

    def __init__(self, spec, value=0.5):
        self.spec = spec
        self.value = np.asarray(value, dtype=np.float64)
        self.resets = []

    def reset(self, mask=None):
        self.resets.append(mask)

    def command(self, observation):
        _, y, _ = self.spec.split(observation)
        return np.broadcast_to(self.value, y.shape).astype(np.float64)


def spec(direction=1.0, limit=10.0, rest_speed=REST, friction=None, velocity=1):
    return LoopSpec(
        dt=0.01,
        limit=limit,
        position=0,
        velocity=velocity,
        reference=2,
        direction=direction,
        rest_speed=rest_speed,
        friction=friction,
    )


def compensator(base=0.5, direction=1.0, model=MODEL, **kwargs):
    return FrictionCompensator(Constant(spec(direction), base), model, **kwargs)


def added(comp, v_obs, y=0.0, r=0.0):
    """The command the compensator adds to its base for the observation ``[y, v_obs, r]``."""
    obs = np.array([y, v_obs, r])
    u = comp(obs)
    assert u.shape == (1,)
    base = comp.base.command(obs)
    term = comp.compensation(obs, base)
    assert term.shape == ()
    # The action is exactly the base command plus this term, saturated.
    assert u[0] == np.clip(base + term, -comp.spec.limit, comp.spec.limit)
    return float(term)


def sliding_by_hand(v, us_pos=US_POS, us_neg=US_NEG, uc_pos=UC_POS, uc_neg=UC_NEG):
    """The paper's linear decay from u_s at rest to u_c at v0, signed, no viscous term."""
    if v > 0:
        return uc_pos if v >= V0_POS else us_pos - (us_pos - uc_pos) * v / V0_POS
    if v < 0:
        return -(uc_neg if -v >= V0_NEG else us_neg - (us_neg - uc_neg) * -v / V0_NEG)
    return 0.0


# --------------------------------------------------------------------------------------------
# Moving: every mode but smooth adds F_nl(v)
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", SLIDING_MODES)
@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("v_plant", [0.5, 1.0, 1.9, 2.0, 3.0, -0.5, -2.0, -3.9, -4.0, -6.0])
def test_moving_adds_the_nonlinear_friction(mode, direction, v_plant):
    # Base commands of both signs and errors of both signs must not matter while sliding.
    for base, r in ((0.5, 1.0), (-0.5, -1.0), (0.0, 0.0)):
        comp = compensator(base, direction, mode=mode)
        v_obs = direction * v_plant
        got = added(comp, v_obs, y=0.0, r=r)
        assert got == pytest.approx(sliding_by_hand(v_plant), abs=1e-12)
        assert got == float(MODEL.nonlinear_force(v_plant))  # the very model curve


def test_hand_values_of_the_linear_decay():
    # Half way to v0: half way from u_s to u_c, in each direction with its own levels.
    comp = compensator(mode="deadband")
    assert added(comp, 1.0) == pytest.approx(0.2, abs=1e-12)  # 0.3 - 0.2 * 1/2
    assert added(comp, -2.0) == pytest.approx(-0.125, abs=1e-12)  # -(0.2 - 0.15 * 2/4)
    assert added(comp, 10.0) == pytest.approx(UC_POS, abs=1e-12)
    assert added(comp, -10.0) == pytest.approx(-UC_NEG, abs=1e-12)
    # direction -1: the plant moves the other way from the observed rate
    comp = compensator(direction=-1.0, mode="deadband")
    assert added(comp, 1.0) == pytest.approx(-(0.2 - 0.15 * 1 / 4), abs=1e-12)
    assert added(comp, -1.0) == pytest.approx(0.3 - 0.2 * 1 / 2, abs=1e-12)


# --------------------------------------------------------------------------------------------
# At rest: what each variant does
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("v_obs", [0.0, REST, -REST, 0.5 * REST])
def test_command_mode_at_rest_follows_the_base_command(direction, v_obs):
    assert added(compensator(0.5, direction), v_obs) == US_POS
    assert added(compensator(-0.5, direction), v_obs) == -US_NEG
    assert added(compensator(0.0, direction), v_obs) == 0.0
    # The error does not matter in this mode.
    assert added(compensator(0.5, direction), v_obs, y=1.0, r=0.0) == US_POS


def test_rest_band_edge():
    comp = compensator(-0.5, mode="command")
    assert added(comp, REST) == -US_NEG  # |v| <= rest_speed: at rest
    assert added(comp, REST * (1 + 1e-9)) == pytest.approx(sliding_by_hand(REST), abs=1e-9)
    # rest_speed given to the compensator replaces the spec's
    wide = compensator(-0.5, mode="command", rest_speed=1.0)
    assert wide.rest_speed == 1.0
    assert added(wide, 0.9) == -US_NEG


@pytest.mark.parametrize("v_obs", [0.0, REST, -REST])
def test_error_mode_at_rest_pushes_toward_the_reference(v_obs):
    # direction +1: r > y pushes positive, r < y negative, r == y nothing; base sign ignored
    assert added(compensator(-0.5, mode="error"), v_obs, y=0.0, r=1.0) == US_POS
    assert added(compensator(0.5, mode="error"), v_obs, y=1.0, r=0.0) == -US_NEG
    assert added(compensator(0.5, mode="error"), v_obs, y=1.0, r=1.0) == 0.0
    # Altino-style direction -1: too close to the wall (r = 5 > y = 4) reverses, away from it
    assert added(compensator(0.5, -1.0, mode="error"), v_obs, y=4.0, r=5.0) == -US_NEG
    assert added(compensator(-0.5, -1.0, mode="error"), v_obs, y=6.0, r=5.0) == US_POS


@pytest.mark.parametrize("v_obs", [0.0, REST, -REST])
def test_deadband_mode_adds_nothing_at_rest(v_obs):
    for base in (0.5, -0.5, 0.0):
        assert added(compensator(base, mode="deadband"), v_obs, y=0.0, r=1.0) == 0.0


# --------------------------------------------------------------------------------------------
# Smooth
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_smooth_mode_by_hand(direction):
    smoothing = 0.4
    comp = compensator(0.5, direction, mode="smooth", smoothing=smoothing)
    for v_plant in (0.05, 0.3, 1.0, 2.5, -0.05, -0.3, -1.0, -5.0):
        expected = abs(sliding_by_hand(v_plant)) * math.tanh(v_plant / smoothing)
        assert added(comp, direction * v_plant) == pytest.approx(expected, abs=1e-12)
    # No rest band: below rest_speed it is still the smooth curve, not a break-away level.
    v = 0.5 * REST
    assert added(comp, direction * v) == pytest.approx(
        abs(sliding_by_hand(v)) * math.tanh(v / smoothing), abs=1e-12
    )


def test_smooth_mode_is_odd_and_continuous():
    symmetric = StictionCoulomb(0.3, 0.3, 0.1, 0.1, 2.0, 2.0)
    comp = compensator(0.0, mode="smooth", model=symmetric)
    assert comp.smoothing == REST  # the rest speed by default
    v = np.linspace(-3.0, 3.0, 601)
    obs = np.stack([np.zeros_like(v), v, np.zeros_like(v)], axis=1)
    c = comp.compensation(obs, np.zeros_like(v))
    np.testing.assert_allclose(c, -c[::-1], atol=1e-15)  # odd
    assert c[300] == 0.0  # 0 at v = 0
    for eps in (1e-3, 1e-6, 1e-9):  # and tends to 0 from both sides: no jump at rest
        small = comp.compensation(np.array([[0.0, eps, 0.0], [0.0, -eps, 0.0]]), np.zeros(2))
        assert np.all(np.abs(small) <= 0.3 * math.tanh(eps / REST) + 1e-15)
    assert np.max(np.abs(np.diff(c))) < 0.05  # no step anywhere on a 0.01 grid


# --------------------------------------------------------------------------------------------
# Level mismatch
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
def test_scale_multiplies_every_level(mode):
    comp = compensator(0.5, mode=mode, scale=1.2)
    assert comp.model == MODEL.scaled(1.2)
    assert comp.model.breakaway == pytest.approx((1.2 * US_POS, 1.2 * US_NEG))
    reference = compensator(0.5, mode=mode, model=MODEL.scaled(1.2))
    for v in (0.0, 0.5, 1.5, 3.0, -0.5, -3.0, -5.0):
        got = added(comp, v, y=0.0, r=1.0)
        assert got == added(reference, v, y=0.0, r=1.0)
        assert got == pytest.approx(1.2 * added(compensator(0.5, mode=mode), v, r=1.0), abs=1e-12)
    hand = {
        "command": 1.2 * US_POS,
        "error": 1.2 * US_POS,
        "deadband": 0.0,
        "smooth": 0.0,
    }
    assert added(comp, 0.0, y=0.0, r=1.0) == pytest.approx(hand[mode], abs=1e-15)
    if mode != "smooth":
        hand_sliding = sliding_by_hand(-1.0, 1.2 * US_POS, 1.2 * US_NEG, 1.2 * UC_POS, 1.2 * UC_NEG)
        assert added(comp, -1.0) == pytest.approx(hand_sliding, abs=1e-12)
        assert added(comp, 5.0) == pytest.approx(1.2 * UC_POS, abs=1e-12)


@pytest.mark.parametrize("mode", MODES)
def test_scale_zero_compensates_nothing(mode):
    comp = compensator(0.5, mode=mode, scale=0.0)
    for v in (0.0, REST, 0.5, 3.0, -0.5, -5.0):
        assert added(comp, v, y=0.0, r=1.0) == 0.0
        assert added(comp, v, y=1.0, r=0.0) == 0.0
    assert "scale=0" in repr(comp)


# --------------------------------------------------------------------------------------------
# Batching, saturation, reset
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
def test_batched_observations_match_single_ones(mode):
    base = np.array([0.5, -0.5, 0.0, 0.5, -0.5])
    obs = np.array(
        [[0.0, 0.0, 1.0], [0.0, 0.05, -1.0], [1.0, 0.0, 1.0], [0.0, 1.0, -1.0], [0.0, -6.0, 1.0]]
    )
    comp = FrictionCompensator(Constant(spec(), base), MODEL, mode=mode, smoothing=0.4)
    actions = comp(obs)
    assert actions.shape == (5, 1)
    for i in range(5):
        single = FrictionCompensator(Constant(spec(), base[i]), MODEL, mode=mode, smoothing=0.4)
        np.testing.assert_array_equal(actions[i], single(obs[i]))


def test_the_total_is_saturated_at_the_limit():
    obs = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    comp = FrictionCompensator(Constant(spec(limit=1.0), [0.95, -0.95, 0.5]), MODEL)
    np.testing.assert_array_equal(comp(obs), [[1.0], [-1.0], [0.5 + US_POS]])
    # The unsaturated sum is still what command() returns.
    np.testing.assert_allclose(comp.command(obs), [0.95 + US_POS, -0.95 - US_NEG, 0.5 + US_POS])


def test_reset_is_forwarded_to_the_base():
    comp = compensator()
    comp.reset()
    comp.reset([True, False, True])
    assert comp.base.resets[0] is None
    np.testing.assert_array_equal(comp.base.resets[1], [True, False, True])
    # and with a real PID: the masked env's integral is forgotten
    pid = PID(spec(), PIDGains(kp=1.0, ki=1.0))
    comp = FrictionCompensator(pid, MODEL)
    comp(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]))
    comp.reset([False, True])
    np.testing.assert_allclose(pid.integral, [0.01, 0.0])


def test_default_model_is_the_specs_friction():
    comp = FrictionCompensator(Constant(spec(friction=ROTARY_PAPER)))
    assert comp.model is ROTARY_PAPER
    assert comp.mode == "command"
    assert added(comp, 0.0) == ROTARY_PAPER.us_pos
    env = gym.make(SERVO)
    pid = PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS))
    comp = FrictionCompensator(pid)
    assert comp.model == ROTARY_PAPER  # the device file's law, read as the preset is
    assert comp.rest_speed == pid.spec.rest_speed == 0.1


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def test_bad_settings_raise():
    with pytest.raises(ValueError, match=r"mode must be one of .*'bang-bang'"):
        compensator(mode="bang-bang")
    with pytest.raises(ValueError, match="velocity entry"):
        FrictionCompensator(Constant(spec(velocity=None)), MODEL)
    with pytest.raises(ValueError, match="no friction model"):
        FrictionCompensator(Constant(spec(friction=None)))
    for smoothing in (0.0, -1.0):
        with pytest.raises(ValueError, match="smoothing > 0"):
            compensator(mode="smooth", smoothing=smoothing)
    with pytest.raises(ValueError, match="smoothing must be finite, got nan"):
        compensator(mode="smooth", smoothing=math.nan)
    # smoothing defaults to the rest speed, so a zero rest speed needs an explicit one
    with pytest.raises(ValueError, match="smoothing > 0"):
        FrictionCompensator(Constant(spec(rest_speed=0.0)), MODEL, mode="smooth")
    compensator(mode="command", smoothing=0.0)  # only the smooth mode reads it
    with pytest.raises(ValueError, match="rest_speed must be >= 0"):
        compensator(rest_speed=-0.1)
    with pytest.raises(ValueError, match="scale factor"):
        compensator(scale=-1.0)


# --------------------------------------------------------------------------------------------
# Closed loop on the envs (physical claims of the paper's compensator)
# --------------------------------------------------------------------------------------------


def _servo_metrics(friction, compensate):
    env = gym.make(SERVO, friction=friction)
    controller = PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS))
    if compensate:
        controller = FrictionCompensator(controller, ROTARY_PAPER, mode="command", scale=1.0)
    return rollout(env, controller).metrics()


def test_compensation_reduces_the_servo_steady_state_error():
    pid = _servo_metrics("paper", compensate=False)
    compensated = _servo_metrics("paper", compensate=True)
    assert compensated.steady_state_error < pid.steady_state_error
    assert compensated.iae < pid.iae


def test_compensating_friction_that_is_not_there_makes_things_worse():
    pid = _servo_metrics("none", compensate=False)
    over = _servo_metrics("none", compensate=True)
    assert over.steady_state_error > pid.steady_state_error
    assert over.iae > pid.iae


def test_over_estimated_altino_friction_drives_a_limit_cycle():
    env = gym.make(ALTINO, max_episode_steps=1200)
    amplitude = {}
    for scale in (1.0, 1.5):
        pid = PID.for_env(env, PIDGains(**ALTINO_PAPER_GAINS_COMPENSATED))
        run = rollout(env, FrictionCompensator(pid, scale=scale))
        assert run.length[0] == 1201
        amplitude[scale] = run.metrics().limit_cycle_amplitude
    assert amplitude[1.5] > 0.0
    assert amplitude[1.0] == 0.0


def test_for_env_builds_the_compensator_on_gains_a_base_or_the_paper_s_pid():
    env = gym.make(ALTINO)
    paper = FrictionCompensator.for_env(env)
    assert paper.base.gains == PIDGains(**ALTINO_PAPER_GAINS_COMPENSATED)
    assert paper.model == paper.spec.friction  # the env's model: the device's paper friction
    on_gains = FrictionCompensator.for_env(env, {"kp": 1.0, "ki": 0.0, "kd": 0.0}, mode="error")
    assert (on_gains.base.gains, on_gains.mode) == (PIDGains(1.0, 0.0, 0.0), "error")
    pid = PID.for_env(env, PIDGains(2.0, 0.0, 0.0))
    on_base = FrictionCompensator.for_env(env, pid, MODEL, scale=1.2)
    assert on_base.base is pid
    assert on_base.model == MODEL.scaled(1.2)
    obs, _ = env.reset(seed=0)
    assert paper(obs).shape == (1,)
    env.close()


def test_for_env_builds_the_residual_controller_on_the_base_of_training():
    class Zero:  # a policy that adds nothing
        def predict(self, observation, deterministic=True):
            return np.zeros((*np.shape(observation)[:-1], 1)), None

    env = gym.make(SERVO)
    config = ResidualConfig.for_env(env)
    residual = ResidualController.for_env(env, Zero(), config)
    assert isinstance(residual.base, FrictionCompensator)
    assert residual.base.base.gains == PIDGains(**ROTARY_PAPER_GAINS)
    obs, _ = env.reset(seed=0)
    _, added = residual.residual(obs)
    assert added.tolist() == [0.0]
    pid = PID.for_env(env, PIDGains(1.0, 0.0, 0.0))
    assert ResidualController.for_env(env, Zero(), config, base=pid).base is pid
    env.close()
