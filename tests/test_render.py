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


def test_render_cli_draws_the_episode_of_its_policy_and_seed(tmp_path, capsys):
    """The CLI's GIF is the episode of the hold policy from start seed 0, frame by frame: every frame's pixels
    are :func:`frame`'s of the same episode played here, up to its end (the takers win the ball)."""
    import numpy as np
    from PIL import ImageSequence

    from kx.sim.policies import BASELINES
    from kx.sim.render import frame

    main(["--task", "3v2", "--policy", "hold", "--seed", "0", "--out", str(tmp_path / "h.gif"), "--max-frames", "30"])
    assert capsys.readouterr().out == f"wrote {tmp_path / 'h.gif'}\n"
    cfg, params = KeepAwayConfig.from_task("3v2"), KeepAwayParams()
    k_start, k_run = jax.random.split(jax.random.key(0))
    states, _ = rollout(BASELINES["hold"](cfg), None, env.reset(k_start, params, cfg), params, cfg, key=k_run,
                        n_steps=30)
    arrays = env.as_numpy(states)
    assert arrays["done"].any()  # holding loses the ball within 30 iterations
    end = int(arrays["done"].argmax())
    with Image.open(tmp_path / "h.gif") as im:
        got = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
    assert len(got) == end + 1
    for i, pixels in enumerate(got):
        want = np.asarray(frame(arrays, i, cfg, 24).convert("RGB"))
        np.testing.assert_array_equal(pixels, want, err_msg=f"frame {i}")
    # another seed is another episode
    main(["--task", "3v2", "--policy", "hold", "--seed", "1", "--out", str(tmp_path / "h1.gif"), "--max-frames", "30"])
    with Image.open(tmp_path / "h1.gif") as im:
        assert not np.array_equal(np.asarray(im.convert("RGB")), got[0])
