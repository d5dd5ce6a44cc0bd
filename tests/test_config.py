"""Config validation's bounds and messages, the feature names of the observation layouts and the
network drawing that uses them, and the package and script hygiene."""

import ast
import importlib
import json
import math
import pathlib
import subprocess
import sys

import jax
import ml_collections
import numpy as np
import pytest

from kx.evolve import config as cfg_lib
from kx.evolve.encodings import neat as neat_encoding
from kx.neat import genome as gn
from kx.neat.types import MAX_CONNS
from kx.sim import env, observe
from kx.sim.types import KeepAwayConfig, KeepAwayParams

ROOT = pathlib.Path(__file__).resolve().parents[1]
HYPERNEAT = ROOT / "configs" / "hyperneat_3v2.py"


def _refused(path, overrides) -> str:
    with pytest.raises(cfg_lib.ConfigError) as e:
        cfg_lib.validate(cfg_lib.load(path, overrides))
    return str(e.value)


def _valid(path, overrides):
    return cfg_lib.validate(cfg_lib.load(path, overrides))


# ------------------------------------------------------------------------------------------ capacities


@pytest.mark.parametrize("section,path", [("neat", None), ("hyperneat", HYPERNEAT)])
def test_genome_capacities_have_an_upper_bound(section, path):
    top = neat_encoding.MAX_HIDDEN
    assert _refused(path, [f"{section}.max_hidden={top + 1}"]) == (
        f"{section}.max_hidden: allowed an integer in [0, {top}], got {top + 1}")
    assert _refused(path, [f"{section}.max_hidden=-1"]) == (
        f"{section}.max_hidden: allowed an integer in [0, {top}], got -1")
    exp = _valid(path, [f"{section}.max_hidden={top}", "population_size=12"])
    assert exp.encoding.neat_config.n_hidden == top
    # connection columns: bounded here, by the field the config has (not NEATConfig's max_conns)
    n_initial = exp.encoding.neat_config.n_initial_conns
    cols = MAX_CONNS - n_initial
    err = _refused(path, [f"{section}.extra_conns={cols + 1}"])
    assert err.startswith(f"{section}.extra_conns: allowed an integer in [0, {cols}] ("), err
    assert err.endswith(f"got {cols + 1}") and "max_conns" not in err
    assert _valid(path, [f"{section}.extra_conns={cols}"]).encoding.neat_config.max_conns == MAX_CONNS


def test_max_add_links_above_the_population_is_refused_by_both_neat_learners():
    assert _refused(None, ["population_size=20", "neat.max_add_links=21"]) == (
        "neat.max_add_links: allowed an integer in [0, population_size = 20] (0: max(8, population_size // 8)), got 21")
    assert _refused(HYPERNEAT, ["population_size=20", "hyperneat.max_add_links=21"]) == (
        "hyperneat.max_add_links: allowed an integer in [0, population_size = 20] (0: min(40, population_size)), "
        "got 21")
    assert _refused(HYPERNEAT, ["hyperneat.max_add_links=-1"]).startswith("hyperneat.max_add_links: allowed")
    cap = lambda overrides: _valid(HYPERNEAT, overrides).encoding.neat_config.add_link_cap  # noqa: E731
    assert cap(["population_size=20", "hyperneat.max_add_links=20"]) == 20
    # the default, 0: the preset's 40 at 150 CPPNs (as before), every add-link of a smaller population
    assert cfg_lib.base_config("hyperneat").hyperneat.max_add_links == 0
    assert cap([]) == 40 and cap(["population_size=12"]) == 12
    assert cap(["population_size=150", "hyperneat.max_add_links=7"]) == 7


# -------------------------------------------------------------------------------------------- messages


def test_a_method_over_another_methods_config_names_the_config_file_to_start_from(capsys, tmp_path):
    err = _refused(None, ["method=hyperneat"])
    assert err == ("method: 'hyperneat' needs its own config section (hyperneat.*), not the 'neat' one; "
                   "start from configs/hyperneat_3v2.py (--config configs/hyperneat_3v2.py)")
    assert _refused(None, ["method=cma_es", "task=4v3"]).endswith(
        "start from configs/cma_es_4v3.py (--config configs/cma_es_4v3.py)")
    assert _refused(HYPERNEAT, ["method=neat"]).startswith("method: 'neat' needs its own config section (neat.*), "
                                                           "not the 'hyperneat' one; start from configs/neat_3v2.py")
    # a field of another method's section
    with pytest.raises(cfg_lib.ConfigError, match=r"^hyperneat\.image: no such config field; the hyperneat\.\* "
                       r"fields belong to method 'hyperneat'; to run it, start from configs/hyperneat_3v2\.py"):
        cfg_lib.load(None, ["hyperneat.image=paper"])
    # and what kx.train prints
    from kx import train

    assert train.main(["--config.method=hyperneat", "--workdir", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "start from configs/hyperneat_3v2.py (--config configs/hyperneat_3v2.py)" in err
    assert "add_link_prob" not in err and len(err) < 400, err


def test_an_unknown_field_lists_its_close_matches_not_every_field():
    def message(overrides):
        with pytest.raises(cfg_lib.ConfigError) as e:
            cfg_lib.load(None, overrides)
        return str(e.value)

    err = message(["neat.add_node_prb=0.1"])
    assert err.startswith("neat.add_node_prb: no such config field; close matches: neat.add_node_prob"), err
    assert "sim.field_size" not in err and len(err) < 200, err
    assert message(["popsize=3"]) == "popsize: no such config field; close matches: population_size"
    assert message(["neat.c4=1"]) == "neat.c4: no such config field; close matches: neat.c3, neat.c2, neat.c1"
    err = message(["zzzz=3"])  # nothing close: the top-level fields and the sections, not their ~70 fields
    assert err.startswith("zzzz: no such config field; no close match; the fields and sections are: "), err
    assert "neat.*" in err and "sim.*" in err and "neat.add_node_prob" not in err
    # a config file's extra field, found by validate
    cfg = cfg_lib.base_config()
    cfg.neat.add_node_prb = 0.1
    with pytest.raises(cfg_lib.ConfigError) as e:
        cfg_lib.validate(cfg)
    assert str(e.value) == ("neat.add_node_prb: no such config field of method 'neat'; close matches: "
                            "neat.add_node_prob, neat.add_link_prob, neat.reenable_prob")
    # a run's config.json with a field this kx does not have
    d = cfg_lib.base_config().to_dict()
    d["trails"] = 3
    with pytest.raises(cfg_lib.ConfigError) as e:
        cfg_lib.from_dict(d)
    assert str(e.value) == "trails: not a field of this kx configs (close matches: trials, task)"


# ------------------------------------------------------------------------------- feature names, drawing


def _reference_features(names, state, config):
    """Each named feature computed from its name alone (numpy, float64)."""
    w = config.field_size
    diag, c = (w - 1) * math.sqrt(2.0), (w - 1) / 2.0
    ko = np.asarray(observe.teammate_order(state, config))
    to = np.asarray(observe.taker_order(state, config))
    kx, ky, tx, ty = (np.asarray(a, np.float64) for a in (state.keeper_x, state.keeper_y, state.taker_x,
                                                           state.taker_y))
    n_takers = sum(n.startswith("dist(K1,T") for n in names)  # the takers the layout sees

    def at(token):
        if token == "C":
            return c, c
        if token[0] == "K":
            k = ko[int(token[1:]) - 1]
            return kx[k], ky[k]
        t = to[int(token[1:]) - 1]
        return tx[t], ty[t]

    def dist(a, b):
        (ax, ay), (bx, by) = at(a), at(b)
        return math.hypot(ax - bx, ay - by) / diag

    def ang(i, j):
        (hx, hy), (ix, iy), (jx, jy) = at("K1"), at(i), at(j)
        u, v = (ix - hx, iy - hy), (jx - hx, jy - hy)
        return math.atan2(abs(u[0] * v[1] - u[1] * v[0]), u[0] * v[0] + u[1] * v[1]) / math.pi

    out = []
    for name in names:
        args = name[name.index("(") + 1:-1].split(",")
        takers = [f"T{j}" for j in range(1, n_takers + 1)]
        if name.startswith("dist("):
            out.append(dist(*args))
        elif name.startswith("min dist("):
            out.append(min(dist(args[0], t) for t in takers))
        else:
            assert name.startswith("min ang(") and args[1:] == ["K1", "T"], name
            out.append(min(ang(args[0], t) for t in takers))
    return np.array(out)


@pytest.mark.parametrize("task", ["3v2", "5v3"])
def test_feature_names_follow_the_observations_order(task):
    config, params = KeepAwayConfig.from_task(task), KeepAwayParams()
    assert len(observe.fixed_names()) == observe.FIXED_INPUTS == len(set(observe.fixed_names()))
    assert observe.fixed_names()[:3] == ("dist(K1,C)", "dist(K1,K2)", "dist(K1,K3)")
    assert observe.fixed_names()[-1] == "min ang(K3,K1,T)"
    full = observe.full_names(config)
    assert len(full) == observe.n_inputs("full", config) == len(set(full))
    assert observe.input_names("fixed", config) == observe.fixed_names()
    assert observe.output_names("fixed", config) == ("hold", "pass K2", "pass K3")
    assert len(observe.output_names("full", config)) == config.n_keepers
    for seed in range(4):
        state = env.reset(jax.random.key(seed), params, config)
        for layout, obs in (("fixed", observe.fixed_obs), ("full", observe.full_obs)):
            names = observe.input_names(layout, config)
            np.testing.assert_allclose(np.asarray(obs(state, config)), _reference_features(names, state, config),
                                       atol=1e-5, err_msg=f"{task} {layout} seed {seed}")


@pytest.mark.parametrize("path", [None, ROOT / "configs" / "neat_full_3v2.py"])
def test_champion_png_labels_a_neat_networks_inputs_with_the_feature_names(path, monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    from kx.neat import draw

    exp = _valid(path, ["population_size=12"])
    enc = exp.encoding
    genome = gn.initial_genome(jax.random.key(0), enc.neat_config, enc.neat_params)
    calls, figs, real_draw, real_close = [], [], draw.draw_genome, plt.close

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real_draw(*args, **kwargs)

    monkeypatch.setattr(draw, "draw_genome", spy)
    monkeypatch.setattr(plt, "close", figs.append)
    out = enc.draw(genome, tmp_path / "champion.png")
    monkeypatch.undo()
    assert pathlib.Path(out).is_file()
    names = list(observe.input_names(exp.layout, exp.sim))
    outputs = list(observe.output_names(exp.layout, exp.sim))
    assert calls[0]["input_names"] == names and calls[0]["output_names"] == outputs
    texts = {t.get_text() for t in figs[0].axes[0].texts}
    real_close(figs[0])
    assert set(names) <= texts and set(outputs) <= texts, texts
    assert not any(t.startswith("in") and t[2:].isdigit() for t in texts), texts


def test_draw_genome_refuses_too_few_names(tmp_path):
    from kx.neat import presets
    from kx.neat.draw import draw_genome

    config, params = presets.xor()
    g = gn.initial_genome(jax.random.key(0), config, params)
    with pytest.raises(ValueError, match="input_names has 1 names, the network 2 inputs"):
        draw_genome(g, config, tmp_path / "x.png", input_names=["a"])


# ------------------------------------------------------------------------------------ package, scripts


def test_kx_neat_is_a_package_that_imports_nothing_eagerly():
    import setuptools

    assert (ROOT / "kx" / "neat" / "__init__.py").is_file()
    assert "kx.neat" in setuptools.find_packages(str(ROOT), include=["kx*"])  # a wheel carries it
    code = ("import sys, kx.neat; assert kx.neat.__doc__ and 'NEAT' in kx.neat.__doc__; "
            "print(sorted(m for m in sys.modules if m.startswith('kx.neat.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out


SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=[p.name for p in SCRIPTS])
def test_scripts_import_the_installed_kx_without_touching_sys_path(script):
    text = script.read_text()
    assert "sys.path" not in text
    # every module the script imports, at the top or inside functions, resolves (kx from the venv)
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module != "__future__":
            module = importlib.import_module(node.module)
            for alias in node.names:
                if not hasattr(module, alias.name):
                    importlib.import_module(f"{node.module}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                importlib.import_module(alias.name)


#: runs each script's ``--help`` as ``python SCRIPT --help`` does (``__main__``, its folder first on sys.path), one
#: after another in one interpreter: what each prints, or how it failed
_HELP_ALL = """
import contextlib, io, json, runpy, sys, traceback
out = {}
for path in sys.argv[1:]:
    buf, code = io.StringIO(), None
    sys.argv, sys.path[0] = [path, "--help"], path.rsplit("/", 1)[0]
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_path(path, run_name="__main__")
    except SystemExit as e:
        code = e.code
    except BaseException:
        code = traceback.format_exc()
    out[path] = [code, buf.getvalue()]
print(json.dumps(out))
"""


def test_every_script_prints_its_usage_run_from_elsewhere_with_the_installed_kx(tmp_path):
    """Each script's ``--help``, run from a folder without kx, where only the installed kx can be found. The scripts
    share one interpreter (importing jax once, not once a script); each runs as ``python SCRIPT`` runs it."""
    done = subprocess.run([sys.executable, "-c", _HELP_ALL, *map(str, SCRIPTS)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert sorted(got) == sorted(map(str, SCRIPTS))
    bad = {pathlib.Path(p).name: v for p, v in got.items() if v[0] not in (0, None) or "usage:" not in v[1]}
    assert not bad, bad


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.py")), ids=lambda p: p.name)
def test_every_shipped_config_loads_and_validates(path):
    """Each config file of configs/ is one a user can run as it is: its fields load and pass validation."""
    exp = cfg_lib.validate(cfg_lib.load(str(path)))
    assert exp.encoding.describe()


def test_the_shipped_configs_are_package_data_and_configs_links_to_them():
    """An installed kx carries its configs (kx/configs/, the package data pyproject names); a checkout's
    configs/ is that folder, so every documented path and the package see the same files."""
    assert cfg_lib.CONFIG_DIR == ROOT / "kx" / "configs"
    assert (ROOT / "configs").resolve() == cfg_lib.CONFIG_DIR.resolve()
    assert "neat_3v2.py" in cfg_lib.shipped() and len(cfg_lib.shipped()) == len(list(cfg_lib.CONFIG_DIR.glob("*.py")))
    assert '"kx" = ["configs/*.py"]' in (ROOT / "pyproject.toml").read_text()


def test_a_config_path_resolves_to_a_file_first_then_to_the_shipped_config_of_that_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a folder with no configs/, as after `pip install .`
    for name in ("configs/neat_4v3.py", "neat_4v3.py", "neat_4v3"):
        assert cfg_lib.resolve(name) == cfg_lib.CONFIG_DIR / "neat_4v3.py"
    assert cfg_lib.load("configs/neat_4v3.py").task == "4v3"
    assert cfg_lib.resolve(None) == cfg_lib.DEFAULT_CONFIG
    # a user's own file of that name wins over the shipped one
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "neat_4v3.py").write_text(
        "from kx.evolve.config import base_config\n\n\ndef get_config():\n    c = base_config('neat')\n"
        "    c.task = '5v3'\n    return c\n")
    assert cfg_lib.resolve("configs/neat_4v3.py") == pathlib.Path("configs/neat_4v3.py")
    assert cfg_lib.load("configs/neat_4v3.py").task == "5v3"
    # a name that is neither a file nor shipped: refused, listing what is shipped; a shipped name under
    # another folder is not taken for the shipped config
    for bad in ("configs/nope.py", "elsewhere/neat_4v3.py"):
        with pytest.raises(cfg_lib.ConfigError, match=r"--config: no config file .*neat_3v2\.py"):
            cfg_lib.resolve(bad)


def test_overrides_give_a_new_config_that_prints_and_leave_the_given_one_as_it_was():
    """apply_overrides copies: the config it was given keeps its values (nested ones too), and what it returns is a
    plain ConfigDict that prints its fields (the flag's unprinted stand-in does not leak out)."""
    base = cfg_lib.base_config()
    want = base.to_dict()
    out = cfg_lib.apply_overrides(base, ["sim.max_iterations=77", "seed=4", "gif=false"])
    assert base.to_dict() == want
    assert (out.sim.max_iterations, out.seed, out.gif) == (77, 4, False)
    assert type(out) is ml_collections.ConfigDict and "max_iterations: 77" in str(out)
    assert {k: v for k, v in cfg_lib.flatten(out.to_dict()).items() if k not in ("sim.max_iterations", "seed", "gif")} \
        == {k: v for k, v in cfg_lib.flatten(want).items() if k not in ("sim.max_iterations", "seed", "gif")}
