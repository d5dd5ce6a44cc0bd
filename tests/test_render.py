import jax
from PIL import Image

from kx.sim import env, policies
from kx.sim.evaluate import rollout
from kx.sim.render import main, render_gif
from kx.sim.types import KeepAwayConfig, KeepAwayParams


def test_render_gif(tmp_path):
    cfg, params = KeepAwayConfig.from_task("4v3"), KeepAwayParams()
    states, _ = rollout(policies.heuristic(cfg), None, env.reset(jax.random.key(0), params, cfg), params, cfg,
                        n_steps=40)
    arrays = env.as_numpy(states)
    path = render_gif(arrays, cfg, tmp_path / "ep.gif", fps=10)
    im = Image.open(path)
    last = int(arrays["done"].argmax()) if arrays["done"].any() else 40
    assert im.n_frames == min(last + 1, 400)  # every iteration to the end
    assert im.size == (20 * 24 + 1, 20 * 24 + 28 + 1)


def test_render_cli(tmp_path, capsys):
    main(["--task", "3v2", "--policy", "hold", "--out", str(tmp_path / "h.gif"), "--max-frames", "30"])
    assert (tmp_path / "h.gif").exists() and "wrote" in capsys.readouterr().out
