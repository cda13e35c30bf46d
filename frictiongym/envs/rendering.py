"""Light rendering for the QUBE-Servo 2 and Altino envs.

Frames need numpy alone: each shape is a signed-distance field (in pixels, negative inside)
evaluated on a cached pixel grid, turned into anti-aliased coverage ``clip(0.5 - sdf, 0, 1)`` and
alpha-blended in painter's order onto a white background. Each shape is evaluated only inside its
bounding box, which keeps a default-size frame at a few milliseconds. Captions (time, position,
reference, command) use a 5x7 bitmap font (:mod:`frictiongym.envs._font`) and a scale is drawn
on each frame: ticks every 30 degrees around the servo's disk, a ruler in cm under the car.
Only :class:`Window` (``render_mode="human"``) needs pygame, and imports it on first use.
"""

from __future__ import annotations

import functools
import importlib
import math
import os
import warnings
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium.error import DependencyNotInstalled

from frictiongym._validation import real_number
from frictiongym.envs._font import GLYPH_HEIGHT, text_mask

__all__ = ["CAR_LENGTH_CM", "Window", "draw_altino", "draw_axis", "draw_servo"]

Colour = tuple[int, int, int]
_F = npt.NDArray[np.float32]
_P = tuple[float, float]
_Box = tuple[float, float, float, float]
_Sdf = Callable[[_F, _F], _F]

# Muted palette; blue/red/orange stay apart for the common colour-vision deficiencies.
BACKGROUND: Colour = (255, 255, 255)
INK: Colour = (52, 58, 68)  # rim, wall, ground, tyres
PANEL: Colour = (226, 229, 234)  # QUBE housing, wall and ground fill, hubs
MOVING: Colour = (76, 114, 176)  # disk and car body
STUCK: Colour = (196, 78, 82)  # rim / car body while stuck in stiction
TARGET: Colour = (221, 132, 82)  # reference angle, target distance
INDICATOR: Colour = (250, 250, 250)
GLASS: Colour = (196, 216, 236)

CAR_LENGTH_CM = 8.0
"""Drawn car length. The real Altino is ~16 cm; half of that reads better in a 35 cm view."""


@functools.lru_cache(maxsize=8)
def _grid(height: int, width: int) -> tuple[_F, _F]:
    """Pixel-centre coordinates as broadcastable ``(height, 1)`` rows and ``(1, width)`` columns."""
    ys = (np.arange(height, dtype=np.float32) + 0.5)[:, None]
    xs = (np.arange(width, dtype=np.float32) + 0.5)[None, :]
    ys.flags.writeable = xs.flags.writeable = False  # shared by every frame of this size
    return ys, xs


def _circle_sdf(ys: _F, xs: _F, cx: float, cy: float, r: float) -> _F:
    return np.hypot(xs - cx, ys - cy) - np.float32(r)


def _segment_sdf(ys: _F, xs: _F, a: _P, b: _P, r: float, dash: float = 0.0) -> _F:
    """Capsule of radius ``r`` from ``a`` to ``b`` (x, y); ``dash > 0`` cuts it into dashes."""
    bx, by = b[0] - a[0], b[1] - a[1]
    length = max(math.hypot(bx, by), 1e-6)
    px, py = xs - a[0], ys - a[1]
    s = (px * bx + py * by) / length  # distance along the segment
    h = np.clip(s / length, 0.0, 1.0)
    d = np.hypot(px - bx * h, py - by * h) - np.float32(r)
    if dash > 0.0:  # period 2*dash: dash on, gap off, starting with a full dash at `a`
        d = np.maximum(d, np.abs(np.mod(s, 2.0 * dash) - dash / 2.0) - dash / 2.0)
    return d


def _box_sdf(ys: _F, xs: _F, x0: float, y0: float, x1: float, y1: float, radius: float = 0.0) -> _F:
    """Axis-aligned box with corners rounded by ``radius``."""
    qx = np.abs(xs - (x0 + x1) / 2) - ((x1 - x0) / 2 - radius)
    qy = np.abs(ys - (y0 + y1) / 2) - ((y1 - y0) / 2 - radius)
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
    return outside + np.minimum(np.maximum(qx, qy), 0.0) - np.float32(radius)


def _triangle_sdf(ys: _F, xs: _F, a: _P, b: _P, c: _P) -> _F:
    """Max of the edge half-planes: exact inside, slightly rounder corners outside (fine for AA)."""
    sign = math.copysign(1.0, (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
    d = [
        ((xs - p[0]) * (q[1] - p[1]) - (ys - p[1]) * (q[0] - p[0]))
        * np.float32(sign / math.dist(p, q))
        for p, q in ((a, b), (b, c), (c, a))
    ]
    return np.maximum(np.maximum(d[0], d[1]), d[2])


def _paint(canvas: _F, box: _Box, colour: Colour, sdf: _Sdf, alpha: float = 1.0) -> None:
    """Blend ``colour`` with the coverage of ``sdf`` inside ``box`` (x0, y0, x1, y1) of pixels."""
    h, w = canvas.shape[:2]
    c0, r0 = max(int(box[0]) - 2, 0), max(int(box[1]) - 2, 0)
    c1, r1 = min(int(box[2]) + 3, w), min(int(box[3]) + 3, h)
    if c0 >= c1 or r0 >= r1:
        return  # off-canvas
    ys, xs = _grid(h, w)
    coverage = np.clip(0.5 - sdf(ys[r0:r1], xs[:, c0:c1]), 0.0, 1.0) * np.float32(alpha)
    region = canvas[r0:r1, c0:c1]
    region += coverage[..., None] * (np.asarray(colour, np.float32) - region)


def _box(canvas: _F, box: _Box, colour: Colour, radius: float = 0.0) -> None:
    _paint(canvas, box, colour, lambda y, x: _box_sdf(y, x, *box, radius))


def _disc(canvas: _F, cx: float, cy: float, r: float, colour: Colour) -> None:
    _paint(
        canvas, (cx - r, cy - r, cx + r, cy + r), colour, lambda y, x: _circle_sdf(y, x, cx, cy, r)
    )


def _triangle(canvas: _F, a: _P, b: _P, c: _P, colour: Colour) -> None:
    xs, ys = zip(a, b, c, strict=True)
    box = (min(xs), min(ys), max(xs), max(ys))
    _paint(canvas, box, colour, lambda y, x: _triangle_sdf(y, x, a, b, c))


def _line(
    canvas: _F, a: _P, b: _P, r: float, colour: Colour, dash: float = 0.0, alpha: float = 1.0
) -> None:
    """Draw a capsule of radius ``r`` from ``a`` to ``b``, dashed if ``dash > 0``."""
    box = (min(a[0], b[0]) - r, min(a[1], b[1]) - r, max(a[0], b[0]) + r, max(a[1], b[1]) + r)
    _paint(canvas, box, colour, lambda y, x: _segment_sdf(y, x, a, b, r, dash), alpha)


def _text(canvas: _F, x: float, y: float, text: str, scale: int, align: str = "left") -> None:
    """Write ``text`` in :data:`INK` with its top-left (``align="left"``) or top-right at x, y."""
    mask = text_mask(text, scale)
    h, w = canvas.shape[:2]
    x0 = round(x - mask.shape[1] if align == "right" else x)
    y0 = round(y)
    r0, c0 = max(y0, 0), max(x0, 0)
    r1, c1 = min(y0 + mask.shape[0], h), min(x0 + mask.shape[1], w)
    if r0 < r1 and c0 < c1:
        region = canvas[r0:r1, c0:c1]
        region[mask[r0 - y0 : r1 - y0, c0 - x0 : c1 - x0]] = INK


def _captions(
    canvas: _F, pad: float, scale: int, first: str, time: float | None, command: str | None
) -> None:
    """Write the first caption line, and a second of the time and the command if given."""
    _text(canvas, pad, pad, first, scale)
    second = [] if time is None else [f"t {time:.2f} s"]
    if command is not None:
        second.append(command)
    if second:
        _text(canvas, pad, pad + (GLYPH_HEIGHT + 3) * scale, "  ".join(second), scale)


def _scale_of(pixels: float) -> int:
    """Integer size of the captions' pixels: one per ``pixels`` of the frame, at least 1."""
    return max(1, int(pixels))


def _new_canvas(height: int, width: int) -> _F:
    return np.broadcast_to(np.asarray(BACKGROUND, np.float32), (height, width, 3)).copy()


def _to_frame(canvas: _F) -> npt.NDArray[np.uint8]:
    return np.clip(canvas + 0.5, 0, 255).astype(np.uint8)


def _check(sizes: dict[str, int], **values: float) -> None:
    for name, value in values.items():
        real_number(name, value)
    for name, size in sizes.items():
        if int(size) != size or size < 8:
            raise ValueError(f"{name} must be an integer >= 8 pixels, got {size!r}")


def draw_servo(
    angle: float,
    reference: float,
    *,
    stuck: bool = False,
    size: int = 400,
    time: float | None = None,
    command: float | None = None,
) -> npt.NDArray[np.uint8]:
    """Draw the QUBE-Servo 2 seen from above, with ticks every 30 degrees around the disk.

    Captions give the angle and the reference, and the time and command when given.

    Parameters
    ----------
    angle : float
        Disk angle in rad; 0 points up, positive is counter-clockwise.
    reference : float
        Reference angle in rad, drawn as an orange triangle outside the rim and a dashed spoke.
    stuck : bool
        Whether the disk is stuck in stiction; the rim turns red.
    size : int
        Side of the square frame in pixels.
    time : float, optional
        Time since the episode's start, s.
    command : float, optional
        Applied command, V.

    Returns
    -------
    numpy.ndarray
        ``(size, size, 3)`` uint8 RGB frame.

    Raises
    ------
    ValueError
        If an angle is not finite or ``size`` is not an integer >= 8.
    """
    _check({"size": size}, angle=angle, reference=reference)
    canvas, s = _servo_base(size, stuck).copy(), float(size)
    c, radius, rim = s / 2, 0.34 * s, 0.025 * s

    def polar(theta: float, r: float) -> tuple[float, float]:
        return c - r * math.sin(theta), c - r * math.cos(theta)  # image y grows downwards

    _line(canvas, (c, c), polar(reference, radius + 0.03 * s), 0.007 * s, TARGET, 0.025 * s, 0.9)
    _line(canvas, (c, c), polar(angle, radius - rim / 2), 0.014 * s, INDICATOR)
    _disc(canvas, c, c, 0.05 * s, INK)
    half = 0.045 * s  # triangle just outside the rim, pointing at the centre
    apex, (bx, by) = polar(reference, radius + rim), polar(reference, radius + rim + 0.075 * s)
    ux, uy = math.cos(reference) * half, -math.sin(reference) * half  # tangent to the rim
    _triangle(canvas, apex, (bx + ux, by + uy), (bx - ux, by - uy), TARGET)
    scale = _scale_of(s / 200.0)  # 2 on the default 400-pixel frame
    pad, bottom = 0.05 * s, s - 0.05 * s - GLYPH_HEIGHT * scale
    _text(canvas, pad, bottom, f"angle {angle:+.3f} rad", scale)
    _text(canvas, s - pad, pad, f"ref {reference:+.3f} rad", scale, "right")
    if time is not None:
        _text(canvas, pad, pad, f"t {time:.3f} s", scale)
    if command is not None:
        _text(canvas, s - pad, bottom, f"u {command:+.2f} V", scale, "right")
    return _to_frame(canvas)


@functools.lru_cache(maxsize=8)
def _servo_base(size: int, stuck: bool) -> _F:
    """Draw what never moves (housing, disk, rim): cached, as it covers the most pixels."""
    canvas, s = _new_canvas(size, size), float(size)
    c, radius, rim = s / 2, 0.34 * s, 0.025 * s
    _box(canvas, (0.04 * s, 0.04 * s, 0.96 * s, 0.96 * s), PANEL, 0.08 * s)
    _disc(canvas, c, c, radius, MOVING)
    disk = (c - radius - rim, c - radius - rim, c + radius + rim, c + radius + rim)
    ring: _Sdf = lambda y, x: np.abs(_circle_sdf(y, x, c, c, radius)) - np.float32(rim / 2)  # noqa: E731
    _paint(canvas, disk, STUCK if stuck else INK, ring)
    for k in range(12):  # the scale: a tick every 30 degrees, longer every 90
        theta = k * math.pi / 6.0
        inner = radius + rim + 0.01 * s
        outer = inner + (0.04 if k % 3 == 0 else 0.022) * s
        a = (c - inner * math.sin(theta), c - inner * math.cos(theta))
        b = (c - outer * math.sin(theta), c - outer * math.cos(theta))
        _line(canvas, a, b, 0.004 * s, INK)
    canvas.flags.writeable = False
    return canvas


def draw_altino(
    distance_cm: float,
    target_cm: float,
    *,
    stuck: bool = False,
    view_cm: float = 35.0,
    width: int = 600,
    height: int = 200,
    time: float | None = None,
    command: float | None = None,
) -> npt.NDArray[np.uint8]:
    """Draw the Altino car seen from the side, driving at a wall on the right.

    A ruler under the ground gives the distance to the wall in cm; captions give the distance
    and the target, and the time and command when given.

    Parameters
    ----------
    distance_cm : float
        Distance in cm from the car's front to the wall; ``<= 0`` draws it touching the wall.
        Past ``view_cm - 0.4 * CAR_LENGTH_CM`` the car is held at the left edge, 40 % visible,
        with a white chevron pointing off-screen.
    target_cm : float
        Target distance in cm, drawn as an orange dashed vertical line.
    stuck : bool
        Whether the car is stuck in stiction; the body turns red.
    view_cm : float
        Distance in cm spanned by the width left of the wall. The car is drawn
        :data:`CAR_LENGTH_CM` long at this scale.
    width, height : int
        Frame size in pixels.
    time : float, optional
        Time since the episode's start, s.
    command : float, optional
        Applied command, motor units.

    Returns
    -------
    numpy.ndarray
        ``(height, width, 3)`` uint8 RGB frame.

    Raises
    ------
    ValueError
        If a distance is not finite, ``view_cm <= 0`` or a size is not an integer >= 8.
    """
    _check(
        {"width": width, "height": height},
        distance_cm=distance_cm,
        target_cm=target_cm,
        view_cm=view_cm,
    )
    if view_cm <= 0:
        raise ValueError(f"view_cm must be > 0, got {view_cm!r}")
    canvas, (wall_x, ground, line) = (
        _altino_base(width, height, view_cm).copy(),
        _layout(width, height),
    )
    cm, h = wall_x / view_cm, float(height)  # pixels per cm
    xt, top = wall_x - target_cm * cm, 0.12 * h
    if xt <= wall_x:  # a target behind the wall face is hidden
        _line(canvas, (xt, ground), (xt, top), 0.6 * line, TARGET, dash=0.035 * h)
        _triangle(canvas, (xt, top + 0.06 * h), (xt - 0.04 * h, top), (xt + 0.04 * h, top), TARGET)

    length = CAR_LENGTH_CM * cm
    shown = min(max(distance_cm, 0.0), view_cm - 0.4 * CAR_LENGTH_CM)  # keep 40 % in view
    front = wall_x - line - shown * cm  # at 0 the bumper touches the wall's face
    rear, wheel = front - length, 1.0 * cm
    body = (rear, ground - 2.8 * cm, front, ground - 0.9 * cm)
    cabin = (rear + 0.22 * length, ground - 4.0 * cm, front - 0.3 * length, body[1] + 0.5 * cm)
    colour = STUCK if stuck else MOVING
    _box(canvas, cabin, colour, 0.6 * cm)
    glass = (cabin[0] + 0.4 * cm, cabin[1] + 0.4 * cm, cabin[2] - 0.4 * cm, body[1])
    _box(canvas, glass, GLASS, 0.3 * cm)
    _box(canvas, body, colour, 0.6 * cm)
    for wx in (rear + 0.2 * length, front - 0.2 * length):
        _disc(canvas, wx, ground - wheel, wheel, INK)
        _disc(canvas, wx, ground - wheel, 0.4 * wheel, PANEL)
    if distance_cm > view_cm - 0.4 * CAR_LENGTH_CM:  # held at the edge: point off-screen
        ym, hw, x0 = (body[1] + body[3]) / 2, 0.35 * (body[3] - body[1]), 0.4 * cm
        _triangle(canvas, (x0, ym), (x0 + 1.5 * hw, ym - hw), (x0 + 1.5 * hw, ym + hw), INDICATOR)
    scale = _scale_of(h / 100.0)  # 2 on the default 200-pixel-tall frame
    first = f"dist {distance_cm:.2f} cm  target {target_cm:.2f} cm"
    command_text = None if command is None else f"u {command:+.0f}"
    _captions(canvas, 0.03 * h, scale, first, time, command_text)
    return _to_frame(canvas)


def _layout(width: int, height: int) -> tuple[float, float, float]:
    """Wall face x, ground y and the half-thickness of the wall and ground lines, in pixels."""
    return width - max(0.04 * width, 6.0), 0.8 * height, max(0.01 * height, 1.0)


@functools.lru_cache(maxsize=8)
def _altino_base(width: int, height: int, view_cm: float) -> _F:
    """Draw what never moves: the ground, its ruler in cm and the hatched wall."""
    canvas, (wall_x, ground, line) = _new_canvas(height, width), _layout(width, height)
    w, h = float(width), float(height)
    _box(canvas, (-9, ground, w + 9, h + 9), PANEL)
    _box(canvas, (-9, ground - line, wall_x, ground + line), INK)
    wall, period = (wall_x, -9.0, w + 9, h + 9), max(0.06 * h, 4.0)
    hatch: _Sdf = lambda y, x: np.maximum(  # noqa: E731
        _box_sdf(y, x, *wall), np.abs(np.mod(x + y, period) - period / 2) * 0.7071 - 0.5 * line
    )
    _box(canvas, wall, PANEL)
    _paint(canvas, wall, INK, hatch)
    _box(canvas, (wall_x - line, -9, wall_x + line, h + 9), INK)
    cm, scale = wall_x / view_cm, _scale_of(h / 100.0)
    every = 5.0 if view_cm <= 60.0 else 10.0 ** math.floor(math.log10(view_cm / 6.0))
    for k in range(int(view_cm / every) + 1):  # the ruler: distance to the wall, cm
        x = wall_x - k * every * cm
        _line(canvas, (x, ground + line), (x, ground + 0.06 * h), 0.5 * line, INK)
        label = f"{k * every:g}" + (" cm" if k == 1 else "")
        width_px = 6 * scale * len(f"{k * every:g}")  # centre the number on its tick,
        left = x - width_px / 2 if k else x - line - width_px - scale  # 0 beside the wall
        if left >= 0.0:  # a number cut by the frame's edge would misread
            _text(canvas, left, ground + 0.08 * h, label, scale)
    canvas.flags.writeable = False
    return canvas


def draw_axis(
    position: float,
    reference: float,
    *,
    stuck: bool = False,
    span: float = 1.0,
    unit: str = "",
    width: int = 600,
    height: int = 160,
    time: float | None = None,
    command: float | None = None,
) -> npt.NDArray[np.uint8]:
    """Draw a linear axis from the side: a carriage on a rail over a ruler of ``±span``.

    The frame of a described device whose file names ``drawing = "draw_axis"``; captions
    give the position and the reference, and the time and command when given.

    Parameters
    ----------
    position, reference : float
        Carriage position and reference, in ``unit``; beyond ``±span`` the carriage is held
        at the rail's end.
    stuck : bool
        Whether the carriage is stuck in stiction; it turns red.
    span : float
        Half the rail's drawn length (the env passes its safety limit).
    unit : str
        The position's unit, for the captions.
    width, height : int
        Frame size in pixels.
    time : float, optional
        Time since the episode's start, s.
    command : float, optional
        Applied command.

    Returns
    -------
    numpy.ndarray
        ``(height, width, 3)`` uint8 RGB frame.
    """
    _check({"width": width, "height": height}, position=position, reference=reference, span=span)
    if span <= 0:
        raise ValueError(f"span must be > 0, got {span!r}")
    canvas = _new_canvas(height, width)
    w, h = float(width), float(height)
    margin, rail_y, line = 0.06 * w, 0.62 * h, max(0.01 * h, 1.0)
    per_unit = (w - 2 * margin) / (2 * span)

    def x_of(value: float) -> float:
        return margin + (min(max(value, -span), span) + span) * per_unit

    _box(canvas, (margin - 2 * line, rail_y, w - margin + 2 * line, rail_y + 0.05 * h), PANEL)
    _line(canvas, (margin, rail_y), (w - margin, rail_y), line, INK)
    scale = _scale_of(h / 80.0)
    every = 10.0 ** math.floor(math.log10(span))  # 2 to 20 ticks over the rail
    for k in range(-int(span / every), int(span / every) + 1):
        x = x_of(k * every)
        _line(canvas, (x, rail_y + 0.06 * h), (x, rail_y + 0.1 * h), 0.5 * line, INK)
        if k % 2 == 0 or span / every < 4:
            label = f"{k * every:g}"
            _text(canvas, x - 3 * scale * len(label), rail_y + 0.13 * h, label, scale)
    xr, top = x_of(reference), 0.22 * h
    _line(canvas, (xr, rail_y), (xr, top), 0.6 * line, TARGET, dash=0.035 * h)
    _triangle(canvas, (xr, top + 0.06 * h), (xr - 0.04 * h, top), (xr + 0.04 * h, top), TARGET)
    xc, half = x_of(position), 0.05 * w
    carriage = (xc - half, rail_y - 0.2 * h, xc + half, rail_y - line)
    _box(canvas, carriage, STUCK if stuck else MOVING, 0.02 * h)
    _line(canvas, (xc, carriage[1] + 0.03 * h), (xc, carriage[3] - 0.03 * h), line, INDICATOR)
    first = f"at {position:.3f} {unit}  ref {reference:.3f} {unit}"
    command_text = None if command is None else f"u {command:+.3g}"
    _captions(canvas, 0.03 * h, scale, first, time, command_text)
    return _to_frame(canvas)


class Window:
    """A ``render_mode="human"`` window showing frames with pygame, opened on the first ``show``.

    It holds no pygame object until then, and pickling keeps only the title and fps, so an env
    can be pickled (or copied to a subprocess) and reopens its window on demand.

    Parameters
    ----------
    title : str
        Window caption.
    fps : float
        Frames per second that :meth:`show` paces to; ``<= 0`` disables pacing.

    Notes
    -----
    Without a display (no ``$DISPLAY`` on Linux, e.g. a server or CI), SDL falls back to an
    off-screen driver: the window then warns once that nothing is shown and stops pacing, so a
    headless run is not slowed down for frames nobody sees. Setting ``SDL_VIDEODRIVER``
    yourself (``dummy`` in tests) keeps it quiet and paced.
    """

    def __init__(self, title: str, fps: float) -> None:
        self.title = title
        self.fps = fps
        self._pygame: ModuleType | None = None
        self._screen: Any = None
        self._clock: Any = None
        self._shown = True

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_pygame": None, "_screen": None, "_clock": None}

    @property
    def shown(self) -> bool:
        """False once :meth:`show` found no display to show frames on (see Notes)."""
        return self._shown

    def show(self, frame: npt.NDArray[np.uint8]) -> None:
        """Show ``frame`` (``(height, width, 3)`` uint8), opening the window if needed.

        Parameters
        ----------
        frame : numpy.ndarray
            RGB frame, e.g. from :func:`draw_servo` or :func:`draw_altino`.

        Raises
        ------
        gymnasium.error.DependencyNotInstalled
            If pygame is not installed.
        """
        pygame = self._pygame or _import_pygame()
        self._pygame = pygame
        size = (int(frame.shape[1]), int(frame.shape[0]))
        if self._screen is None or self._screen.get_size() != size:
            pygame.display.init()
            pygame.display.set_caption(self.title)
            self._screen = pygame.display.set_mode(size)
            self._clock = pygame.time.Clock()
            headless = pygame.display.get_driver() in ("offscreen", "dummy")
            if headless and "SDL_VIDEODRIVER" not in os.environ and self._shown:
                warnings.warn(
                    f"render_mode='human' ({self.title}): no display is available (SDL "
                    f"driver {pygame.display.get_driver()!r}), so frames are not shown and "
                    "steps are not paced; use render_mode='rgb_array' to record frames",
                    UserWarning,
                    stacklevel=3,
                )
                self._shown = False
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.transpose(1, 0, 2)))
        self._screen.blit(surface, (0, 0))
        pygame.event.pump()  # keeps the OS from flagging the window as unresponsive
        pygame.display.flip()
        if self.fps > 0 and self._shown:
            self._clock.tick(self.fps)

    def close(self) -> None:
        """Close the window; safe to call more than once or before any ``show``."""
        if self._pygame is not None:
            self._pygame.display.quit()
            self._pygame.quit()
        self._pygame = self._screen = self._clock = None


def _import_pygame() -> ModuleType:
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no banner on import
    try:
        return importlib.import_module("pygame")  # by name: mypy needs no pygame to check this
    except ImportError as exc:
        raise DependencyNotInstalled(
            'pygame is needed for render_mode="human": run `pip install pygame` (or '
            '`pip install "frictiongym[render]"`). render_mode="rgb_array" needs no extra '
            "dependency."
        ) from exc
