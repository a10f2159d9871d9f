#!/usr/bin/env bash
# The package as a user gets it: build the wheel, install it in a fresh venv outside the checkout, and run sppo-train
# (no -conf: the hyperparameters shipped in the wheel) and sppo-enjoy from a folder outside the checkout. Fails when
# either exits non-zero, when the train output lacks the safety summary or its legend, or when anything is read from
# the checkout instead of the installed package.
#
#     bash scripts/check_wheel.sh            # from anywhere; .ci/run runs it
#
# The wheel is built from a clean copy of the sources (git's tracked and untracked, non-ignored files), so that a stale
# build/ folder of the checkout cannot ship modules that no longer exist. Needs python3 (PYTHON to override), git and
# a package registry; everything it makes lies in one temporary folder, removed at the end (KEEP=1 keeps it). It takes
# 4 to 6 minutes on 2 cores, most of it pip installing torch and the zoo into the fresh venv.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd -P)
python=${PYTHON:-python3}
start=$SECONDS

work=$(mktemp -d "${TMPDIR:-/tmp}/sppo_wheel.XXXXXX")
work=$(cd "$work" && pwd -P)
if [ "${KEEP:-0}" = 1 ]; then
  echo "check_wheel: keeping $work"
else
  # removed in the background: deleting the venv's 1.3 GB takes minutes on some disks, and nothing waits for it
  trap 'echo "check_wheel: [$((SECONDS - start))s] removing $work in the background"; rm -rf "$work" </dev/null >/dev/null 2>&1 &' EXIT
fi
case "$work/" in
  "$repo"/*)
    echo "check_wheel: error: the temporary folder $work lies inside the checkout $repo; set TMPDIR to a folder outside it" >&2
    exit 1
    ;;
esac

fail() {
  echo "check_wheel: FAILED: $*" >&2
  exit 1
}

step() {
  echo "check_wheel: [$((SECONDS - start))s] $*"
}

# ---- the wheel, from a clean copy of the sources (symlinks kept: sppo_sb3/hyperparams -> ../hyperparams)
step "copying the sources to $work/src"
mkdir "$work/src"
(
  cd "$repo"
  git ls-files -z --cached --others --exclude-standard | while IFS= read -r -d '' path; do
    if [ -e "$path" ] || [ -L "$path" ]; then printf '%s\0' "$path"; fi # skip files deleted but not yet committed
  done | tar --null -T - -cf -
) | tar -xf - -C "$work/src"
step "building the wheel"
"$python" -m venv "$work/venv"
pip=("$work/venv/bin/python" -m pip --disable-pip-version-check)
"${pip[@]}" wheel -q --no-deps -w "$work/dist" "$work/src"
wheel=$(ls "$work"/dist/sppo_sb3-*.whl)
"$work/venv/bin/python" - "$wheel" <<'EOF'
import sys
import zipfile

names = zipfile.ZipFile(sys.argv[1]).namelist()
for needed in ("sppo_sb3/hyperparams/sppo.yml", "sppo_sb3/hyperparams/velocity/pdo.yml", "sppo_sb3/hyperparams/dmc/sppo.yml"):
    assert needed in names, f"the wheel lacks {needed}: see [options.package_data] in setup.cfg"
assert "sppo_sb3/docs_tables.py" not in names, "the wheel ships sppo_sb3/docs_tables.py (a repository tool)"
lab = [n for n in names if n.startswith(("sppo_lab/", "sppo_sb3/experiments/")) or "_probe/" in n or "point_sweep/" in n]
assert not lab, f"the wheel ships the lab (its home is lab/, outside the wheel): {lab[:5]}"
print(f"check_wheel: {sys.argv[1]}: {sum(n.endswith('.yml') for n in names)} yml files")
EOF

# ---- a fresh venv outside the checkout, the wheel installed with the CPU build of torch
step "installing the wheel in $work/venv"
"${pip[@]}" install -q -c "$repo/constraints.txt" "$wheel"
mkdir "$work/run"
cd "$work/run"
export OMP_NUM_THREADS=1 PYTHONUNBUFFERED=1
bin="$work/venv/bin"
site=$("$bin/python" -c "import pathlib, sppo_sb3; print(pathlib.Path(sppo_sb3.__file__).parent)")
case "$site/" in
  "$repo"/*) fail "sppo_sb3 imports from the checkout ($site), not from the installed wheel" ;;
esac
"$bin/python" -c "
from sppo_sb3.algorithms import HYPERPARAMS_DIR
from sppo_sb3.zoo import constructor_kwargs
assert HYPERPARAMS_DIR.is_dir() and str(HYPERPARAMS_DIR).startswith('$site'), HYPERPARAMS_DIR
assert constructor_kwargs(HYPERPARAMS_DIR / 'sppo.yml', 'SafePointCircle-v0')
"

# ---- sppo-train without -conf (tiny networks and episodes: this checks the plumbing, not learning), then sppo-enjoy
step "sppo-train --algo sppo --env SafePointCircle-v0 -n 300"
tiny=(
  --hyperparams learning_starts:100 batch_size:16 horizon:2
  "policy_kwargs:dict(latent_dim=8,encoder_dim=16,hidden_dim=16)"
  "planner_kwargs:dict(num_samples=8,num_elites=2,iterations=1,horizon_warmup=10,min_std_decay=10)"
)
short=(--env-kwargs max_episode_steps:50)
set +e
"$bin/sppo-train" --algo sppo --env SafePointCircle-v0 -n 300 -f logs --seed 0 --num-threads 1 --device cpu \
  --eval-freq -1 --deployment-episodes 2 "${short[@]}" "${tiny[@]}" >train.log 2>&1
rc=$?
set -e
cat train.log
[ "$rc" -eq 0 ] || fail "sppo-train exited with $rc"
grep -q "Loading hyperparameters from: $site/hyperparams/sppo.yml" train.log ||
  fail "sppo-train did not read the wheel's hyperparams/sppo.yml"
for expected in "Safety summary: sppo on SafePointCircle-v0" "cumulative violations=" "safety rate=" "eval_unshielded/" \
  "legend:"; do
  grep -qF "$expected" train.log || fail "the train output lacks '$expected'"
done
[ -f logs/sppo/SafePointCircle-v0_1/safety_summary.json ] || fail "no logs/sppo/SafePointCircle-v0_1/safety_summary.json"

step "sppo-enjoy --algo sppo --env SafePointCircle-v0 -n 100"
set +e
"$bin/sppo-enjoy" --algo sppo --env SafePointCircle-v0 -f logs --no-render -n 100 --device cpu "${short[@]}" >enjoy.log 2>&1
rc=$?
set -e
cat enjoy.log
[ "$rc" -eq 0 ] || fail "sppo-enjoy exited with $rc"
grep -q "Episode cost:" enjoy.log || fail "the enjoy output lacks the episodes' costs"

step "passed: the wheel trains and watches outside the checkout"
