"""Frames of the numpy rasteriser and the lazily opened pygame window."""

import math
import pickle
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import DependencyNotInstalled

from frictiongym.envs import rendering
from frictiongym.envs.rendering import Window, draw_altino, draw_servo


def _car_centroid_x(frame: np.ndarray) -> float:
    car = np.all(frame == rendering.MOVING, axis=-1)
    assert car.sum() > 100
    return float(np.nonzero(car)[1].mean())


def test_servo_frame_shape_and_dtype():
    frame = draw_servo(0.3, -0.2)
    assert frame.shape == (400, 400, 3)
    assert frame.dtype == np.uint8
    assert draw_servo(0.3, -0.2, size=64).shape == (64, 64, 3)


def test_altino_frame_shape_and_dtype():
    frame = draw_altino(12.0, 5.0)
    assert frame.shape == (200, 600, 3)
    assert frame.dtype == np.uint8
    assert draw_altino(12.0, 5.0, width=300, height=120).shape == (120, 300, 3)


def test_servo_indicator_points_up_at_zero_and_left_at_half_pi():
    up, left = (200 - 100, 200), (200, 200 - 100)  # (row, col), 100 px from the centre
    at_zero, at_quarter = draw_servo(0.0, math.pi), draw_servo(math.pi / 2, math.pi)
    assert tuple(at_zero[up]) == rendering.INDICATOR
    assert tuple(at_zero[left]) == rendering.MOVING
    assert tuple(at_quarter[left]) == rendering.INDICATOR  # counter-clockwise
    assert tuple(at_quarter[up]) == rendering.MOVING


@pytest.mark.parametrize("angle", [-7.0, 0.0, 1.2, 40.0])
def test_servo_frame_changes_with_angle(angle):
    assert not np.array_equal(draw_servo(angle, 0.0), draw_servo(angle + 0.5, 0.0))


def test_servo_reference_marker_changes_the_image():
    a, b = draw_servo(0.0, 1.0), draw_servo(0.0, 2.5)
    assert not np.array_equal(a, b)
    target = np.all(a == rendering.TARGET, axis=-1)
    rows, cols = np.nonzero(target)
    assert cols.mean() < 200  # reference 1 rad: up and to the left
    assert rows.mean() < 200


def test_stuck_changes_both_frames():
    assert not np.array_equal(draw_servo(0.4, 0.0), draw_servo(0.4, 0.0, stuck=True))
    assert np.all(draw_servo(0.4, 0.0, stuck=True) == rendering.STUCK, axis=-1).any()
    assert not np.array_equal(draw_altino(10.0, 5.0), draw_altino(10.0, 5.0, stuck=True))
    assert np.all(draw_altino(10.0, 5.0, stuck=True) == rendering.STUCK, axis=-1).sum() > 100


def test_car_moves_left_as_distance_grows():
    xs = [_car_centroid_x(draw_altino(d, 5.0)) for d in (0.0, 5.0, 15.0, 25.0)]
    assert xs == sorted(xs, reverse=True)
    assert xs[0] - xs[1] == pytest.approx(5.0 * 576 / 35.0, abs=1.0)  # scale: 35 cm per 576 px


def test_target_line_moves_with_target():
    def target_x(frame: np.ndarray) -> float:
        return float(np.nonzero(np.all(frame == rendering.TARGET, axis=-1))[1].mean())

    assert target_x(draw_altino(30.0, 10.0)) < target_x(draw_altino(30.0, 5.0))


@pytest.mark.parametrize("distance", [-3.0, 0.0, 34.9, 35.0, 80.0, 1e9])
def test_extreme_distances_draw_part_of_the_car(distance):
    frame = draw_altino(distance, 5.0)
    assert np.all(frame == rendering.MOVING, axis=-1).sum() > 100


def test_touching_and_far_clip_to_the_view():
    below_captions = slice(50, None)  # the captions print the distance itself
    assert np.array_equal(draw_altino(-3.0, 5.0)[below_captions], draw_altino(0.0, 5.0)[50:])
    assert np.array_equal(draw_altino(80.0, 5.0)[below_captions], draw_altino(1e9, 5.0)[50:])


def test_captions_print_time_and_command_in_their_corner():
    a = draw_servo(0.5, 1.0, time=1.0, command=0.2)
    b = draw_servo(0.5, 1.0, time=2.0, command=0.2)
    rows, cols = np.nonzero(np.any(a != b, axis=2))
    assert rows.size
    assert rows.max() < 40
    assert cols.max() < 200
    c = draw_servo(0.5, 1.0, time=1.0, command=-0.2)
    rows, cols = np.nonzero(np.any(a != c, axis=2))
    assert rows.min() > 360
    assert cols.min() > 200
    plain = draw_servo(0.5, 1.0)
    assert np.any(a != plain)  # no time and command: no captions for them
    car = draw_altino(10.0, 5.0, time=0.5, command=300.0)
    assert np.any(car != draw_altino(10.0, 5.0, time=0.5, command=-300.0))


def test_env_frames_carry_their_captions():
    env = gym.make("frictiongym/AltinoDistance-v1", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    env.step(np.array([0.0], np.float32))
    assert np.any(first[:50] != env.render()[:50])  # the time moved on, nothing else did


def test_window_without_a_display_warns_once_and_skips_pacing(monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.delenv("SDL_VIDEODRIVER", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    window = Window("servo", fps=1.0)  # paced, this would take a second per frame
    try:
        with pytest.warns(UserWarning, match="no display is available"):
            window.show(draw_servo(0.0, 0.0, size=32))
        assert not window.shown
        ticks = []

        class Clock:
            def tick(self, fps: float) -> None:
                ticks.append(fps)

        window._clock = Clock()
        window.show(draw_servo(0.0, 0.0, size=32))
        assert ticks == []  # not paced
    finally:
        window.close()


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_input_raises(bad):
    with pytest.raises(ValueError, match="angle must be finite"):
        draw_servo(bad, 0.0)
    with pytest.raises(ValueError, match="reference must be finite"):
        draw_servo(0.0, bad)
    with pytest.raises(ValueError, match="distance_cm must be finite"):
        draw_altino(bad, 5.0)
    with pytest.raises(ValueError, match="target_cm must be finite"):
        draw_altino(5.0, bad)


def test_bad_sizes_and_view_raise():
    with pytest.raises(ValueError, match="size"):
        draw_servo(0.0, 0.0, size=2)
    with pytest.raises(ValueError, match="view_cm"):
        draw_altino(5.0, 5.0, view_cm=0.0)


def test_frames_are_fresh_arrays():
    frame = draw_servo(0.0, 0.0)
    frame[:] = 0  # the cached background must not be shared with callers
    assert draw_servo(0.0, 0.0).max() == 255


def test_window_without_pygame_raises(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)
    window = Window("servo", fps=50.0)
    with pytest.raises(DependencyNotInstalled, match="pip install pygame") as info:
        window.show(draw_servo(0.0, 0.0, size=32))
    assert "rgb_array" in str(info.value)
    window.close()


def test_window_pickles_before_show():
    window = Window("servo", fps=0.0)
    clone = pickle.loads(pickle.dumps(window))
    assert (clone.title, clone.fps) == ("servo", 0.0)


def test_window_shows_frames_with_dummy_driver(monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    window = Window("altino", fps=1000.0)
    try:
        window.show(draw_altino(10.0, 5.0))
        window.show(draw_altino(9.0, 5.0))
        window.show(draw_servo(0.0, 1.0, size=64))  # a new size reopens the display
        assert window._screen.get_size() == (64, 64)
        clone = pickle.loads(pickle.dumps(window))
        assert clone._screen is None
    finally:
        window.close()
    window.close()  # idempotent


@pytest.mark.parametrize(("width", "height"), [(600, 200), (400, 400), (256, 96)])
def test_the_ruler_numbers_are_whole_not_cut_by_the_frame_or_the_wall(width, height):
    """The left edge of the ruler's label row holds no ink (a "35" was cut to "5"), and the
    wall's "0" stands beside it, left of the wall's face."""
    frame = draw_altino(distance_cm=50.0, target_cm=5.0, width=width, height=height)
    wall_x, ground, line = rendering._layout(width, height)
    labels = frame[int(ground + 0.08 * height) : int(ground + 0.08 * height) + 7]
    ink = np.abs(labels.astype(int) - np.array(rendering.PANEL)).sum(axis=2) > 60
    assert not ink[:, 0].any()
    assert ink[:, int(wall_x - 3 * line) - 12 : int(wall_x - line)].any()  # the "0"
