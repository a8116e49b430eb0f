"""Issue 17, configs: bad input never becomes a wrong result. Every number in every config
is finite (allow_inf_nan=False on farm.core.config.Strict, and case_from's checks of nested game
values), a boolean is never a number (top level, nested lists, game fields), and
`gradient_steps: 0` (a model never updated) is refused; each with one line naming the field.

Property tests (hypothesis): each config loader (load_train_config, load_sweep_config,
load_table_config) and case_from, given arbitrary YAML mappings (keys from the real field
names plus junk, values numbers with NaN and infinities, booleans, text, null, lists and
mappings), returns a model or raises a workers.SwarmFarmError, never another exception.
Example counts: 150 per loader, 300 for case_from (each property well under 20 s).
"""

import math
import tempfile
import textwrap
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from helpers import raises_one_line
from hypothesis import strategies as st
from pydantic import ValidationError

from farm.alloc import AllocConfig
from farm.alloc.training import EvalParams, ServiceParams, TD3Params, TrainConfig, load_train_config
from farm.core.config import GAME_FIELDS, SETTING_FIELDS, ConfigError, case_from, first_line
from farm.games.sweep import load_sweep_config
from farm.games.sweep.config import VARIABLE_FIELDS, SweepConfig
from farm.service.table import TableConfig, load_table_config
from workers import SwarmFarmError


def write(tmp_path, text, name="config.yaml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def refused(loader, path, *fragments):
    """The loader's ConfigError for path: one line holding every fragment."""
    return raises_one_line(ConfigError, lambda: loader(path), *fragments)


# ----- 1. every number finite ------------------------------------------------------------

@pytest.mark.parametrize("field", ["learning_rate", "noise_std", "tau", "gamma"])
@pytest.mark.parametrize("value", [".inf", "-.inf", ".nan"])
def test_a_training_config_refuses_infinite_and_nan_hyperparameters(tmp_path, field, value):
    """`learning_rate: .inf` was accepted: every policy tensor became NaN, metrics.json
    showed a normal return and config.yaml saved null."""
    path = write(tmp_path, f"name: x\ntd3: {{{field}: {value}}}\n")
    refused(load_train_config, path, f"td3.{field}:", "finite")


def test_a_number_given_as_text_is_finite_too():
    with pytest.raises(ValidationError) as err:
        TrainConfig(name="x", td3={"learning_rate": "inf"})
    assert first_line(err.value) == "td3.learning_rate: Input should be a finite number"
    assert TD3Params(learning_rate="0.01").learning_rate == 0.01  # text numbers still read, as before


@pytest.mark.parametrize("env, field", [
    ("{target: [.nan, 5]}", "env.target"),
    ("{exit_point: [0, .inf]}", "env.exit_point"),
    ("{arena: [[0, 0], [10, 0], [.inf, 10]]}", "env.arena"),
    ("{law: {kind: boxes, pursuer_box: [.nan, 5, 0, 10]}}", "env.law"),
    ("{capture_radius: .inf}", "env.capture_radius"),
    ("{vertical_drift: .nan}", "env.vertical_drift"),
])
def test_the_env_refuses_non_finite_game_values_nested_too(tmp_path, env, field):
    refused(load_train_config, write(tmp_path, f"name: x\nenv: {env}\n"), f"{field}:")


@pytest.mark.parametrize("fields, where", [
    ({"target": [math.nan, 5]}, "target"),
    ({"exit_point": [0.0, math.inf]}, "exit_point"),
    ({"arena": [[0, 0], [10, 0], [math.inf, 10]]}, "arena"),
    ({"law": {"kind": "boxes", "pursuer_box": [3, 5, 0, math.nan]}}, "law.pursuer_box"),
    ({"law": {"kind": "boxes", "evader_box": [7, 9, -math.inf, 10]}}, "law.evader_box"),
    ({"dt": "nan"}, "dt"),
])
def test_case_from_refuses_non_finite_values_nested_too(fields, where):
    with pytest.raises(ConfigError, match=f"^{where}"):
        case_from({"n_pursuers": 1, "n_evaders": 1, **fields})


def test_sweep_and_table_configs_refuse_non_finite_values(tmp_path):
    sweep = "name: s\nbase: {n_pursuers: 1, n_evaders: 1%s}\nvary: %s\n"
    refused(load_sweep_config, write(tmp_path, sweep % (", target: [.nan, 5]", "{}")), "base: target:", "finite")
    refused(load_sweep_config, write(tmp_path, sweep % ("", "{grid: {capture_radius: [0.2, .inf]}}")),
            "vary: point 1 (capture_radius=inf): capture_radius:", "finite")
    refused(load_sweep_config, write(tmp_path, sweep % ("", "{random: {n: 2, ranges: {dt: [0.01, .inf]}}}")),
            "vary.random.ranges:")
    refused(load_table_config, write(tmp_path, "name: t\nsettings: {tau: .nan}\nn_pursuers: [1]\nn_evaders: [1]\n"),
            "tau")


# ----- 2. a boolean is never a number ------------------------------------------------------

def test_capture_radius_true_is_refused_not_read_as_one(tmp_path):
    """`capture_radius: true` ran with r_c = 1 (pydantic's lax mode)."""
    refused(load_train_config, write(tmp_path, "name: x\nenv: {capture_radius: true}\n"),
            "env.capture_radius:", "a bool is not a number")
    with pytest.raises(ConfigError, match="^capture_radius: .*a bool is not a number"):
        case_from({"n_pursuers": 1, "n_evaders": 1, "capture_radius": True})
    with pytest.raises(ConfigError, match=r"^target\[1\]: .*a bool is not a number"):
        case_from({"n_pursuers": 1, "n_evaders": 1, "target": [0, True]})
    with pytest.raises(ConfigError, match=r"^law\.pursuer_box\[0\]: .*a bool is not a number"):
        case_from({"n_pursuers": 1, "n_evaders": 1, "law": {"kind": "boxes", "pursuer_box": [True, 5, 0, 10]}})
    with pytest.raises(ConfigError, match="^n_pursuers: .*a bool is not a number"):
        case_from({"n_pursuers": True, "n_evaders": 1})


def test_a_sweep_grid_with_a_boolean_is_refused_not_two_identical_points(tmp_path):
    """`n_pursuers: [1, true]` made two identical points."""
    refused(load_sweep_config,
            write(tmp_path, "name: s\nbase: {n_evaders: 1}\nvary: {grid: {n_pursuers: [1, true]}}\n"),
            "vary: point 1 (n_pursuers=True): n_pursuers:", "a bool is not a number")
    refused(load_sweep_config, write(tmp_path, "name: s\nbase: {n_pursuers: 1, n_evaders: 1, tau: true}\n"),
            "tau", "a bool is not a number")
    refused(load_sweep_config, write(tmp_path, "name: s\nseed: true\n"), "seed", "a bool is not a number")
    refused(load_sweep_config, write(tmp_path, "name: s\nvary: {random: {n: 2, ranges: {dt: [0.01, true]}}}\n"),
            "vary.random.ranges", "a bool is not a number")


@pytest.mark.parametrize("text, field", [
    ("td3: {n_timesteps: true}", "td3.n_timesteps"),
    ("td3: {learning_rate: true}", "td3.learning_rate"),
    ("td3: {gradient_steps: false}", "td3.gradient_steps"),
    ("td3: {policy_kwargs: {net_arch: [true, 300]}}", "td3.policy_kwargs"),
    ("td3: {policy_kwargs: {n_critics: true}}", "td3.policy_kwargs"),
    ("seed: true", "seed"),
    ("threads: true", "threads"),
    ("eval: {episodes: true}", "eval.episodes"),
    ("env: {grid_size: true}", "env.grid_size"),
    ("env: {c_capture: true}", "env.c_capture"),
    ("env: {games: true}", "env.games"),
    ("env: {target: [true, 5]}", "env.target"),
])
def test_a_training_config_refuses_a_boolean_for_a_number(tmp_path, text, field):
    refused(load_train_config, write(tmp_path, f"name: x\n{text}\n"), f"{field}:")


def test_booleans_where_booleans_belong_and_text_numbers_still_work():
    config = TrainConfig(name="x", service={"warm_lattice": False, "estimates": True},
                         td3={"policy_kwargs": {"net_arch": [8, 8], "share_features_extractor": True}})
    assert config.service.warm_lattice is False and config.service.estimates is True
    # the CLI passes game flags as text to case_from: that reads as before
    case = case_from({"n_pursuers": "2", "n_evaders": 1, "capture_radius": "0.5", "tau": "4"})
    assert (case.n_pursuers, case.capture_radius, case.tau) == (2, 0.5, 4.0)


def test_a_table_config_refuses_booleans(tmp_path):
    refused(load_table_config, write(tmp_path, "name: t\nn_pursuers: [1, true]\nn_evaders: [1]\n"),
            "n_pursuers", "a bool is not a number")
    refused(load_table_config, write(tmp_path, "name: t\nsettings: {capture_radius: true}\nn_pursuers: [1]\n"
                                               "n_evaders: [1]\n"), "capture_radius", "a bool is not a number")


# ----- 3. gradient_steps: 0 --------------------------------------------------------------

def test_gradient_steps_zero_is_refused(tmp_path):
    """`gradient_steps: 0` was accepted: the model was never updated."""
    refused(load_train_config, write(tmp_path, "name: x\ntd3: {gradient_steps: 0}\n"), "td3.gradient_steps:", "-1")
    assert TD3Params(gradient_steps=-1).gradient_steps == -1 and TD3Params(gradient_steps=4).gradient_steps == 4
    refused(load_train_config, write(tmp_path, "name: x\ntd3: {gradient_steps: -2}\n"), "td3.gradient_steps:")


def test_policy_kwargs_that_sb3_would_reject_are_refused_when_loaded(tmp_path):
    for text, fragment in [("{net_arc: [8]}", "net_arc: not a TD3 policy argument"),
                           ("{net_arch: [0, 8]}", "net_arch"),
                           ("{optimizer_kwargs: {lr: 1}}", "optimizer_kwargs"),
                           ("{optimizer_kwargs: {betas: [0.9, 1.5]}}", "optimizer_kwargs.betas"),
                           ("{net_arch: [.nan]}", "net_arch"),
                           ("{optimizer_kwargs: {eps: .inf}}", "optimizer_kwargs.eps"),
                           ("{optimizer_kwargs: {weight_decay: true}}", "optimizer_kwargs.weight_decay")]:
        refused(load_train_config, write(tmp_path, f"name: x\ntd3: {{policy_kwargs: {text}}}\n"),
                "td3.policy_kwargs:", fragment)
    ok = TD3Params(policy_kwargs={"net_arch": {"pi": [8], "qf": [8, 8]}, "optimizer_kwargs": {"eps": 1e-6}})
    assert ok.policy_kwargs["net_arch"] == {"pi": [8], "qf": [8, 8]}


# ----- 7a. property: a loader returns a model or raises the project's error ----------------

JUNK_KEYS = ["", "x", "name ", "Name", "n", "grid", "0", "true", "null", "ñ"]
numbers = st.one_of(
    st.integers(-3, 12), st.sampled_from([0, 1, 2, -1, 2**31, 2**63, 10**30]),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.5, 1.0, 5.0, 10.0, 1e-3, 1e300]))
leaves = st.one_of(numbers, st.booleans(), st.none(),
                   st.sampled_from(["area_min", "centroid", "pure_pursuit", "target", "uniform", "boxes", "v1", "v2",
                                    "local", "softmax", "normal", "x", "", "0.5", "nan", "inf", "true"]),
                   st.text(max_size=6))


JUNK_KEY = st.sampled_from(JUNK_KEYS)


def values(keys=JUNK_KEY):
    """Random YAML values: leaves, and lists and mappings of them (nested a little)."""
    return st.recursive(leaves, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=3),
                        max_leaves=8)


def mapping(fields, plausible=None, required=()):
    """A random mapping over the real field names, each present or not (the required ones
    always): 3 times in 4 a clean one (plausible values where given), else a noisy one
    (any field's value random 1 time in 3, and now and then a junk name too)."""
    plausible = plausible or {}

    def build(noisy):
        def value_of(name):
            good = plausible.get(name)
            if good is None:
                return values()
            return st.sampled_from([True, True, False]).flatmap(lambda ok: good if ok else values()) if noisy else good

        real = st.fixed_dictionaries({name: value_of(name) for name in fields if name in required},
                                     optional={name: value_of(name) for name in fields if name not in required})
        if not noisy:
            return real
        junk = st.dictionaries(st.sampled_from(JUNK_KEYS), values(), max_size=1)
        return st.builds(lambda a, b: {**a, **b}, real, junk)

    return st.sampled_from([False, False, False, True]).flatmap(build)


def point(lo=0.0, hi=10.0):
    return st.lists(st.floats(lo, hi), min_size=2, max_size=2)


LAW = mapping(["kind", "pursuer_box", "evader_box"], {
    "kind": st.sampled_from(["boxes", "uniform"]),
    "pursuer_box": st.just([3, 5, 0, 10]) | st.lists(st.floats(0, 10), min_size=4, max_size=4),
    "evader_box": st.just([7, 9, 0, 10]) | st.lists(st.floats(0, 10), min_size=4, max_size=4)})
SETTING_VALUES = {
    "pursuer_policy": st.sampled_from(["area_min", "pure_pursuit", "nope"]),
    "evader_policy": st.sampled_from(["centroid", "target", "constant_area"]),
    "capture_radius": st.floats(0.05, 1.0), "dt": st.sampled_from([0.01, 0.05]), "t_max": st.sampled_from([5, 10, 60]),
    "tau": st.sampled_from([2, 5.0, 10]), "target": point(), "exit_point": st.none() | point(),
    "arena": st.none() | st.just([[0, 0], [10, 0], [10, 10], [0, 10]]), "law": LAW,
    "pursuer_speed": st.floats(0.5, 2.0), "evader_speed": st.floats(0.5, 2.0), "games": st.integers(2, 8),
    "seed": st.integers(0, 5), "n_pursuers": st.integers(1, 4), "n_evaders": st.integers(1, 4)}
GAME = mapping(GAME_FIELDS, SETTING_VALUES, required=("n_pursuers", "n_evaders"))
SETTINGS = mapping(SETTING_FIELDS + ("games", "seed"), SETTING_VALUES)
ENV = mapping(list(AllocConfig.model_fields), {
    **SETTING_VALUES, "grid_size": st.integers(2, 5), "n_defenders": st.integers(1, 200),
    "n_intruders": st.integers(1, 100), "c_distribution": st.floats(0, 2), "c_capture": st.floats(0, 2),
    "engagement": st.sampled_from(["v1", "v2"]), "team_sizes": st.sampled_from(["exact", "lattice"]),
    "vertical_drift": st.floats(0, 0.5), "max_steps": st.integers(1, 20), "tau": st.none() | st.sampled_from([5, 10]),
    "t_max": st.none() | st.sampled_from([10, 20]), "step_seconds": st.none() | st.just(10)})
TD3 = mapping(list(TD3Params.model_fields), {
    "n_timesteps": st.integers(1, 10**6), "policy": st.just("MlpPolicy"), "buffer_size": st.integers(1, 10**6),
    "learning_starts": st.integers(0, 100), "train_freq": st.integers(1, 4), "policy_delay": st.integers(1, 3),
    "learning_rate": st.floats(1e-6, 1e30), "tau": st.floats(0.001, 1),
    "gamma": st.floats(0, 1), "gradient_steps": st.integers(-2, 4), "noise_std": st.floats(0, 1),
    "noise_type": st.sampled_from(["normal", "none"]), "batch_size": st.integers(1, 512),
    "policy_kwargs": mapping(["net_arch", "n_critics", "optimizer_kwargs", "share_features_extractor"], {
        "net_arch": st.lists(st.integers(1, 64), max_size=3) | st.just({"pi": [8], "qf": [8]}),
        "n_critics": st.integers(1, 3), "optimizer_kwargs": st.just({"eps": 1e-6}),
        "share_features_extractor": st.booleans()})})
TRAIN = mapping(list(TrainConfig.model_fields), {
    "name": st.sampled_from(["run", "a.b-1", "run", "bad name"]), "seed": st.integers(0, 9),
    "threads": st.none() | st.integers(1, 4), "checkpoint_freq": st.integers(1, 10), "log_interval": st.integers(1, 10),
    "env": ENV, "td3": TD3, "eval": mapping(list(EvalParams.model_fields), {"freq": st.integers(1, 100)}),
    "service": mapping(list(ServiceParams.model_fields), {"mode": st.sampled_from(["local", "ray"]),
                                                          "store": st.none() | st.just("s.sqlite"),
                                                          "address": st.none() | st.just("127.0.0.1:6379"),
                                                          "warm_lattice": st.booleans(), "estimates": st.booleans()})},
    required=("name",))
VARY = st.dictionaries(st.sampled_from(VARIABLE_FIELDS), st.lists(st.sampled_from([1, 2, 0.5]) | values(),
                                                                  min_size=1, max_size=3), max_size=2)
SWEEP = mapping(list(SweepConfig.model_fields), {
    "name": st.just("s"), "games_per_point": st.integers(1, 100), "base": GAME, "seed": st.integers(0, 9),
    "shard_games": st.none() | st.integers(1, 10),
    "vary": mapping(["grid", "zip", "random"], {"grid": VARY, "zip": VARY, "random": mapping(["n", "ranges"], {
        "n": st.integers(-1, 3), "ranges": st.dictionaries(st.sampled_from(VARIABLE_FIELDS), st.lists(
            st.floats(0.01, 3) | numbers | st.booleans(), min_size=2, max_size=3), max_size=2)})})},
    required=("name",))
TABLE = mapping(list(TableConfig.model_fields), {
    "name": st.just("t"), "settings": SETTINGS, "store": st.none() | st.just("s.sqlite"),
    "n_pursuers": st.lists(st.integers(1, 4) | st.integers(1, 4) | numbers | st.booleans(), min_size=1, max_size=3),
    "n_evaders": st.lists(st.integers(1, 4), min_size=1, max_size=3),
    "policies": st.lists(mapping(["pursuer_policy", "evader_policy"], SETTING_VALUES,
                                 required=("pursuer_policy", "evader_policy")), max_size=2)},
    required=("name", "n_pursuers", "n_evaders"))

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_DIR = Path(tempfile.mkdtemp(prefix="refuses-configs-"))


def loads_or_refuses(loader, raw):
    """Write raw as YAML and load it: a model, or a SwarmFarmError of one line naming the file."""
    path = _DIR / "config.yaml"
    path.write_text(yaml.safe_dump(raw))
    try:
        return loader(path)
    except SwarmFarmError as e:
        assert len(str(e).splitlines()) == 1 and str(e).startswith(f"{path}: "), str(e)
        assert_a_config_message(str(e))
        return None


PYTHON_ERRORS = ("unhashable", "has no attribute", "not subscriptable", "positional argument",
                 "object is not", "NoneType", "Traceback", "out of bounds")


def assert_a_config_message(message):
    """A message about the config's values, not a Python error leaking out."""
    assert not any(p in message for p in PYTHON_ERRORS), message


@pytest.mark.slow
@FAST
@given(TRAIN)
def test_property_training_configs_load_or_are_refused(raw):
    config = loads_or_refuses(load_train_config, raw)
    if config is not None:  # what loads is finite and saves as it loaded
        assert load_train_config_round_trip(config) == config


def load_train_config_round_trip(config):
    import json

    path = _DIR / "saved.yaml"
    path.write_text(yaml.safe_dump(json.loads(config.model_dump_json()), sort_keys=False))
    return load_train_config(path)


@FAST
@given(SWEEP)
def test_property_sweep_configs_load_or_are_refused(raw):
    loads_or_refuses(load_sweep_config, raw)


@FAST
@given(TABLE)
def test_property_table_configs_load_or_are_refused(raw):
    loads_or_refuses(load_table_config, raw)


@settings(max_examples=300, deadline=None)
@given(GAME)
def test_property_case_from_returns_a_case_or_a_config_error(fields):
    try:
        case = case_from(fields)
    except SwarmFarmError as e:
        assert len(str(e).splitlines()) == 1
        assert_a_config_message(str(e))
        return
    for name in ("capture_radius", "dt", "t_max", "tau", "pursuer_speed", "evader_speed"):
        value = getattr(case, name)
        assert isinstance(value, float) and math.isfinite(value) and value > 0
    assert all(not isinstance(v, bool) for v in (case.n_pursuers, case.n_evaders))


# ----- YAML a config cannot mean -----------------------------------------------------------

SWEEP_TEXT = """\
    name: s
    base: {n_evaders: 1}
    vary: {grid: {n_pursuers: [3, 4]}}
    """


def test_a_key_given_twice_is_refused_not_silently_the_last(tmp_path):
    p = write(tmp_path, SWEEP_TEXT + "name: t\n")
    refused(load_sweep_config, p, str(p), "line 4", "'name' is given twice")
    p = write(tmp_path, "service: {mode: local, mode: ray}\n", name="train.yaml")
    refused(load_train_config, p, "'mode' is given twice")


def test_yaml_aliases_are_read_but_a_short_file_cannot_expand_into_millions_of_values(tmp_path):
    bomb = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n" for i in range(12))
    p = write(tmp_path, bomb)
    message = refused(load_sweep_config, p, "holds more than 100,000 values once its YAML aliases are expanded")
    assert len(message) < 300
    p = write(tmp_path, "a: &a [*a]\n")  # an alias inside itself
    refused(load_sweep_config, p, "not a config")
    raw = {"name": "s", "base": {"n_evaders": 1}, "vary": {"grid": {"n_pursuers": [3, 4]}}}
    raw["vary"]["zip"] = {"n_evaders": raw["vary"]["grid"]["n_pursuers"]}  # one list used twice: PyYAML writes an alias
    p = tmp_path / "dumped.yaml"
    p.write_text(yaml.safe_dump(raw))
    assert "*id001" in p.read_text()
    assert load_sweep_config(p).count() == 4


def test_a_file_nested_too_deep_or_too_large_is_refused(tmp_path):
    from farm.core.config import MAX_CONFIG_BYTES, MAX_CONFIG_DEPTH
    p = write(tmp_path, "a: " + "[" * 2000 + "]" * 2000 + "\n")
    refused(load_sweep_config, p, f"nested deeper than {MAX_CONFIG_DEPTH} levels")
    p = write(tmp_path, "a: " + "[" * (MAX_CONFIG_DEPTH + 1) + "]" * (MAX_CONFIG_DEPTH + 1) + "\n")
    refused(load_sweep_config, p, f"nested deeper than {MAX_CONFIG_DEPTH} levels")
    p = tmp_path / "big.yaml"
    p.write_text("# " + "x" * MAX_CONFIG_BYTES + "\n")
    refused(load_sweep_config, p, "larger than 1 MiB")
    refused(load_sweep_config, Path("/dev/zero"), "/dev/zero", "larger than 1 MiB")


def test_plain_yaml_still_loads_through_the_strict_reader(tmp_path):
    from farm.core.config import read_yaml
    p = write(tmp_path, SWEEP_TEXT)
    assert load_sweep_config(p).name == "s"
    assert read_yaml(p) == yaml.safe_load(p.read_text())
