#!/usr/bin/env bash
# rl-zoo3's own hyperparameter search (Optuna: rl-zoo3's PPO sampler, multivariate TPE seeded
# by --seed, median pruner) on JointTracking-v2 with the agent at 100 Hz; the study is saved in
# results/tuning/zoo_optuna/<study>.db (results/tuning/zoo_optuna/README.md has the results).
#
#   scripts/zoo_optimize.sh [STUDY_NAME] [WALL_SECONDS]
#
# The fixed part of every trial is agents/hyperparams/zoo/ppo_100hz.yml (it says why not
# ppo.yml). Sized for the 2-core machine with two other trainings beside it: 100k steps per
# trial (a trial took 0.4-16 min there: mostly gradient steps, 100k x n_epochs / batch_size),
# 12 trials, the first 5 random (TPE's and the pruner's startup), 4 evaluations of 3 episodes
# per trial. In 40 min it finished 7 (results/tuning/zoo_optuna/README.md).
# WALL_SECONDS (default 2400) stops the search with SIGINT: rl-zoo3 then marks the running trial
# FAIL, keeps the finished ones and still writes its report. Re-running with the same name
# resumes the study (load_if_exists) and adds --n-trials more.
# Retrain a trial with rl-zoo3 itself: add `--storage ... --study-name ... --trial-id N` to a
# plain `python -m rl_zoo3.train` run on the same --conf-file (without -optimize).
set -euo pipefail
cd "$(dirname "$0")/.."
STUDY="${1:-jointtracking_100hz_ppo}"
WALL="${2:-2400}"
LOG="${ZOO_LOG_FOLDER:-/tmp/zoo_optimize}"
export MUJOCO_GL="${MUJOCO_GL:-egl}" OMP_NUM_THREADS=1
mkdir -p results/tuning/zoo_optuna "$LOG"
exec timeout -s INT "$WALL" nice -n 5 python -m rl_zoo3.train \
    --algo ppo --env cir_gym/JointTracking-v2 --gym-packages cir_gym \
    --conf-file agents/hyperparams/zoo/ppo_100hz.yml \
    --env-kwargs control_freq:100.0 \
    --vec-env dummy --num-threads 1 --seed 0 \
    -optimize --n-trials 12 --n-jobs 1 --sampler tpe --pruner median --n-startup-trials 5 \
    --n-timesteps 100000 --n-evaluations 4 --eval-episodes 3 \
    --storage "sqlite:///results/tuning/zoo_optuna/${STUDY}.db" --study-name "$STUDY" \
    --log-folder "$LOG" --no-optim-plots
