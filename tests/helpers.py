"""Helpers the test modules share (`from helpers import ...`): `farm` run as a subprocess or from
the repository's root, the checks of a one-line refusal, the bit-for-bit comparison of what envs
return and of saved models, a training stopped as if killed and a capture-time client without
games. conftest.py holds the fixtures and the Ray and process helpers."""

import contextlib
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent


def farm_process(*args, cwd=None):
    """`farm ARGS` as a real subprocess: its CompletedProcess (returncode, stdout, stderr)."""
    return subprocess.run([sys.executable, "-m", "farm.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=900, cwd=cwd)


def farm_in_repo(*args):
    """`farm ARGS` in this process (farm.cli.main) from the repository's root: returncode, stdout, stderr."""
    from conftest import farm_main

    with contextlib.chdir(REPO):
        status, out, err = farm_main(*args)
    return SimpleNamespace(returncode=status, stdout=out, stderr=err)


def one_line(error, *fragments) -> str:
    """An error's message (or a text), asserted one line holding every fragment; returns it."""
    text = str(error)
    assert text and "\n" not in text and len(text.splitlines()) == 1, text
    for fragment in fragments:
        assert fragment in text, text
    return text


def raises_one_line(error_type, call, *fragments) -> str:
    """The message of the error_type that call() raises, asserted one line holding every fragment."""
    with pytest.raises(error_type) as caught:
        call()
    return one_line(caught.value, *fragments)


def farm_refusal(status, err: str, *fragments) -> str:
    """A `farm` refusal: exit status 2, stderr one `farm: error: ` line (no traceback) holding every fragment."""
    assert status == 2, err
    line = err.strip()
    assert line.startswith("farm: error: ") and "Traceback" not in line, line
    return one_line(line, *fragments)


def assert_same(a, b, where=""):
    """Equal to the bit: arrays (dtype and values), object arrays element by element, dicts by key."""
    if isinstance(a, dict):
        assert set(a) == set(b), (where, sorted(set(a) ^ set(b)))
        for key in a:
            assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert b.dtype == object and a.shape == b.shape, where
        for x, y in zip(a, b):
            assert (x is None and y is None) or np.array_equal(x, y), where
    else:
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and np.array_equal(a, b), (where, a, b)


class Stop(Exception):
    """Raised by stop_at's callback: the run ends as if killed."""


def stop_at(step: int):
    """An SB3 callback raising Stop once the run has taken `step` steps, before that step's update."""
    from stable_baselines3.common.callbacks import BaseCallback

    class StopAt(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= step:
                raise Stop(f"stopped at step {step}")
            return True

    return StopAt()


class Answers:
    """A capture-time client without games: an engaged cell loses a third of its intruders, scores one half."""

    repeatable = True

    def get_many(self, pairs, estimate=False):
        return [SimpleNamespace(frac_captured_tau=1 / 3, capture_score_tau=0.5, estimate=None) for _ in pairs]

    def close(self):
        pass


def policy_tensors(path, algo: str) -> dict:
    """A saved stable-baselines3 model's policy tensors and, for PPO, its optimizer's state."""
    import stable_baselines3
    import torch

    model = getattr(stable_baselines3, algo.upper()).load(path, device="cpu")
    tensors = dict(model.policy.state_dict())
    for i, state in model.policy.optimizer.state_dict()["state"].items() if algo == "ppo" else []:
        tensors.update({f"optimizer.{i}.{k}": torch.as_tensor(v) for k, v in state.items()})
    return tensors


def assert_same_policy(a, b, algo: str) -> None:
    """The models saved at a and b hold the same policy_tensors, to the bit."""
    import torch

    ta, tb = policy_tensors(a, algo), policy_tensors(b, algo)
    assert ta.keys() == tb.keys()
    assert [k for k in ta if not torch.equal(ta[k], tb[k])] == []
