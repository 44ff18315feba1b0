# Sourced: a private one-node Slurm cluster on loopback, for tests (scripts/slurm-test.sh).
# Needs the Debian packages slurm-wlm and munge (Slurm 22.05 on Debian 12); touches nothing
# of the system's own Slurm or munge (/etc/slurm, /etc/munge, /run/munge): every daemon and
# client is pointed at a private slurm.conf with SLURM_CONF, and every path is under DIR.
#
#   slurm_up DIR                 bring up munged, slurmctld and slurmd with state under DIR
#                                (created if missing); exports SLURM_CONF, sets SLURM_PIDS
#                                (munged slurmctld slurmd), SLURM_DIR, SLURM_NODE. Returns
#                                non-zero (after printing the daemon logs' tails) if the
#                                cluster does not come up within SLURM_UP_TIMEOUT (30) s.
#   slurm_down                   cancel every job, stop the daemons started by slurm_up, by
#                                PID (TERM, up to 5 s, then KILL). Idempotent; call it from
#                                the caller's EXIT trap (this file sets no traps).
#   slurm_logs [LINES]           the last LINES (40) lines of each daemon log, on stderr.
#   slurm_wait_jobs [-t SECONDS] JOBID...
#                                poll squeue until none of the jobs (an array job id covers
#                                all its tasks) can still run: every one finished, or pending
#                                with reason DependencyNeverSatisfied (which never changes on
#                                its own; the caller decides: scancel it). Non-zero on timeout
#                                (default 300 s). (The timeout is an option, not a trailing
#                                argument: a job id and a number of seconds look alike.)
#   slurm_job_field JOBSPEC KEY  one KEY=value field of `scontrol -o show job JOBSPEC`
#                                (JOBSPEC: 123 or 123_4 for one array task).
#   slurm_task_exit JOBID INDEX  ExitCode (N:M: exit status, signal) of one array task.
#   slurm_job_exit JOBID         ExitCode of a job.
#   slurm_job_reason JOBID       squeue's reason (%r) of a pending job, e.g. Dependency,
#                                DependencyNeverSatisfied; empty once the job left the queue.
#
# Settled facts for Slurm 22.05 / munge 0.5.15 that shaped this (see the comments below):
# munged refuses a socket directory other users cannot enter (0700), so its socket lives in
# a 0755 directory apart from the 0700 key directory (and --force lets it accept a 0700
# ancestor); slurm.conf's AuthInfo=socket=... points Slurm at that socket; finished jobs stay visible to scontrol
# and squeue for MinJobAge seconds, which is where exit codes are read from since there is
# no accounting database (no sacct); `sbatch --wait` polls slowly, so jobs are waited for by
# polling squeue.

SLURM_PIDS=()
SLURM_DIR=""
SLURM_NODE=""

# Ports for slurmctld and slurmd: free ones (nothing bound to them in /proc/net/tcp{,6}),
# below the kernel's ephemeral range so an outgoing connection cannot take them meanwhile.
_slurm_free_ports() {
    local n="$1" used=" " p out=() tries=0 f addr
    for f in /proc/net/tcp /proc/net/tcp6; do
        [ -r "$f" ] || continue
        # Column 2 is local_address, ADDR:PORT in hex.
        while read -r _ addr _; do
            used+="$((16#${addr##*:})) "
        done < <(tail -n +2 "$f")
    done
    while [ ${#out[@]} -lt "$n" ]; do
        tries=$((tries + 1))
        [ "$tries" -le 1000 ] || return 1
        p=$((20000 + RANDOM % 12000))
        case "$used" in *" $p "*) continue ;; esac
        case " ${out[*]} " in *" $p "*) continue ;; esac
        out+=("$p")
    done
    echo "${out[@]}"
}

# True while the process PID exists and is not a zombie (a daemon that died but that the
# shell has not reaped yet still answers `kill -0`).
_slurm_alive() {
    local state
    state=$(awk '{ print $3 }' "/proc/$1/stat" 2>/dev/null) || return 1
    [ -n "$state" ] && [ "$state" != Z ]
}

# Fails when one of the daemons started so far has exited.
_slurm_check_daemons() {
    local pid
    for pid in "${SLURM_PIDS[@]}"; do
        if ! _slurm_alive "$pid"; then
            echo "slurm: daemon $pid ($(_slurm_pid_name "$pid")) exited" >&2
            return 1
        fi
    done
}

_slurm_pid_name() {
    case "$1" in
        "${SLURM_PIDS[0]:-}") echo munged ;;
        "${SLURM_PIDS[1]:-}") echo slurmctld ;;
        "${SLURM_PIDS[2]:-}") echo slurmd ;;
        *) echo "?" ;;
    esac
}

# Runs "$@" every 0.2 s until it succeeds (0), or fails (1) once TIMEOUT seconds have passed
# or a daemon has died.
_slurm_poll() {
    local timeout="$1" what="$2"
    shift 2
    local deadline=$((SECONDS + timeout))
    until "$@" >/dev/null 2>&1; do
        _slurm_check_daemons || return 1
        if [ "$SECONDS" -ge "$deadline" ]; then
            echo "slurm: timed out after ${timeout} s waiting for $what" >&2
            return 1
        fi
        sleep 0.2
    done
}

_slurm_munge_ok() {
    munge -n -S "$SLURM_DIR/munge-run/munge.socket" | unmunge -S "$SLURM_DIR/munge-run/munge.socket"
}
_slurm_ctld_ok() { scontrol ping | grep -q "is UP"; }
_slurm_node_idle() { [ "$(sinfo -h -N -n "$SLURM_NODE" -o %T)" = idle ]; }

slurm_logs() {
    local lines="${1:-40}" f
    for f in munged.log slurmctld.log slurmd.log; do
        if [ -z "$SLURM_DIR" ] || [ ! -f "$SLURM_DIR/log/$f" ]; then continue; fi
        echo "----- last $lines lines of $SLURM_DIR/log/$f -----" >&2
        tail -n "$lines" "$SLURM_DIR/log/$f" >&2
    done
}

slurm_up() {
    local dir="$1" timeout="${SLURM_UP_TIMEOUT:-30}"
    if [ ${#SLURM_PIDS[@]} -gt 0 ]; then
        echo "slurm: a cluster is already up (pids ${SLURM_PIDS[*]})" >&2
        return 1
    fi
    local cmd
    for cmd in munged mungekey munge unmunge slurmctld slurmd scontrol sinfo squeue sbatch scancel setsid; do
        command -v "$cmd" >/dev/null 2>&1 || {
            echo "slurm: $cmd not found (Debian packages slurm-wlm and munge)" >&2
            return 1
        }
    done
    mkdir -p "$dir" || return 1
    SLURM_DIR="$(cd "$dir" && pwd)"
    local d="$SLURM_DIR"
    mkdir -p "$d/munge-key" "$d/munge-run" "$d/log" "$d/state" "$d/spool" "$d/run" || return 1
    # munged checks ownership and modes: the key stays private (0600 in a 0700 directory);
    # the socket's directory must be enterable by everyone (munged refuses a 0700 one, since
    # clients of any user connect to it), hence two directories.
    chmod 0700 "$d/munge-key"
    chmod 0755 "$d/munge-run"
    # `mungekey` (munge >= 0.5.14) writes a random key, mode 0600, owned by the caller;
    # --force replaces the key of an earlier cluster in the same DIR.
    mungekey --create --force --keyfile="$d/munge-key/munge.key" || return 1

    # The node is this machine under its short host name, which is also the controller's
    # name: slurmctld only runs on a host whose name matches SlurmctldHost. Addresses are
    # given literally (SlurmctldHost=name(ADDR), NodeAddr) so that nothing has to resolve.
    local host user cpus mem_kb mem ports ctld_port slurmd_port
    host="$(hostname -s)"
    SLURM_NODE="$host"
    user="$(id -un)"
    cpus="$(nproc)"
    mem_kb="$(awk '/^MemTotal:/ { print $2 }' /proc/meminfo)"
    # A little under the total: a node whose RealMemory exceeds what slurmd finds is drained.
    mem=$((mem_kb / 1024 * 95 / 100))
    ports="$(_slurm_free_ports 2)" || { echo "slurm: found no free ports" >&2; return 1; }
    read -r ctld_port slurmd_port <<<"$ports"

    # Bind the daemons to loopback, not to every address, where the host name resolves to a
    # loopback address: with these flags each daemon binds to the address its host name
    # resolves to (not to the one slurm.conf names), so that address is the one to name:
    # 127.0.1.1 on a stock Debian /etc/hosts, where 127.0.0.1 would be refused. Elsewhere
    # (a name resolving to another address, or to nothing) the daemons listen on every
    # address and are reached on 127.0.0.1.
    local addr=127.0.0.1 resolved comm_params="#CommunicationParameters= (host name does not resolve to 127.x)"
    resolved="$(getent ahostsv4 "$(hostname)" 2>/dev/null | awk 'NR == 1 { print $1 }')" || resolved=""
    case "$resolved" in
        127.*)
            addr="$resolved"
            comm_params="CommunicationParameters=NoCtldInAddrAny,NoInAddrAny"
            ;;
    esac

    cat >"$d/slurm.conf" <<EOF
# Private one-node test cluster written by scripts/lib/slurm.sh; every path under $d.
ClusterName=biscale-test
SlurmctldHost=$host($addr)
# Whoever runs the test owns the daemons (root in CI); jobs then run as that user.
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
$comm_params
AuthType=auth/munge
CredType=cred/munge
# The private munged's socket, for the daemons, the clients and slurmstepd.
AuthInfo=socket=$d/munge-run/munge.socket
StateSaveLocation=$d/state
SlurmdSpoolDir=$d/spool
SlurmctldPidFile=$d/run/slurmctld.pid
SlurmdPidFile=$d/run/slurmd.pid
SlurmctldLogFile=$d/log/slurmctld.log
SlurmdLogFile=$d/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
# No plugins found in /etc/slurm/plugstack.conf.d may join in.
PlugStackConfig=$d/plugstack.conf
# Neither cgroups nor CPU binding: a container or a CI VM may not delegate cgroups, and
# the test needs neither. linuxproc tracks a job's processes by parentage.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
# One CPU per 1-CPU task (CR_Core would hand out whole cores); memory not consumable, so
# --mem is only checked against RealMemory.
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
# Schedule a submitted batch job at once instead of deferring it to the next pass.
SchedulerParameters=batch_sched_delay=0
# No slurmdbd: no accounting (hence no sacct; exit codes come from scontrol), no job log.
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
MailProg=/bin/true
# Finished jobs stay in slurmctld's memory (scontrol show job, squeue -j) for 10 minutes:
# long enough for the test to read their exit codes.
MinJobAge=600
# scancel/timeout: SIGKILL 5 s after SIGTERM (default 30 s) so teardown is quick.
KillWait=5
# The node becomes idle as soon as slurmd registers, even after an unclean stop.
ReturnToService=2
# Trust the node line below; never drain the node because the hardware count differs
# (nproc may count fewer CPUs than slurmd finds when an affinity mask limits this process).
SlurmdParameters=config_overrides
NodeName=$host NodeAddr=$addr NodeHostname=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
    : >"$d/plugstack.conf"
    export SLURM_CONF="$d/slurm.conf"

    # The daemons run in a session of their own: a Ctrl-C in the terminal (SIGINT to the
    # foreground process group) must reach the caller only, whose trap then cancels the jobs
    # through a still running slurmd before stopping the daemons. (slurmd and slurmstepd
    # handle SIGINT themselves, so the shell's ignoring it for background commands does not
    # protect them; stopped first, they would orphan the jobs' processes.) setsid(1) forks
    # only when it is a process group leader, which a background command is only under job
    # control (an interactive shell): there the daemon has a group of its own anyway, and
    # without the fork $! is the daemon's PID.
    local bg=()
    case "$-" in *m*) ;; *) bg=(setsid) ;; esac

    # munged: its own key, socket, pid, log and seed files. --force: munged also checks the
    # socket directory's ancestors, and refuses one that not everyone can enter, such as a
    # 0700 folder from mktemp -d; with --force that is only a warning in its log ("Socket is
    # inaccessible"). (munge 0.5.15 runs as root without --force.) -F keeps it in the
    # foreground, so that $! is its PID.
    "${bg[@]}" munged -F --force --key-file="$d/munge-key/munge.key" \
        --socket="$d/munge-run/munge.socket" --pid-file="$d/run/munged.pid" \
        --log-file="$d/log/munged.log" --seed-file="$d/munge-key/munged.seed" \
        >>"$d/log/munged.log" 2>&1 &
    SLURM_PIDS+=("$!")
    if ! _slurm_poll "$timeout" "munged" _slurm_munge_ok; then
        slurm_logs
        return 1
    fi

    # -D: stay in the foreground ($! is the daemon's PID); -i: ignore saved state (there is
    # none; a restart would otherwise try to recover old jobs).
    "${bg[@]}" slurmctld -D -i >>"$d/log/slurmctld.stdout" 2>&1 &
    SLURM_PIDS+=("$!")
    if ! _slurm_poll "$timeout" "slurmctld (scontrol ping)" _slurm_ctld_ok; then
        slurm_logs
        return 1
    fi
    "${bg[@]}" slurmd -D -N "$host" >>"$d/log/slurmd.stdout" 2>&1 &
    SLURM_PIDS+=("$!")
    if ! _slurm_poll "$timeout" "node $host to be idle (sinfo)" _slurm_node_idle; then
        sinfo -N -l >&2 || true
        scontrol show node "$host" >&2 || true
        slurm_logs
        return 1
    fi
}

# Every job this cluster still has, cancelled, so that no slurmstepd or job process
# outlives the daemons; then the daemons, by PID, newest first.
slurm_down() {
    [ ${#SLURM_PIDS[@]} -gt 0 ] || return 0
    local jobs pid i
    if [ ${#SLURM_PIDS[@]} -ge 2 ] && _slurm_alive "${SLURM_PIDS[1]}"; then
        jobs="$(squeue -h -o %A 2>/dev/null | sort -u | tr '\n' ' ')" || jobs=""
        if [ -n "${jobs// /}" ]; then
            # shellcheck disable=SC2086 # a list of job ids
            scancel $jobs 2>/dev/null || true
            for _ in $(seq 1 50); do
                [ -z "$(squeue -h -t PD,R,CG,CF,S -o %A 2>/dev/null)" ] && break
                sleep 0.2
            done
        fi
    fi
    # Steps that did not end with their job (slurmstepd detaches from slurmd), found by the
    # SLURM_CONF they inherited from this cluster's slurmd.
    _slurm_sweep slurmstepd
    for ((i = ${#SLURM_PIDS[@]} - 1; i >= 0; i--)); do
        pid="${SLURM_PIDS[$i]}"
        _slurm_alive "$pid" || continue
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 25); do
            _slurm_alive "$pid" || break
            sleep 0.2
        done
        if _slurm_alive "$pid"; then
            echo "slurm: $(_slurm_pid_name "$pid") ($pid) ignored SIGTERM; killing it" >&2
            kill -9 "$pid" 2>/dev/null || true
        fi
        wait "$pid" 2>/dev/null || true
    done
    # Job processes left behind if slurmd died before the jobs were cancelled: found by
    # their environment (this cluster's SLURM_CONF, exported by sbatch, and the job id and
    # cluster name Slurm sets), which nothing outside this cluster's jobs has.
    _slurm_sweep job
    SLURM_PIDS=()
}

# Kills (-9, by PID) this cluster's leftover slurmstepd processes (KIND slurmstepd) or job
# processes (KIND job).
_slurm_sweep() {
    local kind="$1" p pid env
    [ -n "$SLURM_DIR" ] || return 0
    for p in /proc/[0-9]*; do
        pid="${p#/proc/}"
        if [ "$pid" = "$$" ] || [ "$pid" = "${BASHPID:-$$}" ]; then continue; fi
        if [ "$kind" = slurmstepd ]; then
            [ "$(cat "$p/comm" 2>/dev/null)" = slurmstepd ] || continue
        fi
        # The process may be gone, or exiting (its environ unreadable), meanwhile.
        env="$({ tr '\0' '\n' <"$p/environ"; } 2>/dev/null)" || continue
        grep -qxF "SLURM_CONF=$SLURM_DIR/slurm.conf" <<<"$env" || continue
        if [ "$kind" = job ]; then
            grep -q '^SLURM_JOB_ID=' <<<"$env" || continue
            grep -qx 'SLURM_CLUSTER_NAME=biscale-test' <<<"$env" || continue
        fi
        echo "slurm: killing leftover $kind process $pid ($(cat "$p/comm" 2>/dev/null))" >&2
        kill -9 "$pid" 2>/dev/null || true
    done
}

slurm_wait_jobs() {
    local timeout=300
    if [ "${1:-}" = -t ]; then
        timeout="$2"
        shift 2
    fi
    [ $# -gt 0 ] || { echo "slurm_wait_jobs: no job ids" >&2; return 2; }
    local ids deadline=$((SECONDS + timeout)) out state reason active
    ids="$(IFS=,; echo "$*")"
    while true; do
        # -t all: finished jobs too (they stay listed for MinJobAge); one line per job or
        # per array task (the not yet started tasks of an array share one line).
        if out="$(squeue -h -t all -j "$ids" -o '%i %T %r' 2>&1)"; then
            active=0
            while read -r _ state reason; do
                case "$state" in
                    COMPLETED | FAILED | CANCELLED | TIMEOUT | NODE_FAIL | PREEMPTED | \
                        OUT_OF_MEMORY | BOOT_FAIL | DEADLINE) ;;
                    PENDING)
                        [ "$reason" = DependencyNeverSatisfied ] || active=1 ;;
                    *) active=1 ;;
                esac
            done <<<"$out"
            [ "$active" = 1 ] || return 0
        else
            # A transient error (slurmctld busy) is retried; an unknown job id (never
            # submitted, or purged MinJobAge seconds after it ended) or a dead cluster is not.
            case "$out" in
                *"Invalid job id"*)
                    echo "slurm: squeue -j $ids: $out" >&2
                    return 1 ;;
            esac
            _slurm_check_daemons || { echo "$out" >&2; return 1; }
        fi
        if [ "$SECONDS" -ge "$deadline" ]; then
            echo "slurm: jobs $ids still running or pending after ${timeout} s:" >&2
            echo "$out" >&2
            return 1
        fi
        sleep 0.25
    done
}

slurm_job_field() {
    local line
    line="$(scontrol -o show job "$1")" || return 1
    # Fields are space-separated KEY=value; values here (ExitCode, JobState) have no spaces.
    tr ' ' '\n' <<<"$line" | sed -n "s/^$2=//p" | head -n 1
}

slurm_task_exit() { slurm_job_field "$1_$2" ExitCode; }
slurm_job_exit() { slurm_job_field "$1" ExitCode; }
slurm_job_reason() { squeue -h -t PD -j "$1" -o %r 2>/dev/null || true; }
