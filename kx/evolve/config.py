"""Experiment configs: ``ml_collections.ConfigDict`` files under ``configs/``, checked before any compute.

A config file defines ``get_config()`` and usually starts from :func:`base_config` (the paper's source
task: 3v2, NEAT, population 150, 30 trials, 20 generations). ``kx.train`` loads one with
:func:`load` and applies command-line overrides (``--config.population_size=50``,
``--config.neat.add_node_prob=0.05``); :func:`validate` refuses an unknown field or a value out of
range with a message that names the field and what it allows.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import pathlib
from typing import Any

import ml_collections

from kx.neat import presets
from kx.neat.activations import ACTIVATIONS
from kx.neat.types import NEATConfig, NEATError, NEATParams
from kx.sim import env, observe
from kx.sim.types import KeepAwayConfig, KeepAwayError, KeepAwayParams

CONFIG_DIR = pathlib.Path(__file__).resolve().parents[2] / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "neat_3v2.py"
METHODS = ("neat",)  # HyperNEAT and the novelty hybrid join with their own issues
LAYOUTS = ("fixed", "full")
PAPER_TASKS = ("3v2", "4v3", "5v3", "6v4")

# Fields that may change when a run is resumed (how long it runs and what it writes, not what it
# computes); every other field must equal the checkpoint's.
RESUMABLE = ("generations", "checkpoint_every", "keep_checkpoints", "gif", "gif_frames")


class ConfigError(ValueError):
    """A config field that does not exist or holds a value out of range."""


def neat_params_fields(params: NEATParams) -> dict:
    """A :class:`NEATParams` as ``neat.*`` config values (plain Python numbers)."""
    return {f.name: getattr(params, f.name) for f in dataclasses.fields(NEATParams)}


def base_config(reading: str = "sharpneat") -> ml_collections.ConfigDict:
    """The paper's source task with NEAT (Table 2 in ``reading`` "sharpneat", the default, or
    "literal"; see :mod:`kx.neat.presets`), every field a user may set."""
    ncfg, nparams = {"sharpneat": presets.keepaway_sharpneat, "literal": presets.keepaway_literal}[reading]()
    sim_cfg, sim_params = KeepAwayConfig(), KeepAwayParams()
    c = ml_collections.ConfigDict()
    c.task = "3v2"  # "<keepers>v<takers>": the paper's 3v2, 4v3, 5v3, 6v4 or any other in range
    c.method = "neat"
    c.layout = "fixed"  # "fixed": 13 inputs, 3 outputs (the paper's NEAT); "full": 4K+2T-3 inputs, K outputs
    c.population_size = ncfg.population_size
    c.trials = 30  # start states per generation, shared by every genome
    c.generations = 20
    c.seed = 0
    c.checkpoint_every = 5  # generations between checkpoints (and one at the end)
    c.keep_checkpoints = 3  # the last few are kept, and the best (by best fitness) too
    # each generation's champion (by training fitness) replays on this many validation start states; the
    # run's champion is the one that validates best
    c.validation_trials = 100
    c.gif = True  # render the champion's episode at the end
    c.gif_frames = 300
    c.sim = ml_collections.ConfigDict({
        "field_size": sim_cfg.field_size, "agent_speed": sim_cfg.agent_speed, "ball_speed": sim_cfg.ball_speed,
        "n_chasers": sim_cfg.n_chasers,
        **{f: getattr(sim_params, f) for f in ("max_iterations", "start_clearance", "kick_noise_deg",
                                               "taker_reaction_delay", "tackle_iterations")}})
    c.sim.kick_noise_deg = float(c.sim.kick_noise_deg)
    neat = neat_params_fields(nparams)
    neat.update(output_activation=ncfg.output_activation, hidden_activation=ncfg.hidden_activation,
                max_hidden=ncfg.max_nodes - ncfg.n_fixed, species_capacity=ncfg.species_capacity,
                extra_conns=ncfg.max_conns - ncfg.n_initial_conns, extra_genes=ncfg.genes - ncfg.n_initial_conns)
    c.neat = ml_collections.ConfigDict(neat)
    return c


def load(path: str | pathlib.Path | None = None, overrides=()) -> ml_collections.ConfigDict:
    """The config of file ``path`` (default ``configs/neat_3v2.py``) with ``overrides`` applied
    (``"population_size=50"``, ``"neat.add_node_prob=0.05"``), locked against new fields."""
    path = pathlib.Path(path) if path is not None else DEFAULT_CONFIG
    if not path.is_file():
        known = ", ".join(sorted(p.name for p in CONFIG_DIR.glob("*.py"))) if CONFIG_DIR.is_dir() else "none"
        raise ConfigError(f"--config: no config file {str(path)!r} (configs/ has: {known})")
    spec = importlib.util.spec_from_file_location(f"kx_config_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if not hasattr(module, "get_config"):
        raise ConfigError(f"--config: {path} defines no get_config()")
    cfg = module.get_config()
    apply_overrides(cfg, overrides)
    cfg.lock()
    return cfg


def _fields(cfg: ml_collections.ConfigDict, prefix: str = "") -> list[str]:
    out = []
    for k, v in cfg.items():
        out += _fields(v, f"{prefix}{k}.") if isinstance(v, ml_collections.ConfigDict) else [prefix + k]
    return out


def _parse(field: str, text: str, current: Any) -> Any:
    kind = type(current)
    try:
        if kind is bool:
            if text.lower() in ("1", "true", "yes"):
                return True
            if text.lower() in ("0", "false", "no"):
                return False
            raise ValueError(text)
        if kind is int:
            return int(text)
        if kind is float:
            return float(text)
        return text
    except ValueError:
        what = {bool: "true or false", int: "an integer", float: "a number"}.get(kind, kind.__name__)
        raise ConfigError(f"{field}: allowed {what}, got {text!r}") from None


def apply_overrides(cfg: ml_collections.ConfigDict, overrides) -> None:
    """Set ``a.b=value`` fields in place, parsed by the type of the value they replace."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--config.{item}: expected --config.<field>=<value>")
        field, text = item.split("=", 1)
        *parents, leaf = field.split(".")
        node = cfg
        for p in parents:
            node = node.get(p) if isinstance(node, ml_collections.ConfigDict) else None
        if not isinstance(node, ml_collections.ConfigDict) or leaf not in node or isinstance(
                node[leaf], ml_collections.ConfigDict):
            raise ConfigError(f"{field}: no such config field; the fields are: {', '.join(_fields(cfg))}")
        with node.unlocked():
            node[leaf] = _parse(field, text, node[leaf])


def _need(ok: bool, field: str, allowed: str, value: Any) -> None:
    if not ok:
        raise ConfigError(f"{field}: allowed {allowed}, got {value!r}")


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


@dataclasses.dataclass(frozen=True)
class Experiment:
    """A validated config turned into the objects that run it."""

    sim: KeepAwayConfig
    sim_params: KeepAwayParams
    neat: NEATConfig
    neat_params: NEATParams
    layout: str


def validate(cfg: ml_collections.ConfigDict) -> Experiment:
    """Check every field (raising :class:`ConfigError` that names the first bad one) and build the
    experiment's objects."""
    expected = _fields(base_config())
    unknown = sorted(set(_fields(cfg)) - set(expected))
    missing = sorted(set(expected) - set(_fields(cfg)))
    if unknown:
        raise ConfigError(f"{unknown[0]}: no such config field; the fields are: {', '.join(expected)}")
    if missing:
        raise ConfigError(f"{missing[0]}: missing from the config (start config files from "
                          f"kx.evolve.config.base_config())")
    _need(isinstance(cfg.method, str) and cfg.method in METHODS, "method", f"one of {METHODS}", cfg.method)
    _need(isinstance(cfg.layout, str) and cfg.layout in LAYOUTS, "layout", f"one of {LAYOUTS}", cfg.layout)
    _need(_int(cfg.population_size) and 2 <= cfg.population_size <= 100_000, "population_size",
          "an integer in [2, 100000]", cfg.population_size)
    _need(_int(cfg.trials) and 1 <= cfg.trials <= 100_000, "trials", "an integer in [1, 100000]", cfg.trials)
    _need(_int(cfg.generations) and 1 <= cfg.generations <= 1_000_000, "generations",
          "an integer in [1, 1000000]", cfg.generations)
    _need(_int(cfg.seed) and 0 <= cfg.seed < 2**31, "seed", "an integer in [0, 2^31)", cfg.seed)
    _need(_int(cfg.checkpoint_every) and cfg.checkpoint_every >= 1, "checkpoint_every", "an integer >= 1",
          cfg.checkpoint_every)
    _need(_int(cfg.keep_checkpoints) and cfg.keep_checkpoints >= 1, "keep_checkpoints", "an integer >= 1",
          cfg.keep_checkpoints)
    _need(_int(cfg.validation_trials) and 1 <= cfg.validation_trials <= 100_000, "validation_trials",
          "an integer in [1, 100000]", cfg.validation_trials)
    _need(isinstance(cfg.gif, bool), "gif", "true or false", cfg.gif)
    _need(_int(cfg.gif_frames) and 1 <= cfg.gif_frames <= 5000, "gif_frames", "an integer in [1, 5000]",
          cfg.gif_frames)
    if not isinstance(cfg.task, str):
        raise ConfigError(f"task: allowed '<keepers>v<takers>' such as {', '.join(PAPER_TASKS)}, got {cfg.task!r}")
    s = cfg.sim
    try:
        sim = KeepAwayConfig.from_task(cfg.task, field_size=s.field_size, agent_speed=s.agent_speed,
                                       ball_speed=s.ball_speed, n_chasers=s.n_chasers)
    except KeepAwayError as e:
        field, _, rest = str(e).partition(": ")
        name = "task" if field in ("task", "n_keepers", "n_takers") else f"sim.{field}"
        raise ConfigError(f"{name}: {rest if name != 'task' else str(e)}") from None
    try:
        sim_params = KeepAwayParams(max_iterations=s.max_iterations, start_clearance=s.start_clearance,
                                    kick_noise_deg=s.kick_noise_deg,
                                    taker_reaction_delay=s.taker_reaction_delay,
                                    tackle_iterations=s.tackle_iterations).validate()
        env.check(sim, sim_params)
    except KeepAwayError as e:
        raise ConfigError(f"sim.{e}") from None
    n = dict(cfg.neat)
    for f in ("max_hidden", "species_capacity", "extra_conns", "extra_genes"):
        _need(_int(n[f]) and n[f] >= (1 if f == "species_capacity" else 0), f"neat.{f}", "an integer >= "
              + ("1" if f == "species_capacity" else "0"), n[f])
    _need(n["species_capacity"] <= cfg.population_size, "neat.species_capacity",
          f"at most population_size ({cfg.population_size})", n["species_capacity"])
    _need(n["extra_genes"] <= n["extra_conns"], "neat.extra_genes", f"at most neat.extra_conns ({n['extra_conns']})",
          n["extra_genes"])
    for f in ("output_activation", "hidden_activation"):
        _need(isinstance(n[f], str) and n[f] in ACTIVATIONS, f"neat.{f}", f"one of {sorted(ACTIVATIONS)}", n[f])
    n_in, n_out = observe.n_inputs(cfg.layout, sim), observe.n_outputs(cfg.layout, sim)
    try:
        neat_cfg, _ = presets.keepaway(
            n_inputs=n_in, n_outputs=n_out, population_size=cfg.population_size,
            max_nodes=n_in + 1 + n_out + n["max_hidden"], max_conns=(n_in + 1) * n_out + n["extra_conns"],
            max_genes=(n_in + 1) * n_out + n["extra_genes"], species_capacity=n["species_capacity"],
            output_activation=n["output_activation"], hidden_activation=n["hidden_activation"],
            activation_options=tuple(dict.fromkeys((n["hidden_activation"], n["output_activation"]))))
        neat_params = NEATParams(**{f.name: n[f.name] for f in dataclasses.fields(NEATParams)})
        neat_params.validate()
        if neat_params.target_species > neat_cfg.species_capacity:
            raise NEATError(f"NEATParams.target_species = {neat_params.target_species}: allowed at most "
                            f"neat.species_capacity = {neat_cfg.species_capacity}")
    except NEATError as e:
        raise ConfigError(str(e).replace("NEATParams.", "neat.").replace("NEATConfig.", "neat.")) from None
    return Experiment(sim=sim, sim_params=sim_params, neat=neat_cfg, neat_params=neat_params, layout=cfg.layout)


def flatten(d: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    out = {}
    for k, v in d.items():
        out.update(flatten(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
    return out


def from_dict(d: dict) -> ml_collections.ConfigDict:
    """A config from its ``to_dict()`` form (e.g. a run's ``config.json``), on top of
    :func:`base_config`; unlocked."""
    cfg = base_config()
    cfg.update_from_flattened_dict(flatten(d))
    return cfg


def identity_mismatch(saved: dict, cfg: ml_collections.ConfigDict) -> str | None:
    """The first field (other than :data:`RESUMABLE`) where a checkpoint's config differs from
    ``cfg``, described; ``None`` if they agree."""
    now = cfg.to_dict()
    a, b = flatten(saved), flatten(now)
    for field in sorted(set(a) | set(b)):
        if field in RESUMABLE:
            continue
        if a.get(field, "<absent>") != b.get(field, "<absent>"):
            return f"{field} = {a.get(field, '<absent>')!r} in the checkpoint, {b.get(field, '<absent>')!r} now"
    return None
