# `make demo` and `make test` each create .venv when missing and install the project.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
# CPU-only torch on machines like ours; set CONSTRAINTS= to keep your own torch.
CONSTRAINTS ?= -c constraints-cpu.txt
RESULTS ?= results/demo

# The documentation site (mkdocs.yml): built with --strict into site/, so a broken link or reference fails.
export NO_MKDOCS_2_WARNING := 1

.PHONY: docs docs-serve demo lint test test-fast bench exploit robust experiments experiments-learners experiments-learners-hard experiments-learners-near experiments-size-free suite install browser clean

$(STAMP): pyproject.toml constraints-cpu.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(CONSTRAINTS) -e '.[dev]'
	$(PY) -c 'from workers.compiled import precompile; print(f"compiled kernels ready in {precompile():.0f} s")'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/farm pe-table --games 50 --out $(RESULTS)/pe-table
	$(VENV)/bin/farm game --n-pursuers 5 --n-evaders 1 --seed 1 --plot $(RESULTS)/game_5v1.png --animate $(RESULTS)/game_5v1.gif
	$(VENV)/bin/farm sweep configs/smoke.yaml --out $(RESULTS)/sweep-smoke
	$(VENV)/bin/farm table configs/table_small.yaml --store $(RESULTS)/capture_times.sqlite
	rm -rf $(RESULTS)/runs/demo-3x3
	$(VENV)/bin/farm train configs/train/demo_3x3.yaml --out $(RESULTS)/runs/demo-3x3
	$(VENV)/bin/farm eval $(RESULTS)/runs/demo-3x3 --episodes 10 --animate
	$(VENV)/bin/farm suite configs/suite_demo.yaml --out $(RESULTS)/suite
	$(VENV)/bin/farm report $(RESULTS)

# Debian's chromium renders the report in the tests; installed here when missing (needs root).
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || \
	  echo "warning: could not install chromium; the browser test will be skipped outside CI"

# ruff's rules and import-linter's contracts (pyproject.toml): the style, the complexity cap, the
# docstrings, and farm's layers.
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	PYTHONPATH=$(CURDIR) $(VENV)/bin/lint-imports

# Three xdist workers on 2 cores (a third worker fills the time the tests wait on Ray starts and processes):
# the two shared Rays' groups on two, the `ray start` clusters' module on the third, then the modules
# without Ray over all three (tests/conftest.py). The lint comes first: it takes seconds. Bytecode is
# written (into the ignored __pycache__/) even where PYTHONDONTWRITEBYTECODE is set: every test process
# and `farm` subprocess would otherwise compile the project and rewrite the tests' asserts anew.
test: $(STAMP) browser lint
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -q -n 3 --dist loadgroup --no-loadscope-reorder

# The tests marked neither `ray` nor `slow` (every module's quick ones), on the same three workers.
test-fast: $(STAMP)
	PYTHONDONTWRITEBYTECODE= $(PY) -m pytest -q -n 3 --dist loadgroup --no-loadscope-reorder -m "not ray and not slow"

bench: $(STAMP)
	$(PY) benchmarks/engine.py
	$(PY) benchmarks/farm.py
	$(PY) benchmarks/service.py
	$(PY) benchmarks/alloc.py
	$(PY) benchmarks/planners.py
	$(PY) benchmarks/experiments.py
	$(PY) benchmarks/vector_env.py
	$(PY) benchmarks/exploit.py all
	$(PY) benchmarks/minimax.py
	$(PY) benchmarks/searching.py --store results/capture_times.sqlite
	$(PY) benchmarks/robust.py

# The exploitability table (configs/exploit/table.yaml): every allocator against drift, the heuristic
# intruders and the exact best response (3 x 3); then the PPO best responses over 3 seeds
# (validate.yaml and validate_paper.yaml on 3 x 3, learned_large.yaml on 5 x 5, learned_8x8*.yaml on 8 x 8).
# Each scenario's best learned allocator (configs/train/best_<scenario>.yaml) is trained first when missing.
EXPLOIT_RUNS := best_paper_3x3_c1_1.5 best_outnumbered_3x3 best_outnumbered_5x5 best_wide_front_8x8
exploit: $(STAMP)
	for e in $(EXPLOIT_RUNS); do \
	  test -f results/runs/$$e/model.zip || $(VENV)/bin/farm train configs/train/$$e.yaml --out results/runs/$$e || exit 1; \
	done
	$(VENV)/bin/farm exploit configs/exploit/table.yaml --out results/exploit/table
	$(VENV)/bin/farm exploit configs/exploit/validate.yaml --out results/exploit/validate
	$(VENV)/bin/farm exploit configs/exploit/validate_paper.yaml --out results/exploit/validate_paper
	$(VENV)/bin/farm exploit configs/exploit/learned_large.yaml --out results/exploit/learned_large
	$(VENV)/bin/farm exploit configs/exploit/learned_8x8.yaml --out results/exploit/learned_8x8
	$(VENV)/bin/farm exploit configs/exploit/learned_8x8_rh.yaml --out results/exploit/learned_8x8_rh
	$(VENV)/bin/farm report results

# Policy-space response oracles on the four maps (configs/robust/<scenario>.yaml; on outnumbered_3x3
# also with the intruders' exact oracle, outnumbered_3x3_search.yaml), seeds 0, 1 and 2, each into
# results/robust/<the config's name>_s<seed>; the same command again resumes them.
ROBUST_MAPS := outnumbered_3x3 outnumbered_3x3_search paper_3x3_c1_1.5 outnumbered_5x5 wide_front_8x8
robust: $(STAMP)
	for m in $(ROBUST_MAPS); do for s in 0 1 2; do \
	  $(VENV)/bin/farm robust configs/robust/$$m.yaml --seed $$s || exit 1; \
	done; done
	$(VENV)/bin/farm report results

# The scenario suite (configs/suite.yaml): TD3 trained on each scenario (configs/train/suite_*.yaml,
# into results/runs/suite_<scenario>) and the theatres' size-free learner (size_free_transport.yaml),
# then the baselines, the planners and the learned runs on one leaderboard.
SUITE_RUNS := $(patsubst configs/train/%.yaml,%,$(wildcard configs/train/suite_*.yaml)) size_free_transport
suite: $(STAMP)
	for e in $(SUITE_RUNS); do \
	  test -f results/runs/$$e/model.zip || $(VENV)/bin/farm train configs/train/$$e.yaml --out results/runs/$$e || exit 1; \
	done
	$(VENV)/bin/farm suite configs/suite.yaml --out results/suite
	$(VENV)/bin/farm report results

# The paper's runs and the suite's scenarios, 3 seeds each, as one Ray Tune experiment on one
# capture-time service (configs/experiments/paper.yaml); the same command again resumes it.
experiments: $(STAMP)
	$(VENV)/bin/farm experiments configs/experiments/paper.yaml --out results/experiments/paper
	$(VENV)/bin/farm report results

# The learners' recipe (PPO pretrained by DAgger from receding_horizon) on every scenario, 3 seeds.
experiments-learners: $(STAMP)
	$(VENV)/bin/farm experiments configs/experiments/learners.yaml --out results/experiments/learners
	$(VENV)/bin/farm report results

# The long recipe on the four hard 3 x 3 and 5 x 5 maps, 3 seeds (about 45 minutes on 2 cores).
experiments-learners-hard: $(STAMP)
	$(VENV)/bin/farm experiments configs/experiments/learners_hard.yaml --out results/experiments/learners_hard
	$(VENV)/bin/farm report results

# The long recipe on the four maps the uniform one misses by less than 0.003.
experiments-learners-near: $(STAMP)
	$(VENV)/bin/farm experiments configs/experiments/learners_near.yaml --out results/experiments/learners_near
	$(VENV)/bin/farm report results

# The size-free learner (configs/train/size_free_transport.yaml: DAgger from the transport planner on maps
# of at most 8 x 8) over 3 seeds; then its runs on the larger theatres.
experiments-size-free: $(STAMP)
	$(VENV)/bin/farm experiments configs/experiments/size_free_transport.yaml --out results/experiments/size_free_transport
	for s in 0 1 2; do for m in theatre_16x16 theatre_32x32; do \
	  $(VENV)/bin/farm eval results/experiments/size_free_transport/trials/p0_s$$s/run --scenario $$m --references none; done; done
	$(VENV)/bin/farm report results

docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict -d site
	@echo "site: site/index.html (make docs-serve serves it at http://127.0.0.1:8000)"

docs-serve: $(STAMP)
	$(VENV)/bin/mkdocs serve --strict -a 127.0.0.1:8000

clean:
	rm -rf $(VENV) results .pytest_cache site
