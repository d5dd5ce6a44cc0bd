"""Experiment configs: ``ml_collections.ConfigDict`` files under ``configs/``, checked before any compute.

Over 450 lines because it is the one place a config is built, loaded, checked and read back from a run
directory: the fields' defaults and their checks stay together.

A config file defines ``get_config()`` and usually starts from :func:`base_config`, which gives the run
loop's fields and the config section of one method (``base_config("cma_es")`` ...; the default is the
paper's source task with NEAT: 3v2, population 150, 30 trials, 20 generations). ``kx.train`` loads one
with :func:`load`; command-line overrides (``--config.population_size=50``,
``--config.neat.add_node_prob=0.05``, tuples and nested fields too) go through ml_collections' own flag
parsing (``config_flags``, as the flax examples do). :func:`validate` refuses an unknown field or a value
out of range with a message that names the field and what it allows; each method's encoding
(:mod:`kx.evolve.encoding`, :mod:`kx.evolve.encodings`) validates its own section.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib.util
import json
import pathlib

import ml_collections

from kx.evolve import objective as objectives
from kx.evolve import registry
from kx.evolve.encoding import Encoding
from kx.evolve.errors import ConfigError, ObjectiveError, is_int, need
from kx.evolve.objective import OBJECTIVES
from kx.sim import env
from kx.sim.types import KeepAwayConfig, KeepAwayError, KeepAwayParams

# The shipped configs: package data (kx/configs/), so an installed kx has them; a checkout's configs/ links here
CONFIG_DIR = pathlib.Path(__file__).resolve().parents[1] / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "neat_3v2.py"
PAPER_TASKS = ("3v2", "4v3", "5v3", "6v4")

# config.json's record of a transferred run's source (kx.evolve.transfer), beside the config's fields
SOURCE_RECORD = "transfer_source"
# Fields that may change when a run is resumed (how long it runs and what it writes, not what it
# computes); every other field must equal the checkpoint's.
# hyperneat.impl: which code computes the same bits (a run may resume on a machine without the native kernel)
RESUMABLE = ("generations", "checkpoint_every", "keep_checkpoints", "gif", "gif_frames", "hyperneat.impl")
# How a transfer source's population seeds a run (transfer.seeding; kx.evolve.transfer)
SEEDINGS = ("population", "champion", "half")


def base_config(method: str = "neat", **section_options) -> ml_collections.ConfigDict:
    """The run loop's fields at their defaults and the config section of ``method``'s encoding
    (``section_options`` go to its ``default_config``, e.g. ``base_config("neat", reading="literal")``
    for Table 2 read literally; see :mod:`kx.neat.presets`)."""
    if method not in registry.names():
        raise ConfigError(f"method: allowed one of {registry.names()}, got {method!r}")
    cls = registry.get(method)
    sim_cfg, sim_params = KeepAwayConfig(), KeepAwayParams()
    c = ml_collections.ConfigDict()
    c.task = "3v2"  # "<keepers>v<takers>": the paper's 3v2, 4v3, 5v3, 6v4 or any other in range
    c.method = method  # the encoding: one of kx.evolve.registry.names()
    c.objective = "fitness"  # what the learner selects on (kx.evolve.objective); reports are always fitness
    # the novelty search hybrid (objective = "hybrid", SPEC section 4; kx.novelty): k nearest neighbours,
    # rho the weight of fitness in the score, the archive's size and its admission threshold
    c.novelty = ml_collections.ConfigDict(objectives.novelty_defaults())
    # policy transfer (SPEC section 5; kx.evolve.transfer): the run directory of a source run whose
    # checkpointed population seeds this one ("": no transfer, a fresh population), its checkpoint
    # (-1: the latest) and how its population seeds this run's ("population": all of it;
    # "champion": its validated champion and mutated copies; "half": its fittest half and mutated copies)
    c.transfer = ml_collections.ConfigDict({"source": "", "step": -1, "seeding": "population"})
    c.layout = "fixed"  # "fixed": 13 inputs, 3 outputs (the paper's NEAT); "full": 4K+2T-3 inputs, K outputs
    c.population_size = 150
    c.trials = 30  # start states per generation, shared by every individual
    c.generations = 20
    c.seed = 0
    c.checkpoint_every = 5  # generations between checkpoints (and one at the end)
    c.keep_checkpoints = 3  # the last few are kept, and the one whose champion validated best too
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
    for k, v in cls.defaults().items():
        c[k] = v
    c[cls.section] = cls.default_config(**section_options)
    return c



#: a target task's budget in episodes: NEAT's 50 generations of 150 individuals x 30 trials (SPEC section 6)
TARGET_EPISODES = 50 * 150 * 30


def target_config(method: str, task: str) -> ml_collections.ConfigDict:
    """``method`` from scratch in the target ``task`` at the protocol's budget (:data:`TARGET_EPISODES`): NEAT
    and HyperNEAT 50 generations of 150 x 30; CMA-ES (population 50) 150 generations of 30 trials; PPO 50
    generations of 4500 training episodes, its learning rate falling to 0 over them. What the shipped
    ``<method>_<task>.py`` configs of the targets are; with ``transfer.source`` a run starts from a source."""
    c = base_config(method)
    c.task = task
    if method in ("ppo", "ppo_entity"):
        section = c[method]
        c.generations = TARGET_EPISODES // section.episodes_per_generation
        section.anneal_episodes = TARGET_EPISODES  # the learning rate falls to 0 over the run's budget
    else:
        c.generations = TARGET_EPISODES // (c.population_size * c.trials)
    return c


def _fields(cfg: ml_collections.ConfigDict, prefix: str = "") -> list[str]:
    out = []
    for k, v in cfg.items():
        out += _fields(v, f"{prefix}{k}.") if isinstance(v, ml_collections.ConfigDict) else [prefix + k]
    return out


def _field(cfg, name: str):
    node = cfg
    for part in name.split("."):
        if not isinstance(node, ml_collections.ConfigDict) or part not in node:
            return None, False
        node = node[part]
    return node, True


def _start_from(method: str, task=None) -> str:
    """Where a config of ``method`` starts: its shipped config file (of ``task`` if there is one, else of
    3v2), or :func:`base_config`."""
    for name in (f"{method}_{task}.py", f"{method}_3v2.py"):
        if (CONFIG_DIR / name).is_file():
            return f"start from configs/{name} (--config configs/{name})"
    return f"start from kx.evolve.config.base_config({method!r})"


def _section_owner(field: str) -> str | None:
    """The method whose config section ``field`` lies in (``"hyperneat.image"`` -> ``"hyperneat"``)."""
    head = field.split(".")[0]
    for m in registry.names():
        if "." in field and registry.get(m).section == head:
            return m
    return None


def close_fields(field: str, known) -> str:
    """The fields of ``known`` closest to the unknown ``field`` (difflib; a section's fields are matched
    by their last part too: ``neat.add_node_prb``), or, when none is close, the top-level fields and
    sections."""
    known = sorted(known)
    matches = difflib.get_close_matches(field, known, n=5, cutoff=0.6)
    if not matches and "." in field:
        head, _, leaf = field.rpartition(".")
        inside = {f.rpartition(".")[2]: f for f in known if f.startswith(head + ".")}
        matches = [inside[m] for m in difflib.get_close_matches(leaf, list(inside), n=5, cutoff=0.6)]
    if matches:
        return f"close matches: {', '.join(matches)}"
    tops = sorted({f.split(".")[0] + (".*" if "." in f else "") for f in known})
    return f"no close match; the fields and sections are: {', '.join(tops)}"


def unknown_field(field: str, known, method: str | None = None, task=None) -> str:
    """What to say of the unknown config field ``field``: the config file to start from when it lies in
    the section of another method than ``method``, else its close matches (:func:`close_fields`)."""
    owner = _section_owner(field)
    if owner is not None and owner != method:
        return f"the {field.split('.')[0]}.* fields belong to method {owner!r}; to run it, {_start_from(owner, task)}"
    return close_fields(field, known)


_KIND = {bool: "true or false", int: "an integer", float: "a number", str: "a string", tuple: "a tuple"}


def apply_overrides(cfg: ml_collections.ConfigDict, overrides) -> ml_collections.ConfigDict:
    """``cfg`` with ``field=value`` overrides applied by ml_collections' ``config_flags`` (values parsed
    by the type of the field they replace: ``seed=3``, ``gif=false``, ``neat.add_node_prob=0.05``): a new config,
    ``cfg`` left as it was (``cfg`` itself when there are no overrides)."""
    from absl import flags
    from ml_collections import config_flags

    argv = ["kx"]
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--config.{item}: expected --config.<field>=<value>")
        field, text = item.split("=", 1)
        value, ok = _field(cfg, field)
        if not ok or isinstance(value, ml_collections.ConfigDict):
            method = cfg.get("method")
            raise ConfigError(f"{field}: no such config field; "
                              f"{unknown_field(field, _fields(cfg), method, cfg.get('task'))}")
        argv.append(f"--config.{field}={text}")
    if len(argv) == 1:
        return cfg
    fv = flags.FlagValues()
    # (the flag holds the config as an _Unprinted: absl writes a flag's default into its help text, and the whole
    # config's str, a YAML dump, twice a load, was three quarters of a load's time)
    config_flags.DEFINE_config_dict("config", _Unprinted(copy.deepcopy(cfg)), flag_values=fv, lock_config=False,
                                    sys_argv=argv)
    try:
        fv(argv)
    except flags.Error as e:
        msg = str(e)
        for item in overrides:
            field, text = item.split("=", 1)
            if f"--config.{field}=" in msg:
                value, _ = _field(cfg, field)
                what = _KIND.get(type(value), type(value).__name__)
                raise ConfigError(f"{field}: allowed {what}, got {text!r}") from None
        raise ConfigError(f"--config: {msg}") from None
    return ml_collections.ConfigDict(fv.config)


class _Unprinted(ml_collections.ConfigDict):
    """A config whose str is a name, not a YAML dump of every field: what absl makes of a flag's default, for a help
    text kx never shows."""

    def __str__(self) -> str:
        return "<kx config>"


def shipped() -> list[str]:
    """The names of the configs kx ships (``neat_3v2.py`` ...)."""
    return sorted(p.name for p in CONFIG_DIR.glob("*.py")) if CONFIG_DIR.is_dir() else []


def resolve(path: str | pathlib.Path | None) -> pathlib.Path:
    """The config file ``path`` names: the file itself where it exists, else the shipped config of that
    name when ``path`` is ``configs/<name>.py``, ``<name>.py`` or ``<name>`` (so the documented
    ``--config configs/neat_4v3.py`` works from any folder, and from an installed kx); None is the default."""
    if path is None:
        return DEFAULT_CONFIG
    path = pathlib.Path(path)
    if path.is_file():
        return path
    name = path.name if path.suffix == ".py" else f"{path.name}.py"
    if path.parent in (pathlib.Path("."), pathlib.Path("configs")) and (CONFIG_DIR / name).is_file():
        return CONFIG_DIR / name
    raise ConfigError(f"--config: no config file {str(path)!r} (a path to a file, or one of the shipped configs, "
                      f"as configs/<name>.py or <name>: {', '.join(shipped()) or 'none'})")


def load(path: str | pathlib.Path | None = None, overrides=()) -> ml_collections.ConfigDict:
    """The config of file ``path`` (default ``configs/neat_3v2.py``) with ``overrides`` applied
    (``"population_size=50"``, ``"neat.add_node_prob=0.05"``), locked against new fields."""
    path = resolve(path)
    spec = importlib.util.spec_from_file_location(f"kx_config_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if not hasattr(module, "get_config"):
        raise ConfigError(f"--config: {path} defines no get_config()")
    cfg = apply_overrides(module.get_config(), overrides)
    cfg.lock()
    return cfg


def check_transfer(cfg: ml_collections.ConfigDict) -> None:
    """The ``transfer`` section's values (no file is read here; :func:`kx.evolve.transfer.load` reads
    the source)."""
    t = cfg.transfer
    need(isinstance(t.source, str), "transfer.source", "a run directory (a string; '' for no transfer)", t.source)
    need(is_int(t.step) and (t.step == -1 or t.step >= 1), "transfer.step",
         "-1 (the latest checkpoint) or a checkpoint step >= 1", t.step)
    need(isinstance(t.seeding, str) and t.seeding in SEEDINGS, "transfer.seeding", f"one of {SEEDINGS}", t.seeding)


@dataclasses.dataclass(frozen=True)
class Experiment:
    """A validated config turned into the objects that run it."""

    sim: KeepAwayConfig
    sim_params: KeepAwayParams
    encoding: Encoding
    layout: str
    objective: objectives.Objective

    @property
    def neat(self):
        """The NEAT encoding's :class:`~kx.neat.types.NEATConfig` (NEAT runs only)."""
        return self.encoding.neat_config


def validate(cfg: ml_collections.ConfigDict) -> Experiment:
    """Check every field (raising :class:`ConfigError` that names the first bad one) and build the
    experiment's objects, its encoding included."""
    if not isinstance(cfg, ml_collections.ConfigDict):
        raise ConfigError(f"config: expected an ml_collections.ConfigDict, got {type(cfg).__name__}")
    method = cfg.get("method")
    need(isinstance(method, str) and method in registry.names(), "method", f"one of {registry.names()}", method)
    cls = registry.get(method)
    others = {registry.get(m).section for m in registry.names()} - {cls.section}
    theirs = sorted(k for k in cfg.keys() if k in others)
    if cls.section not in cfg or theirs:
        instead = f", not the {theirs[0]!r} one" if theirs else ""
        raise ConfigError(f"method: {method!r} needs its own config section ({cls.section}.*){instead}; "
                          f"{_start_from(method, cfg.get('task'))}")
    expected = _fields(base_config(method))
    unknown = sorted(set(_fields(cfg)) - set(expected))
    missing = sorted(set(expected) - set(_fields(cfg)))
    if unknown:
        raise ConfigError(f"{unknown[0]}: no such config field of method {method!r}; "
                          f"{unknown_field(unknown[0], expected, method, cfg.get('task'))}")
    if missing:
        raise ConfigError(f"{missing[0]}: missing from the config (start config files from "
                          f"kx.evolve.config.base_config({method!r}))")
    need(isinstance(cfg.objective, str) and cfg.objective in OBJECTIVES, "objective", f"one of {OBJECTIVES}",
         cfg.objective)
    check_transfer(cfg)
    try:
        objective = objectives.make(cfg)
    except ObjectiveError as e:
        raise ConfigError(str(e)) from None
    need(isinstance(cfg.layout, str) and cfg.layout in cls.layouts, "layout",
         f"one of {cls.layouts} for method {method!r}", cfg.layout)
    low, high = cls.population_sizes
    need(is_int(cfg.population_size) and low <= cfg.population_size <= high, "population_size",
         f"an integer in [{low}, {high}] for method {method!r}" if low < high else f"{low} for method {method!r}",
         cfg.population_size)
    need(is_int(cfg.trials) and 1 <= cfg.trials <= 100_000, "trials", "an integer in [1, 100000]", cfg.trials)
    need(is_int(cfg.generations) and 1 <= cfg.generations <= 1_000_000, "generations",
         "an integer in [1, 1000000]", cfg.generations)
    need(is_int(cfg.seed) and 0 <= cfg.seed < 2**31, "seed", "an integer in [0, 2^31)", cfg.seed)
    need(is_int(cfg.checkpoint_every) and cfg.checkpoint_every >= 1, "checkpoint_every", "an integer >= 1",
         cfg.checkpoint_every)
    need(is_int(cfg.keep_checkpoints) and cfg.keep_checkpoints >= 1, "keep_checkpoints", "an integer >= 1",
         cfg.keep_checkpoints)
    need(is_int(cfg.validation_trials) and 1 <= cfg.validation_trials <= 100_000, "validation_trials",
         "an integer in [1, 100000]", cfg.validation_trials)
    need(isinstance(cfg.gif, bool), "gif", "true or false", cfg.gif)
    need(is_int(cfg.gif_frames) and 1 <= cfg.gif_frames <= 5000, "gif_frames", "an integer in [1, 5000]",
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
    return Experiment(sim=sim, sim_params=sim_params, encoding=cls(cfg, sim, sim_params), layout=cfg.layout,
                      objective=objective)


def flatten(d: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    out = {}
    for k, v in d.items():
        out.update(flatten(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
    return out


def from_dict(d: dict) -> ml_collections.ConfigDict:
    """A config from its ``to_dict()`` form (e.g. a run's ``config.json``), on top of
    :func:`base_config` of its method; unlocked. A field that this kx's configs do not have, or a
    section in the place of a value, is refused with :class:`ConfigError`."""
    if not isinstance(d, dict):
        raise ConfigError(f"config: expected a JSON object of config fields, got {type(d).__name__}")
    method = d.get("method", "neat")
    if method not in registry.names():
        raise ConfigError(f"method: allowed one of {registry.names()}, got {method!r}")
    cfg = base_config(method)
    known = set(_fields(cfg))
    for field, value in flatten(d).items():
        if field not in known:
            section = any(f.startswith(field + ".") for f in known)
            if section:
                raise ConfigError(f"{field}: a section, not a value (its fields: "
                                  f"{', '.join(sorted(f for f in known if f.startswith(field + '.')))})")
            raise ConfigError(f"{field}: not a field of this kx configs ({unknown_field(field, known, method)})")
        parent, _, leaf = field.rpartition(".")
        node = _field(cfg, parent)[0] if parent else cfg
        if isinstance(node[leaf], tuple) and isinstance(value, list):  # JSON has no tuples
            value = tuple(value)
        try:
            node[leaf] = value
        except TypeError as e:
            raise ConfigError(f"{field}: {value!r} does not fit the field ({e})") from None
    return cfg


#: config fields added after runs were written with the code before them: a config.json or a checkpoint
#: without one reads it as this value, which is what that code did (so those runs resume and seed targets)
ADDED_LATER = {"novelty.normalisation": "population", "novelty.archive_rule": "paper", "novelty.behaviour": "paper",
               "hyperneat.impl": "auto",
               **{f"{section}.{field}": value for section in ("ppo", "ppo_entity")
                  for field, value in (("rollout", "smdp"), ("max_minibatches", 0), ("learn_per_episode", 0),
                                       ("devices", 1))}}


def with_later_fields(d: dict) -> dict:
    """``d`` (a nested config dict) with each :data:`ADDED_LATER` field it lacks at its old value; a copy."""
    d = copy.deepcopy(d)
    for dotted, value in ADDED_LATER.items():
        *parents, leaf = dotted.split(".")
        node = d
        for part in parents:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and leaf not in node:
            node[leaf] = value
    return d


def read_run_json(path: str | pathlib.Path):
    """A run directory's ``config.json`` as JSON (the config's fields and a transferred run's record of its
    source), or :class:`ConfigError` when it is there but not readable as JSON; ``None`` when it is missing."""
    path = pathlib.Path(path)
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"{path}: corrupt, not readable as JSON ({e})") from None


def read_run_config(path: str | pathlib.Path) -> ml_collections.ConfigDict:
    """A run directory's ``config.json`` as a config (unlocked), or :class:`ConfigError` saying why not:
    missing, not JSON, not an object of config fields, or written by a kx with other fields."""
    path = pathlib.Path(path)
    d = read_run_json(path)
    if d is None:
        raise ConfigError(f"{path}: no such file (not a kx run directory?)")
    if isinstance(d, dict):
        d = {k: v for k, v in d.items() if k != SOURCE_RECORD}  # a transferred run's record of its source
        d = with_later_fields(d)
    try:
        cfg = from_dict(d)
        missing = sorted(set(_fields(cfg)) - set(flatten(d)))
        if missing:
            raise ConfigError(f"{missing[0]}: missing ({len(missing)} fields this kx's configs have are missing)")
        return cfg
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}; written by another kx version, or edited by hand") from None
    except (TypeError, ValueError, AttributeError) as e:
        raise ConfigError(f"{path}: its fields do not fit this kx's configs ({e})") from None


def identity_mismatch(saved: dict, cfg: ml_collections.ConfigDict) -> str | None:
    """The first field (other than :data:`RESUMABLE`) where a checkpoint's config differs from
    ``cfg``, described; ``None`` if they agree."""
    now = cfg.to_dict()
    # JSON writes tuples as lists
    tup = lambda d: {k: tuple(v) if isinstance(v, list) else v for k, v in flatten(d).items()}  # noqa: E731
    a, b = tup(with_later_fields(saved)), tup(now)
    for field in sorted(set(a) | set(b)):
        if field in RESUMABLE:
            continue
        if a.get(field, "<absent>") != b.get(field, "<absent>"):
            return f"{field} = {a.get(field, '<absent>')!r} in the checkpoint, {b.get(field, '<absent>')!r} now"
    return None


def parse_seeds(text: str) -> list[int]:
    """The seeds of a ``--seeds`` flag (``kx.train``, ``kx.experiments sweep``): ``N``, ``A-B`` (``A`` to ``B``,
    both included) or several of them separated by commas (``0-15``, ``0,3,7``, ``0-2,7``), each seed once and
    a valid config ``seed``; otherwise a ``ConfigError`` naming the flag, the allowed forms and ``text``."""
    allowed = "N, A-B or A,B,C (mixed: 0-2,7) with 0 <= seed < 2**31, each seed once"
    seeds: list[int] = []
    for part in text.split(","):
        lo, dash, hi = part.strip().partition("-")
        try:
            a, b = int(lo), int(hi) if dash else int(lo)
        except ValueError:
            raise ConfigError(f"--seeds: allowed {allowed}, got {text!r}") from None
        need(0 <= a <= b < 2**31, "--seeds", allowed, text)
        seeds += range(a, b + 1)
    need(len(set(seeds)) == len(seeds), "--seeds", allowed, text)
    return seeds
