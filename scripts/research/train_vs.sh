#!/usr/bin/env bash
# Start or resume every training run of the visual-servoing RL plan (docs/research/visual_servo_rl.md),
# idempotently: re-running it later (another session, after a reboot) carries on where the runs
# stopped. Each run is an ordinary `cir-gym train` run under $VS_RUNS (default
# /work/main/runs/rl, gitignored) in <Env-vN>/<algo>/seed_<k>/, checkpointed every 100k steps
# (agents/hyperparams/vs/*.yml); its config.yml records the command that retrains it.
#
#   scripts/research/train_vs.sh            # start the driver unless it is running
#   scripts/research/train_vs.sh status     # progress of every run, the queues' PIDs
#   scripts/research/train_vs.sh stop       # SIGTERM everything (trainings checkpoint)
#
# Everything runs in one background driver (setsid nohup nice 19, one torch/OMP thread): one
# session, so with the kernel's autogroup scheduling (on here) the plan takes one session's
# share of the machine, not one per process; its processes run at nice 19 inside it.
# Stage 0: the Optuna study (scripts/research/optimize_vs.py) until STUDY_TRIALS trials are
# complete; its best trial is written to agents/hyperparams/vs/ppo_study.yml, which every PPO
# run uses (commit that file). Then a queue per environment (side by side) that trains
# their runs one after the other: a finished run (meta.json "finished": true) is skipped, a
# started one resumes from its last checkpoint (`--resume`), a run directory without a
# checkpoint (stopped in its first 100k steps) starts over. Order: PPO seeds 0-4 (PPO takes
# ~20x the env steps per CPU second of SAC here), then the off-policy seeds 0-4. VS_ENVS
# picks the queues (default both envs); VS_PPO_STEPS (default: each env's own, ppo_budget)
# and VS_SAC_STEPS the budgets.
# A driver whose PID file names a live process is left alone.
# CPU time: each training session appends "wall user sys" seconds to <run>.time in
# $VS_RUNS/logs/ (GNU time), so the budget is stated in CPU hours as well as env steps.
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT="${VS_RUNS:-/work/main/runs/rl}"
LOGS="$ROOT/logs"
# the plan; the VS_* variables override it (a smoke test of this script: tiny budgets)
PPO_STEPS="${VS_PPO_STEPS:-}"  # empty: each env's own budget (ppo_budget)
SAC_STEPS="${VS_SAC_STEPS:-500000}"
SEEDS_REST="${VS_SEEDS_REST-1 2 3 4}"
ENVS="${VS_ENVS:-cir_gym/VisualServo-v1 cir_gym/VisualServoEyeToHand-v1}"  # one queue each
PPO_HP="${VS_PPO_HP:-agents/hyperparams/vs/ppo_study.yml}"  # the study's best trial
STUDY_WORKERS=3     # one process each, sharing the sqlite study
STUDY_TRIALS=4      # complete trials before the best is adopted (the hand recipe among them)
STUDY_STEPS=120000  # env steps per trial
mkdir -p "$LOGS"

# Stage 0: the Optuna study until STUDY_TRIALS trials are complete, then its best trial is
# written to $PPO_HP.
study_stage() {
    local w
    for w in $(seq 0 $((STUDY_WORKERS - 1))); do
        python scripts/research/optimize_vs.py run --total "$STUDY_TRIALS" --trials 100 \
            --wall 1e9 --timesteps "$STUDY_STEPS" --worker "$w" \
            >> "$ROOT/study/logs/worker_$w.log" 2>&1 &
    done
    wait
    python scripts/research/optimize_vs.py best --write "$PPO_HP" >> "$LOGS/queue.log" 2>&1
}

# PPO env steps per run: eye-to-hand 1 M (its seed 0 succeeded from 0.3 M on), eye-in-hand 3 M
ppo_budget() {  # env_id
    if [[ -n "$PPO_STEPS" ]]; then echo "$PPO_STEPS"
    elif [[ "$1" == *EyeToHand* ]]; then echo 1000000
    else echo 3000000; fi
}

# one queue's runs: "env_id algo seed timesteps hyperparameter_file"
queue_runs() {
    local env_id="$1"
    for k in 0 $SEEDS_REST; do echo "$env_id ppo $k $(ppo_budget "$env_id") $PPO_HP"; done
    for k in 0 $SEEDS_REST; do echo "$env_id sac $k $SAC_STEPS agents/hyperparams/vs/sac.yml"; done
}

run_dir() {  # env_id algo seed
    echo "$ROOT/${1#cir_gym/}/$2/seed_$3"
}

finished() {  # run_dir
    [[ -f "$1/meta.json" ]] && grep -q '"finished": true' "$1/meta.json"
}

train_one() {  # env_id algo seed timesteps hyperparameter_file
    local env_id="$1" algo="$2" seed="$3" steps="$4" hp="$5"
    local dir tag resume=()
    dir="$(run_dir "$env_id" "$algo" "$seed")"
    tag="${env_id#cir_gym/}_${algo}_seed${seed}"
    if finished "$dir"; then
        return 0
    fi
    if [[ -f "$dir/config.yml" ]]; then
        if compgen -G "$dir/checkpoints/model_*_steps.zip" > /dev/null; then
            resume=(--resume)
        else  # stopped before its first checkpoint: nothing to keep
            rm -rf "$dir"
        fi
    fi
    echo "$(date -u +%FT%TZ) start $tag ${resume[*]:-}" >> "$LOGS/queue.log"
    /usr/bin/time -a -o "$LOGS/$tag.time" -f "%e %U %S" \
        cir-gym train --env "$env_id" --algo "$algo" --seed "$seed" --timesteps "$steps" \
        --name "$algo/seed_$seed" --out "$ROOT" --hyperparams "$hp" "${resume[@]}" \
        >> "$LOGS/$tag.log" 2>&1 || echo "$(date -u +%FT%TZ) $tag exited $?" >> "$LOGS/queue.log"
}

run_queue() {  # env_id
    local line
    while read -r line; do
        # shellcheck disable=SC2086
        train_one $line
    done < <(queue_runs "$1")
    echo "$(date -u +%FT%TZ) queue ${1#cir_gym/} done" >> "$LOGS/queue.log"
}

driver() {  # the study if no trial is adopted yet, then both queues side by side
    if [[ ! -f "$PPO_HP" ]]; then
        mkdir -p "$ROOT/study/logs"
        study_stage
    fi
    [[ -f "$PPO_HP" ]] || { echo "$(date -u +%FT%TZ) no adopted trial" >> "$LOGS/queue.log"; exit 1; }
    local env_id
    for env_id in $ENVS; do run_queue "$env_id" & done
    wait
}

alive() {  # pid file
    [[ -f "$1" ]] && kill -0 "$(cat "$1")" 2> /dev/null
}

status() {
    local env_id line dir
    if alive "$LOGS/driver.pid"; then echo "driver: running, PID $(cat "$LOGS/driver.pid")"
    else echo "driver: not running"; fi
    if [[ -f "$PPO_HP" ]]; then echo "study adopted: $PPO_HP"; else echo "study: not adopted"; fi
    for env_id in $ENVS; do
        echo "${env_id#cir_gym/}:"
        while read -r line; do
            # shellcheck disable=SC2086
            set -- $line
            dir="$(run_dir "$1" "$2" "$3")"
            if finished "$dir"; then state="finished"
            elif [[ -d "$dir" ]]; then
                state="started, last checkpoint: $(ls "$dir/checkpoints" 2> /dev/null \
                    | sed -n 's/^model_\([0-9]*\)_steps.zip$/\1/p' | sort -n | tail -1)"
            else state="not started"; fi
            echo "  $2 seed $3 ($4 steps): $state"
        done < <(queue_runs "$env_id")
    done
}

pid_file="$LOGS/driver.pid"
case "${1:-start}" in
    status) status ;;
    stop)  # the driver is a process group of its own (setsid): every shell, GNU time and
        # training gets SIGTERM; a training checkpoints before it exits
        if alive "$pid_file"; then kill -TERM -- "-$(cat "$pid_file")"; fi ;;
    start)
        if alive "$pid_file"; then echo "already running (PID $(cat "$pid_file"))"; exit 0; fi
        . .venv/bin/activate
        export MUJOCO_GL="${MUJOCO_GL:-egl}" OMP_NUM_THREADS=1
        setsid nohup nice -n 19 bash -c "$(declare -f study_stage ppo_budget queue_runs run_dir finished \
            train_one run_queue driver); ROOT='$ROOT' LOGS='$LOGS' PPO_STEPS='$PPO_STEPS' \
            SAC_STEPS=$SAC_STEPS SEEDS_REST='$SEEDS_REST' PPO_HP='$PPO_HP' ENVS='$ENVS' \
            STUDY_WORKERS=$STUDY_WORKERS STUDY_TRIALS=$STUDY_TRIALS STUDY_STEPS=$STUDY_STEPS; \
            driver" > /dev/null 2>&1 &
        echo $! > "$pid_file"
        echo "started (PID $!): $([[ -f "$PPO_HP" ]] && echo queues || echo "study, then queues")" ;;
    *) echo "usage: $0 [start|status|stop]" >&2; exit 2 ;;
esac
