#!/usr/bin/env bash
# run_all.sh CODEDIR OUTDIR
#
# Runs the `make demo` commands (plus table show, eval --fidelity games, experiments smoke,
# claims) with the code of CODEDIR (cd CODEDIR; PYTHONPATH=CODEDIR; $PYTHON -m farm.cli),
# every result and every capture-time store under OUTDIR, which must not exist or be empty.
#
# Stores: the configs' store paths `results/demo/X` become OUTDIR/X and `results/X` become
# OUTDIR/X (the Makefile's RESULTS=results/demo is OUTDIR). Where a command has --store it is
# used; otherwise a copy of the config, changed only in its `store:` line, is written to
# OUTDIR/configs/<same relative path> and used instead of CODEDIR/configs/....
#
# Logs: OUTDIR/logs/<step>.out / .err; each step's wall time on stdout and in
# OUTDIR/logs/steps.tsv; the code dir in OUTDIR/logs/codedir.txt (compare.py masks it).
# PYTHON: the interpreter (default: this checkout's .venv/bin/python). Steps run one after another.
set -u -o pipefail

if [ $# -ne 2 ]; then
  echo "usage: $0 CODEDIR OUTDIR" >&2
  exit 2
fi
PYTHON=${PYTHON:-$(cd "$(dirname "$0")/.." && pwd -P)/.venv/bin/python}
CODEDIR=$(cd "$1" && pwd -P) || { echo "run_all: no such CODEDIR $1" >&2; exit 2; }
case "$2" in /*) OUTDIR=$2 ;; *) OUTDIR=$(pwd -P)/$2 ;; esac
OUTDIR=${OUTDIR%/}
if [ -e "$OUTDIR" ] && [ -n "$(ls -A "$OUTDIR" 2>/dev/null)" ]; then
  echo "run_all: $OUTDIR exists and is not empty; give a new folder (each run starts from empty stores)" >&2
  exit 2
fi
mkdir -p "$OUTDIR/logs" "$OUTDIR/configs/train" "$OUTDIR/configs/experiments"
LOGS=$OUTDIR/logs
STORE=$OUTDIR/capture_times.sqlite
echo "$CODEDIR" > "$LOGS/codedir.txt"
printf 'step\tseconds\tstatus\n' > "$LOGS/steps.tsv"

cd "$CODEDIR" || exit 2
export PYTHONPATH=$CODEDIR
unset RAY_ADDRESS SWARM_FARM_STORE

# Check that CODEDIR's code is what gets imported (not the venv's editable install).
got=$("$PYTHON" -c 'import farm, workers, os; print(os.path.dirname(os.path.dirname(farm.__file__)), os.path.dirname(os.path.dirname(workers.__file__)))') \
  || { echo "run_all: cannot import farm with $PYTHON" >&2; exit 2; }
if [ "$got" != "$CODEDIR $CODEDIR" ]; then
  echo "run_all: farm/workers are imported from '$got', not from $CODEDIR" >&2
  exit 2
fi

# A copy of CODEDIR/configs/REL with its store line pointed under OUTDIR; prints the copy's path.
config_copy() {
  local rel=$1 src=$CODEDIR/configs/$1 dst=$OUTDIR/configs/$1
  [ -f "$src" ] || { echo "run_all: no config $src" >&2; return 1; }
  mkdir -p "$(dirname "$dst")"
  sed -E "/^[[:space:]]*(service:.*)?store:/ { s#results/demo/#$OUTDIR/#; s#results/#$OUTDIR/# }" "$src" > "$dst"
  if cmp -s "$src" "$dst"; then
    echo "run_all: $src names no store under results/ (nothing to redirect)" >&2
    return 1
  fi
  if grep -nE 'store:' "$dst" | grep -v "$OUTDIR/" >&2; then
    echo "run_all: a store line of $dst above is not under $OUTDIR" >&2
    return 1
  fi
  echo "$dst"
}

step() {  # step NAME ARGS...: farm ARGS, logs in LOGS/NAME.out/.err
  local name=$1; shift
  local t0 t1 rc secs
  echo "== $name: farm $*"
  t0=$(date +%s.%N)
  "$PYTHON" -m farm.cli "$@" > "$LOGS/$name.out" 2> "$LOGS/$name.err"
  rc=$?
  t1=$(date +%s.%N)
  secs=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.1f", b - a }')
  printf '%s\t%s\t%s\n' "$name" "$secs" "$rc" >> "$LOGS/steps.tsv"
  if [ $rc -ne 0 ]; then
    echo "   FAILED (exit $rc) after $secs s; last lines of $LOGS/$name.err:" >&2
    tail -n 15 "$LOGS/$name.err" >&2
    echo "run_all: stopped at step $name" >&2
    exit 1
  fi
  echo "   ok, $secs s"
}

TRAIN_CFG=$(config_copy train/demo_3x3.yaml) || exit 2
SUITE_CFG=$(config_copy suite_demo.yaml) || exit 2
EXP_CFG=$(config_copy experiments/smoke.yaml) || exit 2

T_ALL=$(date +%s)
step pe-table     pe-table --games 50 --out "$OUTDIR/pe-table"
step game         game --n-pursuers 5 --n-evaders 1 --seed 1 --plot "$OUTDIR/game_5v1.png"
step sweep        sweep configs/smoke.yaml --out "$OUTDIR/sweep-smoke"
step table        table configs/table_small.yaml --store "$STORE"
step table-show   table show configs/table_small.yaml --store "$STORE"
step train        train "$TRAIN_CFG" --out "$OUTDIR/runs/demo-3x3"
step eval         eval "$OUTDIR/runs/demo-3x3" --episodes 10
step eval-games   eval "$OUTDIR/runs/demo-3x3" --episodes 10 --fidelity games
step suite        suite "$SUITE_CFG" --out "$OUTDIR/suite"
step experiments  experiments "$EXP_CFG" --out "$OUTDIR/experiments/smoke"
step claims       claims "$OUTDIR/experiments/smoke"
step report       report "$OUTDIR"
echo "all steps ok in $(( $(date +%s) - T_ALL )) s; results in $OUTDIR"
