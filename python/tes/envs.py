"""Our worlds as Gymnasium environments, registered by ``import tes``.

* ``tes/GridTask-v0`` (:class:`GridTaskEnv`) — a grid task of the paper's §5.1 suite
  (``task`` 0–14, ``irrelevant`` random features per cell, ``world_seed`` for the layout).
* ``tes/Arena-v0`` (:class:`ArenaEnv`) — a robot arena of §5.2 (``arena`` 1–3): a
  differential-drive robot with wheel slip, 3 actions, 20 effects, 312 camera features.

Observations are a ``Dict``: ``"state"`` (the state id the structures number by),
``"features"`` (the state's binary features, ``MultiBinary``) and the state's attributes
(``"position"`` ``(x, y)`` on the grid; ``"attributes"`` ``(x, y, orientation)`` in the arena,
``(cells, cells, 0)`` once the robot has left it). ``info["effect"]`` is the effect the last
action had. ``reset(seed=...)`` makes every later step reproducible; ``reset(options=...)``
with any option is refused (``ValueError``: the settings are ``make`` arguments), and a
``step`` after the episode ended (terminated or truncated) raises
``gymnasium.error.ResetNeeded`` in both worlds. Both pickle and ``copy.deepcopy`` (the world
with its random source's exact position). ``render_mode="rgb_array"``
draws the world with the agent.

>>> import gymnasium, tes
>>> env = gymnasium.make("tes/GridTask-v0", task=1, irrelevant=20)
>>> obs, info = env.reset(seed=3)
>>> sorted(obs)
['features', 'position', 'state']
>>> obs["features"].shape
(30,)
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from tes import _tes

__all__ = ["GridTaskEnv", "ArenaEnv"]

GRID_EFFECTS = ("north", "east", "south", "west", "stayed")

# Surface colours (RGB): grid sand, soil, water, brick, fire; arena carpet, board, beans, slope.
_GRID_SURFACES = np.array(
    [[237, 214, 160], [150, 105, 60], [80, 140, 220], [175, 70, 55], [255, 120, 20]], np.uint8
)
_ARENA_SURFACES = np.array(
    [[236, 236, 236], [247, 243, 227], [217, 185, 155], [207, 227, 180]], np.uint8
)


def _no_options(options: dict | None) -> None:
    """Neither world takes reset options: refuse any rather than ignore them."""
    if options:
        raise ValueError(
            f"reset() takes no options here (got {sorted(options)}); "
            "the world's settings are make() arguments"
        )


def _check_not_over(over: bool) -> None:
    """Stepping after the episode ended is an error, as the arena's own rule has it."""
    if over:
        raise gymnasium.error.ResetNeeded(
            "the episode is over (terminated or truncated); reset() starts the next"
        )


def _seed_from(rng: np.random.Generator) -> int:
    """A seed for the native world's random source, drawn from Gymnasium's."""
    return int(rng.integers(0, 2**63 - 1))


class GridTaskEnv(gymnasium.Env):
    """A grid task of the paper's §5.1 (see the module docs). Actions: 0 north, 1 east,
    2 south, 3 west; −0.01 per action, −1 for fire and +1 for an exit (both end the episode);
    an episode is cut off (truncated) after ``4 · (width + height)`` actions."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 8}

    def __init__(
        self,
        task: int = 0,
        irrelevant: int = 200,
        world_seed: int = 0,
        render_mode: str | None = None,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', not {render_mode!r}")
        self.task, self.world_seed = int(task), int(world_seed)
        if not 0 <= self.world_seed < 2**64:
            raise ValueError(f"world_seed must be from 0 to 2**64 - 1, not {world_seed!r}")
        if int(irrelevant) < 0:
            raise ValueError(f"irrelevant must be at least 0, not {irrelevant!r}")
        self.world = _tes.GridWorld(self.task, int(irrelevant), self.world_seed)
        self.render_mode = render_mode
        w, h = self.world.width, self.world.height
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Discrete(self.world.n_states),
                "features": spaces.MultiBinary(self.world.n_features),
                "position": spaces.MultiDiscrete([w, h]),
            }
        )
        self.action_space = spaces.Discrete(4)
        self._steps = 0
        self._over = False
        self._layout = self.world.layout()

    def _obs(self, state: int) -> dict[str, Any]:
        features = np.zeros(self.world.n_features, dtype=np.int8)
        features[self.world.features(state)] = 1
        w = self.world.width
        return {
            "state": state,
            "features": features,
            "position": np.array([state % w, state // w], dtype=np.int64),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _no_options(options)
        super().reset(seed=seed)
        self._steps = 0
        self._over = False
        state = self.world.reset(_seed_from(self.np_random))
        return self._obs(state), {}

    def step(self, action: Any):
        if not self.action_space.contains(action):
            raise ValueError(f"action must be 0 to 3, not {action!r}")
        _check_not_over(self._over)
        state, effect, reward, terminal = self.world.step(int(action))
        self._steps += 1
        truncated = not terminal and self._steps >= self.world.step_cap
        self._over = terminal or truncated
        info = {"effect": effect, "effect_name": GRID_EFFECTS[effect]}
        return self._obs(state), reward, terminal, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        surfaces, walls, exits = self._layout
        h, w = surfaces.shape
        px = max(6, 480 // max(w, h))
        image = np.repeat(np.repeat(_GRID_SURFACES[surfaces], px, 0), px, 1)
        for y, x in zip(*np.nonzero(exits)):
            image[y * px + 1 : (y + 1) * px - 1, x * px + 1 : (x + 1) * px - 1] = (40, 170, 60)
        for y, x, side in zip(*np.nonzero(walls)):
            top, left = y * px, x * px
            if side == 0:
                image[top : top + 2, left : left + px] = 0
            elif side == 1:
                image[top : top + px, left + px - 2 : left + px] = 0
            elif side == 2:
                image[top + px - 2 : top + px, left : left + px] = 0
            else:
                image[top : top + px, left : left + 2] = 0
        y, x = divmod(self.world.state, w)
        _disc(image, (y + 0.5) * px, (x + 0.5) * px, px * 0.35, (20, 20, 20))
        return image


class ArenaEnv(gymnasium.Env):
    """A robot arena of the paper's §5.2 (see the module docs). Actions: 0 forward (both
    wheels 246°), 1 spin (left 90°, right −90°), 2 pivot (left 90°); +2 for the ball's cell,
    −1 for a death spot or leaving the area (all three end the episode), −0.05 otherwise. An
    episode is truncated when the robot is stuck for 4 actions (the paper's rule) or after
    ``max_actions``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, arena: int = 1, max_actions: int = 100, render_mode: str | None = None):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', not {render_mode!r}")
        if max_actions < 1:
            raise ValueError(f"max_actions must be at least 1, not {max_actions}")
        self.arena = int(arena)
        self.world = _tes.ArenaWorld(self.arena)
        self.max_actions = int(max_actions)
        self.render_mode = render_mode
        n = self.world.cells
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Discrete(self.world.n_states),
                "features": spaces.MultiBinary(self.world.n_features),
                "attributes": spaces.MultiDiscrete([n + 1, n + 1, 8]),
            }
        )
        self.action_space = spaces.Discrete(3)
        self._steps = 0
        self._over = False
        self._layout = self.world.layout()

    def _obs(self, state: int) -> dict[str, Any]:
        features = np.zeros(self.world.n_features, dtype=np.int8)
        features[self.world.features(state)] = 1
        return {
            "state": state,
            "features": features,
            "attributes": np.array(self.world.attributes(state), dtype=np.int64),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _no_options(options)
        super().reset(seed=seed)
        self._steps = 0
        self._over = False
        state = self.world.reset(_seed_from(self.np_random))
        return self._obs(state), {"pose": self.world.pose}

    def step(self, action: Any):
        if not self.action_space.contains(action):
            raise ValueError(f"action must be 0 to 2, not {action!r}")
        _check_not_over(self._over)
        state, effect, reward, terminal = self.world.step(int(action))
        self._steps += 1
        truncated = not terminal and (self.world.stuck or self._steps >= self.max_actions)
        self._over = terminal or truncated
        info = {
            "effect": effect,
            "effect_name": self.world.effect_name(effect),
            "pose": self.world.pose,
            "stuck": self.world.stuck,
        }
        return self._obs(state), reward, terminal, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        layout = self._layout
        n, side = self.world.cells, self.world.side_cm
        px = 480 // n
        scale = n * px / side
        # Row 0 of the layout is the south edge; the image's row 0 is its top (north).
        surfaces = layout["surfaces"][::-1]
        image = np.repeat(np.repeat(_ARENA_SURFACES[surfaces], px, 0), px, 1)
        image[::px, :] = (185, 185, 185)
        image[:, ::px] = (185, 185, 185)

        def at(x_cm: float, y_cm: float) -> tuple[float, float]:
            return (side - y_cm) * scale, x_cm * scale

        for y, x in zip(*np.nonzero(layout["death"][::-1])):
            for i in range(px // 5, px - px // 5):
                for dx in (i, px - 1 - i):
                    image[y * px + i, x * px + dx] = (200, 0, 0)
        for colour, rgb in (("green", (44, 160, 44)), ("blue", (31, 95, 191))):
            for mx, my in layout[colour]:
                row, col = at(mx, my)
                r0, c0 = int(row) - 3, int(col) - 3
                image[max(r0, 0) : r0 + 7, max(c0, 0) : c0 + 7] = rgb
        _disc(image, *at(*layout["ball"]), px * 0.3, (31, 95, 191))
        x, y, heading = self.world.pose
        row, col = at(x, y)
        _disc(image, row, col, px * 0.3, (30, 30, 30))
        for t in np.linspace(0, px * 0.55, 12):
            r, c = int(row - t * np.sin(heading)), int(col + t * np.cos(heading))
            if 0 <= r < image.shape[0] and 0 <= c < image.shape[1]:
                image[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2] = (230, 40, 40)
        return image


def _disc(image: np.ndarray, row: float, col: float, radius: float, rgb: tuple) -> None:
    """Fills a disc centred at ``(row, col)`` pixels (clipped to the image)."""
    h, w, _ = image.shape
    r0, r1 = max(int(row - radius), 0), min(int(row + radius) + 1, h)
    c0, c1 = max(int(col - radius), 0), min(int(col + radius) + 1, w)
    if r0 >= r1 or c0 >= c1:
        return
    rows, cols = np.ogrid[r0:r1, c0:c1]
    inside = (rows - row) ** 2 + (cols - col) ** 2 <= radius**2
    image[r0:r1, c0:c1][inside] = rgb
