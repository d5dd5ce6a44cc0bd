"""Render a keep-away episode as an animated GIF (Pillow).

``python -m kx.sim.render --task 3v2 --policy heuristic --seed 0 --out episode.gif`` writes one
episode of a baseline policy; :func:`render_gif` takes any rollout from
:func:`kx.sim.evaluate.rollout`.
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np
from PIL import Image, ImageDraw

from kx.sim.types import KeepAwayConfig, Reason

KEEPER, TAKER, BALL, PASS, GRID, BG = (40, 110, 220), (215, 50, 50), (250, 200, 0), (250, 200, 0), (
    200, 200, 200), (245, 250, 240)


def frame(arrays: dict, i: int, config: KeepAwayConfig, cell: int = 24) -> Image.Image:
    """Frame ``i`` of the stacked state arrays (``kx.sim.env.as_numpy`` of a rollout)."""
    w = config.field_size
    top = 28
    img = Image.new("RGB", (w * cell + 1, w * cell + top + 1), BG)
    d = ImageDraw.Draw(img)
    for k in range(w + 1):
        d.line([(k * cell, top), (k * cell, top + w * cell)], fill=GRID)
        d.line([(0, top + k * cell), (w * cell, top + k * cell)], fill=GRID)

    def centre(x, y):
        return (x + 0.5) * cell, top + (y + 0.5) * cell

    holder = int(arrays["holder"][i])
    if holder < 0:  # a pass in flight: draw its line from the kicker's cell to the ball
        ox, oy = centre(int(arrays["origin_x"][i]), int(arrays["origin_y"][i]))
        bx, by = centre(int(arrays["ball_x"][i]), int(arrays["ball_y"][i]))
        d.line([(ox, oy), (bx, by)], fill=PASS, width=2)
    r = cell * 0.38
    for x, y in zip(arrays["keeper_x"][i], arrays["keeper_y"][i]):
        cx, cy = centre(int(x), int(y))
        d.ellipse([cx - r, cy - r, cx + r, cy + r], fill=KEEPER)
    for x, y in zip(arrays["taker_x"][i], arrays["taker_y"][i]):
        cx, cy = centre(int(x), int(y))
        d.rectangle([cx - r, cy - r, cx + r, cy + r], fill=TAKER)
    bx, by = centre(int(arrays["ball_x"][i]), int(arrays["ball_y"][i]))
    rb = cell * 0.2
    d.ellipse([bx - rb, by - rb, bx + rb, by + rb], fill=BALL, outline=(0, 0, 0))
    reason = int(arrays["reason"][i])
    status = Reason(reason).name.lower().replace("_", " ") if reason else "running"
    d.text((6, 8), f"{config.name}  iteration {int(arrays['t'][i])}  passes {int(arrays['passes'][i])}  "
                   f"{status}", fill=(0, 0, 0))
    return img


def render_gif(arrays: dict, config: KeepAwayConfig, path: str | pathlib.Path, *, fps: int = 8,
               max_frames: int = 400, cell: int = 24) -> pathlib.Path:
    """Writes the episode (up to its end, or ``max_frames`` frames) as an animated GIF."""
    done = np.asarray(arrays["done"])
    last = int(np.argmax(done)) if done.any() else len(done) - 1
    n = min(last + 1, max_frames)
    frames = [frame(arrays, i, config, cell) for i in range(n)]
    durations = [int(1000 / fps)] * (n - 1) + [1500]  # hold the last frame
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=durations, loop=0)
    return path


def render_policy(policy_name: str, config: KeepAwayConfig, path, *, seed: int = 0, max_frames: int = 400,
                  fps: int = 8) -> pathlib.Path:
    """One episode of a baseline policy (``hold``, ``random``, ``heuristic``) from start seed ``seed``."""
    import jax

    from kx.sim import env
    from kx.sim.evaluate import rollout
    from kx.sim.policies import BASELINES
    from kx.sim.types import KeepAwayParams

    params = KeepAwayParams()
    key_start, key_run = jax.random.split(jax.random.key(seed))
    start = env.reset(key_start, params, config)
    states, _ = rollout(BASELINES[policy_name](config), None, start, params, config, key=key_run,
                        n_steps=max_frames)
    return render_gif(env.as_numpy(states), config, path, fps=fps, max_frames=max_frames)


def main(argv=None) -> None:
    from kx.sim.policies import BASELINES

    p = argparse.ArgumentParser(description="Render one keep-away episode as an animated GIF.")
    p.add_argument("--task", default="3v2", help="e.g. 3v2, 4v3, 5v3, 6v4")
    p.add_argument("--policy", default="heuristic", choices=sorted(BASELINES))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-frames", type=int, default=400)
    p.add_argument("--fps", type=int, default=8)
    p.add_argument("--out", default="episode.gif")
    a = p.parse_args(argv)
    path = render_policy(a.policy, KeepAwayConfig.from_task(a.task), a.out, seed=a.seed,
                         max_frames=a.max_frames, fps=a.fps)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
