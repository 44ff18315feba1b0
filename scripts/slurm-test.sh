#!/usr/bin/env bash
# shellcheck source-path=SCRIPTDIR
# biscale's sharded precompute on a real Slurm cluster: a private one-node cluster on
# loopback (scripts/lib/slurm.sh), brought up in a temporary folder and torn down on any exit.
#
#   bash scripts/slurm-test.sh                 the biscale test (CI runs it after the unit tests)
#   bash scripts/slurm-test.sh --cluster-only  the cluster alone: a tiny array job with one
#                                              failing task and a dependent job; for debugging
#                                              the cluster without biscale
#
# The biscale test:
#   a. `biscale run` of configs/tests/shard.toml on this machine: the reference;
#   b. `biscale shard plan` (4 shards) and `biscale shard sbatch`, then the generated submit.sh
#      with BISCALE_SHARD_FAIL=2, so that shard 2 fails: the merge job, which depends on the
#      whole array (afterok), can then never run; it is cancelled;
#   c. task 2 failed (its exit code and its log), tasks 0, 1 and 3 succeeded, `biscale shard
#      status` names shard 2 as incomplete, a local `biscale shard merge` refuses naming it;
#   d. index 2 alone is resubmitted (`sbatch --array=2 shards.sbatch`), then merge.sbatch;
#   e. the merged run's images and transfer cache are byte-identical to the reference's.
#
# Environment:
#   BISCALE                 the binary (default: target/debug/biscale, under CARGO_TARGET_DIR
#                           if set, brought up to date with cargo build first)
#   BISCALE_SKIP_SLURM=1    skip this test (ignored when CI is set: CI always runs it)
#   BISCALE_KEEP_SLURM_TMP=1  keep the temporary folder (cluster state and logs, outputs)
#   BISCALE_SLURM_TIMEOUT   seconds to wait for each job (default 300)
#
# Needs root (or sudo) once to install slurm-wlm and munge (scripts/lib/apt.sh); the cluster
# itself runs as the calling user (tested as root, as in CI).
set -euo pipefail
caller_pwd="$(pwd)"
cd "$(dirname "$0")/.."
repo="$(pwd)"

log() { echo "slurm-test: $*"; }
die() {
    echo "slurm-test: FAILED: $*" >&2
    exit 1
}

mode=biscale
case "${1:-}" in
    "") ;;
    --cluster-only) mode=cluster ;;
    -h | --help)
        sed -n '3,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
        exit 0
        ;;
    *)
        echo "usage: $0 [--cluster-only]" >&2
        exit 2
        ;;
esac

if [ "${BISCALE_SKIP_SLURM:-}" = 1 ]; then
    if [ -n "${CI:-}" ]; then
        log "BISCALE_SKIP_SLURM=1 is ignored in CI (CI is set): running"
    else
        log "skipped (BISCALE_SKIP_SLURM=1)"
        exit 0
    fi
fi

# The failure injection is for submit.sh alone; nothing else may inherit it from the caller.
unset BISCALE_SHARD_FAIL
JOB_TIMEOUT="${BISCALE_SLURM_TIMEOUT:-300}"

# shellcheck source=lib/apt.sh
source scripts/lib/apt.sh
# shellcheck source=lib/slurm.sh
source scripts/lib/slurm.sh

now() { date +%s.%N; }
# Seconds since a `now` timestamp, one decimal.
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.1f", b - a }'; }

tmp="$(mktemp -d -t biscale-slurm.XXXXXX)"
cluster_state=down  # down | failed (slurm_up printed the daemon logs) | up
JOBS=()             # every job submitted, for the diagnostics
JOB_LOG_DIRS=()     # folders holding the jobs' Slurm logs, for the diagnostics

# What a failure needs to be understood: the queue, the jobs, their Slurm logs, the daemons'
# logs.
diagnostics() {
    [ "$cluster_state" = up ] || [ ${#JOB_LOG_DIRS[@]} -gt 0 ] || return 0
    echo "slurm-test: ===== diagnostics =====" >&2
    if [ "$cluster_state" = up ]; then
        echo "----- squeue -t all -----" >&2
        squeue -t all -o '%.12i %.10T %.26r %.10M %j' >&2 || true
        local j
        for j in "${JOBS[@]}"; do
            echo "----- scontrol -o show job $j -----" >&2
            scontrol -o show job "$j" >&2 || true
        done
    fi
    local dir f
    for dir in "${JOB_LOG_DIRS[@]}"; do
        [ -d "$dir" ] || continue
        for f in "$dir"/*; do
            [ -f "$f" ] || continue
            echo "----- last 60 lines of Slurm log $f -----" >&2
            tail -n 60 "$f" >&2
        done
    done
    if [ "$cluster_state" = up ]; then
        slurm_logs 40
    fi
}

cleanup() {
    local rc=$?
    set +e
    trap - EXIT
    # The teardown must finish (it takes seconds at most): a second Ctrl-C is ignored, and
    # output to a closed pipe (`| head`) fails instead of killing the shell.
    trap '' INT TERM HUP PIPE
    [ "$rc" -eq 0 ] || diagnostics
    if [ "$cluster_state" != down ]; then
        log "stopping the cluster"
        slurm_down
    fi
    if [ "${BISCALE_KEEP_SLURM_TMP:-}" = 1 ]; then
        log "kept $tmp (BISCALE_KEEP_SLURM_TMP=1)"
    else
        rm -rf "$tmp"
    fi
    [ "$rc" -eq 0 ] || echo "slurm-test: failed (exit $rc)" >&2
    exit "$rc"
}
trap cleanup EXIT
# A signal ends the script through `exit`, so that the EXIT trap stops the daemons (bash
# runs no EXIT trap when a signal it does not trap kills it). PIPE: output piped into
# `head`, say, which has exited.
trap 'exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP
trap 'exit 141' PIPE

# Runs a command with its output in $tmp/logs/NAME.log; on failure prints the log's tail.
run_logged() {
    local name="$1"
    shift
    mkdir -p "$tmp/logs"
    if ! "$@" >"$tmp/logs/$name.log" 2>&1; then
        echo "----- last 60 lines of $tmp/logs/$name.log -----" >&2
        tail -n 60 "$tmp/logs/$name.log" >&2
        die "$name: $* exited non-zero"
    fi
}

# The job id of `sbatch --parsable` output ("ID" or "ID;CLUSTER").
job_id() {
    local id="${1%%;*}"
    [[ "$id" =~ ^[0-9]+$ ]] || die "not a job id: '$1'"
    echo "$id"
}

wait_jobs() {
    slurm_wait_jobs -t "$JOB_TIMEOUT" "$@" || die "jobs $* did not finish within ${JOB_TIMEOUT} s"
}

expect_task_ok() {
    local code
    code="$(slurm_task_exit "$1" "$2")" || die "no record of array task $1_$2"
    [ "$code" = 0:0 ] || die "array task $1_$2 exited $code ($(slurm_job_field "$1_$2" JobState)); expected 0:0"
    log "   task $1_$2: exit $code, as expected"
}

expect_task_failed() {
    local code state
    code="$(slurm_task_exit "$1" "$2")" || die "no record of array task $1_$2"
    state="$(slurm_job_field "$1_$2" JobState)"
    if [ "$code" = 0:0 ] || [ "$state" != FAILED ]; then
        die "array task $1_$2 exited $code ($state); expected a failure"
    fi
    log "   task $1_$2: exit $code ($state), as expected"
}

expect_job_ok() {
    local code
    code="$(slurm_job_exit "$1")" || die "no record of job $1"
    [ "$code" = 0:0 ] || die "job $1 exited $code ($(slurm_job_field "$1" JobState)); expected 0:0"
    log "   job $1: exit $code, as expected"
}

# A job that depends (afterok) on a failed one stays pending forever with reason
# DependencyNeverSatisfied (this Slurm does not cancel it by itself); wait for that reason
# (slurmctld sets it on a scheduling pass, about a second after the failure), then cancel it.
expect_never_satisfied() {
    local job="$1" reason="" state deadline=$((SECONDS + 30))
    while [ "$SECONDS" -lt "$deadline" ]; do
        reason="$(slurm_job_reason "$job")"
        [ "$reason" = DependencyNeverSatisfied ] && break
        # Empty: no longer pending (so it started although its dependency failed), unless
        # squeue failed for a moment.
        if [ -z "$reason" ]; then
            state="$(slurm_job_field "$job" JobState)" || state=""
            [ "$state" = PENDING ] ||
                die "job $job is $state, not pending; it should wait forever on its failed dependency"
        fi
        sleep 0.25
    done
    [ "$reason" = DependencyNeverSatisfied ] ||
        die "job $job is pending with reason '$reason' after 30 s; expected DependencyNeverSatisfied"
    log "   job $job: pending, DependencyNeverSatisfied, as expected; cancelling it"
    scancel "$job"
    deadline=$((SECONDS + 10))
    until [ "$(slurm_job_field "$job" JobState)" = CANCELLED ]; do
        [ "$SECONDS" -lt "$deadline" ] || die "job $job is not cancelled 10 s after scancel"
        sleep 0.2
    done
}

# The Slurm log files (stdout, and stderr where apart) of a job or array task.
job_log_files() {
    local out err
    out="$(slurm_job_field "$1" StdOut)"
    err="$(slurm_job_field "$1" StdErr)"
    echo "$out"
    [ -z "$err" ] || [ "$err" = "$out" ] || echo "$err"
}

# The failed task's log must say why: the logs found through scontrol's StdOut/StdErr.
expect_log_mentions() {
    local spec="$1" pattern="$2" f found=0 files
    files="$(job_log_files "$spec")"
    while read -r f; do
        if [ -z "$f" ] || [ ! -f "$f" ]; then continue; fi
        if grep -Eiq "$pattern" "$f"; then
            found=1
            log "   log of $spec ($f) says: $(grep -Ei "$pattern" "$f" | head -n 1)"
        fi
    done <<<"$files"
    [ "$found" = 1 ] || die "the Slurm log of $spec ($(echo "$files" | tr '\n' ' ')) does not match /$pattern/"
}

apt_ensure slurm-test slurm-wlm munge

bring_up() {
    log "bringing up a one-node Slurm cluster in $tmp/cluster"
    local t0
    t0="$(now)"
    cluster_state=failed
    slurm_up "$tmp/cluster" || die "the cluster did not come up (daemon logs above)"
    cluster_state=up
    T_UP="$(since "$t0")"
    log "cluster up in ${T_UP} s: node $SLURM_NODE, $(sinfo -h -o '%c CPUs, %m MB') (SLURM_CONF=$SLURM_CONF)"
}

# ---------------------------------------------------------------------------------------
# --cluster-only: the cluster alone, through the same checks as the biscale test.
cluster_selftest() {
    bring_up
    local d="$tmp/selftest" t0 array merge rerun i
    mkdir -p "$d/logs"
    JOB_LOG_DIRS+=("$d/logs")
    cd "$d"
    # The task fails when its index is in FAIL (exported by sbatch, like BISCALE_SHARD_FAIL).
    cat >task.sbatch <<'EOF'
#!/bin/bash
#SBATCH --job-name=selftest-task
echo "task $SLURM_ARRAY_TASK_ID of job $SLURM_ARRAY_JOB_ID on $(hostname)"
if [ "${FAIL:-}" = "$SLURM_ARRAY_TASK_ID" ]; then
    echo "error: task $SLURM_ARRAY_TASK_ID fails on purpose" >&2
    exit 3
fi
touch "done-$SLURM_ARRAY_TASK_ID"
EOF
    cat >merge.sbatch <<'EOF'
#!/bin/bash
#SBATCH --job-name=selftest-merge
for i in 0 1 2 3; do [ -f "done-$i" ] || { echo "error: task $i missing" >&2; exit 1; }; done
echo merged >merged
EOF

    log "submitting an array of 4 tasks (task 2 fails) and a job depending on it (afterok)"
    t0="$(now)"
    array="$(job_id "$(FAIL=2 sbatch --parsable --array=0-3 -o "$d/logs/task-%A_%a.out" task.sbatch)")"
    JOBS+=("$array")
    merge="$(job_id "$(sbatch --parsable --dependency="afterok:$array" -o "$d/logs/merge-%j.out" merge.sbatch)")"
    JOBS+=("$merge")
    wait_jobs "$array"
    T_ARRAY="$(since "$t0")"
    log "array job $array done in ${T_ARRAY} s"
    for i in 0 1 3; do expect_task_ok "$array" "$i"; done
    expect_task_failed "$array" 2
    expect_log_mentions "${array}_2" "fails on purpose"
    expect_never_satisfied "$merge"

    log "resubmitting task 2 alone"
    t0="$(now)"
    rerun="$(job_id "$(sbatch --parsable --array=2 -o "$d/logs/task-%A_%a.out" task.sbatch)")"
    JOBS+=("$rerun")
    wait_jobs "$rerun"
    T_RERUN="$(since "$t0")"
    expect_task_ok "$rerun" 2

    log "submitting the merge job (no dependency)"
    t0="$(now)"
    merge="$(job_id "$(sbatch --parsable -o "$d/logs/merge-%j.out" merge.sbatch)")"
    JOBS+=("$merge")
    wait_jobs "$merge"
    T_MERGE="$(since "$t0")"
    expect_job_ok "$merge"
    [ -f merged ] || die "the merge job left no 'merged' file"
    cd "$repo"

    log "summary: cluster bring-up ${T_UP} s, array job (4 tasks on $(nproc) CPUs) ${T_ARRAY} s, rerun of task 2 ${T_RERUN} s, merge job ${T_MERGE} s"
}

# ---------------------------------------------------------------------------------------
# The biscale test.
biscale_test() {
    local config="$repo/configs/tests/shard.toml"
    [ -f "$config" ] || die "$config not found"

    if [ -n "${BISCALE:-}" ]; then
        # A relative BISCALE is relative to the caller's working folder.
        case "$BISCALE" in /*) ;; *) BISCALE="$caller_pwd/$BISCALE" ;; esac
    else
        BISCALE="${CARGO_TARGET_DIR:-target}/debug/biscale"
        # A no-op when the binary is up to date (after scripts/test.sh it is).
        log "cargo build -p biscale-cli --locked --bin biscale"
        cargo build -p biscale-cli --locked --bin biscale
    fi
    [ -x "$BISCALE" ] || die "BISCALE=$BISCALE is not an executable file"
    # Absolute, since everything below runs in $tmp/work; and first on PATH, for the
    # generated batch scripts whichever way they name the binary (sbatch exports PATH).
    BISCALE="$(cd "$(dirname "$BISCALE")" && pwd)/$(basename "$BISCALE")"
    PATH="$(dirname "$BISCALE"):$PATH"
    export PATH
    log "using $BISCALE"

    bring_up

    # Everything runs from a scratch folder (as on a cluster, where jobs start in the
    # submission folder): nothing may depend on the repository being the working folder,
    # and nothing (a default out/ or .cache) lands in the repository.
    local work="$tmp/work" shards="$tmp/shards" t0 out
    local manifest="$tmp/shards/manifest.json" slurm_dir="$tmp/shards/slurm"
    mkdir -p "$work"
    cd "$work"

    # a. The reference.
    log "a. single-machine run: biscale run $config"
    t0="$(now)"
    run_logged single "$BISCALE" run "$config" --out "$tmp/single" --cache-dir "$tmp/cache-single"
    T_SINGLE="$(since "$t0")"
    log "   done in ${T_SINGLE} s"

    # b. Plan, batch scripts, submission with shard 2 failing.
    log "b. biscale shard plan --shards 4"
    run_logged plan "$BISCALE" shard plan "$config" --shards 4 --out "$shards"
    [ -f "$manifest" ] || die "biscale shard plan wrote no $manifest"
    log "   biscale shard sbatch"
    run_logged sbatch "$BISCALE" shard sbatch "$manifest" --cpus 1 --time 10 --mem 1G \
        --out "$tmp/merged" --cache-dir "$tmp/cache-merged"
    local f
    for f in shards.sbatch merge.sbatch submit.sh; do
        [ -f "$slurm_dir/$f" ] || die "biscale shard sbatch wrote no $slurm_dir/$f"
    done
    JOB_LOG_DIRS+=("$slurm_dir/logs")

    log "   BISCALE_SHARD_FAIL=2 bash $slurm_dir/submit.sh"
    t0="$(now)"
    out="$(BISCALE_SHARD_FAIL=2 bash "$slurm_dir/submit.sh")" || die "submit.sh failed: $out"
    echo "$out" | sed 's/^/slurm-test:   submit.sh: /'
    # Exactly two lines, "shards <jobid>" and "merge <jobid>".
    [ "$(echo "$out" | wc -l)" = 2 ] || die "submit.sh printed $(echo "$out" | wc -l) lines; expected 2"
    local array merge rerun
    array="$(job_id "$(echo "$out" | awk '$1 == "shards" { print $2 }')")"
    merge="$(job_id "$(echo "$out" | awk '$1 == "merge" { print $2 }')")"
    JOBS+=("$array" "$merge")
    wait_jobs "$array"
    T_ARRAY="$(since "$t0")"
    log "   array job $array done in ${T_ARRAY} s"

    # c. Shard 2 failed, and everything downstream says so.
    log "c. shard 2 failed, the others succeeded; the merge job waits forever"
    for f in 0 1 3; do expect_task_ok "$array" "$f"; done
    expect_task_failed "$array" 2
    expect_log_mentions "${array}_2" "error|fail|panic"
    expect_never_satisfied "$merge"

    log "   biscale shard status (expects shard 2 incomplete, exit non-zero)"
    if out="$("$BISCALE" shard status "$manifest" 2>&1)"; then
        echo "$out" >&2
        die "biscale shard status exited 0 with shard 2 missing"
    fi
    echo "$out" | sed 's/^/slurm-test:   status: /'
    echo "$out" | grep -E 'shard 2([^0-9]|$)' | grep -Eq 'missing|stale|corrupt' ||
        die "biscale shard status has no line naming shard 2 missing, stale or corrupt"
    for f in 0 1 3; do
        if echo "$out" | grep -E "shard $f([^0-9]|\$)" | grep -Eq 'missing|stale|corrupt'; then
            die "biscale shard status reports the completed shard $f incomplete"
        fi
    done

    log "   biscale shard merge on this machine (expects a refusal naming shard 2)"
    if out="$("$BISCALE" shard merge "$manifest" --out "$tmp/merge-refused" \
        --cache-dir "$tmp/cache-refused" 2>&1)"; then
        echo "$out" >&2
        die "biscale shard merge succeeded with shard 2 missing"
    fi
    echo "$out" | tail -n 5 | sed 's/^/slurm-test:   merge: /'
    echo "$out" | grep -Eq 'shard 2([^0-9]|$)' || die "biscale shard merge's refusal does not name shard 2"

    # d. Rerun index 2 alone (without the failure injection), then the merge job.
    log "d. rerun of shard 2: sbatch --array=2 shards.sbatch"
    t0="$(now)"
    rerun="$(job_id "$(sbatch --parsable --array=2 "$slurm_dir/shards.sbatch")")"
    JOBS+=("$rerun")
    wait_jobs "$rerun"
    T_RERUN="$(since "$t0")"
    expect_task_ok "$rerun" 2
    run_logged status-after-rerun "$BISCALE" shard status "$manifest"
    log "   biscale shard status: every shard complete"

    log "   sbatch merge.sbatch"
    t0="$(now)"
    merge="$(job_id "$(sbatch --parsable "$slurm_dir/merge.sbatch")")"
    JOBS+=("$merge")
    wait_jobs "$merge"
    T_MERGE="$(since "$t0")"
    expect_job_ok "$merge"
    log "   merge job $merge done in ${T_MERGE} s"

    # e. Byte for byte against the reference.
    log "e. comparing $tmp/merged with the single-machine run"
    [ -d "$tmp/single/images" ] || die "the single-machine run wrote no images/"
    [ -d "$tmp/merged/images" ] || die "the merged run wrote no images/"
    local names_single names_merged n=0 rel
    names_single="$(cd "$tmp/single/images" && find . -type f | sort)"
    names_merged="$(cd "$tmp/merged/images" && find . -type f | sort)"
    [ -n "$names_single" ] || die "the single-machine run's images/ is empty"
    if [ "$names_single" != "$names_merged" ]; then
        diff <(echo "$names_single") <(echo "$names_merged") >&2 || true
        die "images/ holds different files (diff of the names above: < single, > merged)"
    fi
    while read -r rel; do
        cmp "$tmp/single/images/$rel" "$tmp/merged/images/$rel" >&2 ||
            die "images/${rel#./} differs between the single-machine and the merged run"
        n=$((n + 1))
    done <<<"$names_single"
    log "   $n image(s) identical"

    local transfers=0 name
    for f in "$tmp/cache-single"/transfer*; do
        [ -f "$f" ] || continue
        name="$(basename "$f")"
        [ -f "$tmp/cache-merged/$name" ] || die "the merged cache has no $name"
        cmp "$f" "$tmp/cache-merged/$name" >&2 || die "cache file $name differs"
        transfers=$((transfers + 1))
    done
    [ "$transfers" -gt 0 ] || die "the single-machine run's cache ($tmp/cache-single) has no transfer* file"
    for f in "$tmp/cache-merged"/transfer*; do
        [ -f "$f" ] || continue
        [ -f "$tmp/cache-single/$(basename "$f")" ] ||
            die "the merged cache has $(basename "$f"), the single-machine run's has not"
    done
    log "   $transfers transfer cache file(s) identical"
    cd "$repo"

    log "summary: cluster bring-up ${T_UP} s, single-machine run ${T_SINGLE} s, array job (4 shards, shard 2 failing) ${T_ARRAY} s, rerun of shard 2 ${T_RERUN} s, merge job ${T_MERGE} s"
}

T_UP="" T_ARRAY="" T_RERUN="" T_MERGE="" T_SINGLE=""
if [ "$mode" = cluster ]; then
    cluster_selftest
else
    biscale_test
fi
log "ok"
