"""farm claims: the paper's claims (a)-(c) measured on hand-built run folders whose
numbers are known."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import yaml

from farm.studies.claims import claims, plateau_minutes


def make_run(root, name, steps_rows, returns, wall=600.0, total=20000, c_capture=None):
    run = root / name
    run.mkdir(parents=True)
    c_capture = (1.5 if name.endswith("1.5") else 0.0) if c_capture is None else c_capture
    (run / "config.yaml").write_text(yaml.safe_dump({"name": name, "env": {"grid_size": 3, "c_capture": c_capture}}))
    pd.DataFrame(steps_rows, columns=["policy", "episode", "step", "coverage", "engaged_cells",
                                      "defenders_per_engaged"]).to_csv(run / "eval_steps.csv", index=False)
    timesteps = np.linspace(total / len(returns), total, len(returns)).astype(int)
    np.savez(run / "evaluations.npz", timesteps=timesteps, results=np.array(returns)[:, None].repeat(3, axis=1))
    (run / "metrics.json").write_text(json.dumps({"timesteps": total, "wall_seconds": wall}))
    return run


def spread_rows(engaged, per_cell, coverage_step1):
    rows = []
    for ep in range(4):
        for step in (1, 2, 3):
            rows.append(["td3", ep, step, coverage_step1 if step == 1 else 0.5, engaged[ep % 2], per_cell[ep % 2]])
    return rows


def test_claims_on_known_runs(tmp_path):
    make_run(tmp_path, "paper_3x3_c1_0", spread_rows((3, 3), (33.0, 33.0), 1.0), [-3, -1, -0.5, -0.5, -0.5])
    make_run(tmp_path, "paper_3x3_c1_1.5", spread_rows((1, 1), (90.0, 100.0), 0.4), [-2, -2, -2, -1, 0])
    rows = {r["claim"][:3]: r for r in claims(tmp_path)}
    assert "coverage at step 1: 1.000" in rows["(a)"]["measured"] and "100% of episodes" in rows["(a)"]["measured"]
    assert rows["(a)"]["verdict"].startswith("confirmed")
    assert rows["(b)"]["verdict"].startswith("confirmed")
    assert "engaged cells per step 1.000 ± 0.000 vs 3.000 ± 0.000" in rows["(b)"]["measured"]
    assert "defenders per engaged cell 95.000 ± 9.187 vs 33.000" in rows["(b)"]["measured"]
    # c1-0 reaches -0.5 (within 5% of the range 2.5 below the best) at its 3rd of 5 evaluations: 12000 of
    # 20000 steps of a 10-minute run; c1-1.5 only at its last.
    assert plateau_minutes(tmp_path / "paper_3x3_c1_0")[:2] == (6.0, 12000)
    assert plateau_minutes(tmp_path / "paper_3x3_c1_1.5")[:2] == (10.0, 20000)
    assert rows["(c)"]["verdict"].startswith("confirmed")


def test_claims_not_confirmed_when_the_numbers_say_so(tmp_path):
    make_run(tmp_path, "paper_3x3_c1_0", spread_rows((2, 3), (33.0, 50.0), 0.5), [-3, -2, -1], wall=1800)
    make_run(tmp_path, "paper_3x3_c1_1.5", spread_rows((2, 3), (33.0, 50.0), 0.5), [-3, -2, -1], wall=1800)
    rows = {r["claim"][:3]: r for r in claims(tmp_path)}
    assert rows["(a)"]["verdict"].startswith("not confirmed")
    assert rows["(b)"]["verdict"].startswith("not confirmed")
    assert rows["(c)"]["verdict"].startswith("not confirmed")


@pytest.mark.slow
def test_cli_claims_writes_a_table_and_errors_in_one_line(tmp_path):
    make_run(tmp_path, "paper_3x3_c1_0", spread_rows((3, 3), (33.0, 33.0), 1.0), [-1, -1])
    farm = [sys.executable, "-m", "farm.cli"]
    ok = subprocess.run([*farm, "claims", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert "(a)" in ok.stdout and (tmp_path / "claims.csv").exists()
    status, _, stderr = farm_claims(tmp_path / "nope")  # in process: the real process is the one above
    assert status == 2 and stderr.strip().count("\n") == 0 and "not a folder" in stderr


def farm_claims(*args):
    """`farm claims ARGS` in this process (farm.cli.main): (exit code, stdout, stderr)."""
    import contextlib
    import io

    from farm.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["claims", *map(str, args)])
    return code, out.getvalue(), err.getvalue().strip()


def test_cli_claims_refuses_runs_that_cannot_be_the_pair_in_one_line(tmp_path):
    """Issue 28's findings: --c0 X --c15 X compared a run with itself; a --c0 naming a missing
    run silently dropped (a) and (b); a run of another C_capture than its flag's was not checked."""
    make_run(tmp_path, "paper_3x3_c1_0", spread_rows((3, 3), (33.0, 33.0), 1.0), [-1, -1])
    make_run(tmp_path, "paper_3x3_c1_1.5", spread_rows((1, 1), (90.0, 100.0), 0.4), [-1, -1])
    make_run(tmp_path, "other_c0", spread_rows((3, 3), (33.0, 33.0), 1.0), [-1, -1], c_capture=0.0)
    for args, expected in [
        (("--c0", "paper_3x3_c1_0", "--c15", "paper_3x3_c1_0"), "--c15: names the same run as --c0"),
        (("--c0", "nope"), "--c0: "),
        (("--c15", "other_c0"), "--c15: "),
        (("--c0", "paper_3x3_c1_1.5", "--c15", "other_c0"), "--c0: "),
    ]:
        code, _, err = farm_claims(tmp_path, *args)
        assert code == 2 and "\n" not in err and expected in err, (args, err)
        assert not (tmp_path / "claims.csv").exists()
    assert "not a trained run folder" in farm_claims(tmp_path, "--c0", "nope")[2]
    assert "trained at C_capture 0.0, not 1.5" in farm_claims(tmp_path, "--c15", "other_c0")[2]
    code, out, _ = farm_claims(tmp_path, "--c0", "other_c0")
    assert code == 0 and "(a)" in out and "(b)" in out


def test_cli_claims_says_when_the_default_pair_is_missing(tmp_path):
    make_run(tmp_path, "larger_5x5", spread_rows((3, 3), (33.0, 33.0), 1.0), [-1, -1])
    code, out, _ = farm_claims(tmp_path)
    assert code == 0 and "(a), (b) left out: no run folder --c0 paper_3x3_c1_0 or --c15 paper_3x3_c1_1.5" in out
    assert pd.read_csv(tmp_path / "claims.csv")["claim"].str[:3].tolist() == ["(c)"]


# ----------------------------------------------------------------------------- over an experiment's seeds
STEPS = [4000, 8000, 12000, 16000, 20000]


def make_trial(folder, key, point, seed, c_capture, steps_rows, returns, timesteps=STEPS, wall=600.0, finished=True,
               defenders=100):
    """One trial of a hand-built experiment folder: its run folder (config.yaml, eval_steps.csv,
    evaluations.npz with 3 episodes each equal to `returns`, metrics.json) and, when finished,
    its result.json (a row of trials.csv)."""
    trial = folder / "trials" / key
    run = trial / "run"
    run.mkdir(parents=True)
    env = {"grid_size": 3, "n_defenders": defenders, "c_capture": c_capture}
    (run / "config.yaml").write_text(yaml.safe_dump({"name": f"fake-{key}", "seed": seed, "env": env,
                                                     "td3": {"n_timesteps": 20000}}))
    np.savez(run / "evaluations.npz", timesteps=np.array(timesteps),
             results=np.array(returns)[:, None].repeat(3, axis=1))
    if not finished:
        return
    pd.DataFrame(steps_rows, columns=["policy", "episode", "step", "coverage", "engaged_cells",
                                      "defenders_per_engaged"]).to_csv(run / "eval_steps.csv", index=False)
    (run / "metrics.json").write_text(json.dumps({"timesteps": 20000, "wall_seconds": wall}))
    (trial / "result.json").write_text(json.dumps({
        "trial": key, "point": point, "seed": seed, "env.c_capture": c_capture, "final_eval_return": returns[-1],
        "best_eval_return": max(returns), "td3_return": returns[-1], "td3_eliminated": 0.9 + 0.01 * seed,
        "spread_evenly_return": -0.5, "spread_evenly_eliminated": 0.95}))


def make_experiment(root, seed1_b=None, defenders15=100):
    """A hand-built experiment folder: points 0 (C_capture 0) and 1 (1.5), seeds 0, 1, 2.

    Seed 0 confirms (a) and (b); seed 1 confirms neither (coverage 0.5 at step 1; the same
    engaged cells and defenders per cell under both settings, unless seed1_b gives its 1.5
    run's rows); seed 2's 1.5 trial is unfinished (no result.json, 2 evaluations), its 0 trial
    evaluated at 3 of the 5 timesteps. Plateaus: 6 min (p0_s0), 30 min (p0_s1, wall 30 min,
    plateau at the last step), the others within 10. defenders15: point 1's defenders (100:
    the pair's other settings equal)."""
    folder = root / "fake"
    trials = [("p0_s0", 0, 0, 0.0, spread_rows((3, 3), (33.0, 33.0), 1.0), [-3, -1, -0.5, -0.5, -0.5], STEPS, 600),
              ("p0_s1", 0, 1, 0.0, spread_rows((2, 3), (33.0, 50.0), 0.5), [-3, -2.5, -2, -1.5, -1], STEPS, 1800),
              ("p0_s2", 0, 2, 0.0, spread_rows((3, 3), (33.0, 33.0), 1.0), [-2, -1, 0], [4000, 12000, 20000], 300),
              ("p1_s0", 1, 0, 1.5, spread_rows((1, 1), (90.0, 100.0), 0.4), [-2, -2, -2, -1, 0], STEPS, 600),
              ("p1_s1", 1, 1, 1.5, seed1_b or spread_rows((2, 3), (33.0, 50.0), 0.5), [-1, -1, -1, -1, -1], STEPS, 600)]
    for key, point, seed, c, rows, returns, timesteps, wall in trials:
        make_trial(folder, key, point, seed, c, rows, returns, timesteps, wall,
                   defenders=100 if point == 0 else defenders15)
    make_trial(folder, "p1_s2", 1, 2, 1.5, [], [-5, -4], [4000, 8000], finished=False, defenders=defenders15)
    manifest = {"name": "fake", "digest": "0" * 16, "config": {"name": "fake", "grid": {"env.c_capture": [0.0, 1.5]},
                                                              "seeds": [0, 1, 2]},
                "store": str(root / "store.sqlite"), "fields": ["env.c_capture"],
                "trials": [{"key": f"p{p}_s{s}", "point": p, "seed": s, "values": {"env.c_capture": c}}
                           for p, c in ((0, 0.0), (1, 1.5)) for s in (0, 1, 2)]}
    (folder / "experiment.json").write_text(json.dumps(manifest))
    return folder


T975_1 = 12.706204736174698  # scipy.stats.t.ppf(0.975, 1): the 95% t interval of 2 values
T975_2 = 4.302652729911275  # scipy.stats.t.ppf(0.975, 2): of 3 values


def test_claims_over_seeds_on_a_known_experiment(tmp_path):
    """Seed 0 confirms (a) and (b), seed 1 neither: both mixed; seed 2 (its 1.5 trial unfinished)
    is left out of (a) and (b); (c) over the 5 finished trials, one of them 30 minutes."""
    from farm.studies.claims import claims_over_seeds

    found = claims_over_seeds(make_experiment(tmp_path))
    assert found.pair == (0, 1) and found.note.startswith("(a), (b): points 0 (C_capture 0) and 1 (C_capture 1.5)")
    assert "2 seed(s) with both trials finished" in found.note
    seeds = found.seeds.set_index("seed")
    assert seeds.index.tolist() == [0, 1]
    assert seeds.a_verdict.tolist() == ["confirmed", "not confirmed"] and seeds.all_engaged.tolist() == [1.0, 0.5]
    assert seeds.b_verdict.tolist() == ["confirmed", "not confirmed"]
    assert seeds.loc[0, "dpe_mean_c15"] == 95.0 and seeds.loc[1, "engaged_mean_c0"] == 2.5
    rows = {r["claim"][:3]: r for r in found.rows}
    assert rows["(a)"]["verdict"] == "mixed (confirmed in 1 of 2 seeds)"
    # coverage at step 1: 1.0 and 0.5 -> mean 0.75, half-width t(0.975, 1) * sd 0.3536 / sqrt 2 = 12.706 * 0.25
    expected = f"coverage at step 1 over seeds 0.750 ± {T975_1 * 0.25:.3f} (per seed 1.000, 0.500)"
    assert expected in rows["(a)"]["measured"]
    assert rows["(b)"]["verdict"] == ("mixed (fewer engaged cells in 1 of 2 seeds, more defenders per engaged cell "
                                      "in 1 of 2)")
    # engaged cells 1.5 - 0: seed 0 1 - 3 = -2, seed 1 2.5 - 2.5 = 0 -> -1 ± 12.706 * 1.414 / 1.414;
    # defenders per engaged cell: seed 0 95 - 33 = 62, seed 1 41.5 - 41.5 = 0 -> 31 ± 12.706 * 31
    assert f"over seeds -1.000 ± {T975_1:.3f} (per seed -2.000, 0.000)" in rows["(b)"]["measured"]
    assert f"31.000 ± {T975_1 * 31:.3f} (per seed 62.000, 0.000)" in rows["(b)"]["measured"]
    assert rows["(c)"]["verdict"] == "mixed (confirmed in 4 of 5 trials)"
    assert found.trials.trial.tolist() == ["p0_s0", "p0_s1", "p0_s2", "p1_s0", "p1_s1"]
    # p0_s0: 12000 of 20000 steps of 10 min; p0_s1: the last step of 30 min; p0_s2: 20000 of 5 min
    assert found.trials.plateau_minutes.tolist()[:3] == [6.0, 30.0, 5.0]
    # point 0 over its 3 seeds: mean 41 / 3, half-width t(0.975, 2) * sd / sqrt 3
    mean = 41 / 3
    sd = np.sqrt(((6 - mean) ** 2 + (30 - mean) ** 2 + (5 - mean) ** 2) / 2)
    assert f"point 0: 13.7 ± {T975_2 * sd / np.sqrt(3):.1f} min (per seed 6.0, 30.0, 5.0)" in rows["(c)"]["measured"]
    assert all("confirmed when every" in r["rule"] for r in found.rows)


def test_claims_over_seeds_partly_confirmed_and_without_a_pair(tmp_path):
    """(b) with more defenders per cell in every seed and fewer cells in none: partly confirmed.
    Point 1 with other defenders than point 0: no pair, only (c), said in one line."""
    from farm.studies.claims import claims_over_seeds

    more_only = spread_rows((2, 3), (90.0, 100.0), 0.5)  # seed 1: the same cells as its 0 run, more defenders
    folder = make_experiment(tmp_path / "a", seed1_b=more_only)
    (folder / "trials" / "p1_s0" / "run" / "eval_steps.csv").write_text(
        pd.DataFrame(spread_rows((3, 3), (90.0, 100.0), 0.4), columns=["policy", "episode", "step", "coverage",
                     "engaged_cells", "defenders_per_engaged"]).to_csv(index=False))
    rows = {r["claim"][:3]: r for r in claims_over_seeds(folder).rows}
    assert rows["(b)"]["verdict"].startswith("partly confirmed (fewer engaged cells in 0 of 2 seeds, more defenders "
                                             "per engaged cell in 2 of 2)")

    alone = claims_over_seeds(make_experiment(tmp_path / "b", defenders15=50))
    assert alone.pair is None and "\n" not in alone.note and alone.note.endswith("only (c)")
    assert [r["claim"][:3] for r in alone.rows] == ["(c)"] and alone.seeds.empty
    named = claims_over_seeds(tmp_path / "b" / "fake", points=(0, 1))
    assert named.pair == (0, 1) and [r["claim"][:3] for r in named.rows] == ["(a)", "(b)", "(c)"]


@pytest.mark.slow
def test_cli_claims_on_an_experiment_folder(tmp_path):
    folder = make_experiment(tmp_path)
    farm = [sys.executable, "-m", "farm.cli", "claims"]
    ok = subprocess.run([*farm, str(folder)], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith("(a), (b): points 0 (C_capture 0) and 1 (C_capture 1.5)")
    assert "verdict:  mixed (confirmed in 1 of 2 seeds)" in ok.stdout and "rule:" in ok.stdout
    table = pd.read_csv(folder / "claims.csv")
    assert table.columns.tolist() == ["claim", "verdict", "measured", "rule"] and len(table) == 3
    assert pd.read_csv(folder / "claims_seeds.csv").seed.tolist() == [0, 1]
    status, _, stderr = farm_claims(folder, "--points", "0", "7")  # in process
    assert status == 2 and stderr.strip().count("\n") == 0 and "points: 7 is not a point of" in stderr


def test_a_damaged_manifest_is_one_line(tmp_path):
    from farm.core.errors import ResultsError
    from farm.studies.claims import claims_over_seeds

    (tmp_path / "experiment.json").write_text("{not json")
    with pytest.raises(ResultsError, match="experiment.json: unreadable experiment manifest") as e:
        claims_over_seeds(tmp_path)
    assert "\n" not in str(e.value)


def test_cli_claims_on_an_experiment_refuses_a_point_twice_a_wrong_point_and_a_run_flag(tmp_path):
    """Issue 28's findings: `--points 0 0` overwrote the experiment's own claims.csv, and an
    ignored --c0 was not refused. Each is one line now, and claims.csv is left as it was."""
    folder = make_experiment(tmp_path)
    code, _, err = farm_claims(folder)
    assert code == 0
    before = (folder / "claims.csv").read_bytes()
    for args, expected in [(("--points", "0", "0"), "points: names point 0 twice"),
                           (("--points", "1", "0"), "points: point 1 trains at C_capture 1.5, not 0"),
                           (("--c0", "p0_s0"), "--c0: names a run of a folder of runs"),
                           (("--c15", "x"), "--c15: names a run of a folder of runs")]:
        code, _, err = farm_claims(folder, *args)
        assert code == 2 and "\n" not in err and expected in err, (args, err)
    assert (folder / "claims.csv").read_bytes() == before
