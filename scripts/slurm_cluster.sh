#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for testing sweeps (tests/test_slurm.py, .ci/run).
#
#   scripts/slurm_cluster.sh install        # Debian packages (root; a few seconds)
#   scripts/slurm_cluster.sh start [DIR]    # munged, slurmctld, slurmd; prints `export SLURM_CONF=...`
#   scripts/slurm_cluster.sh stop  [DIR]    # stops the three daemons by the PIDs in DIR
#
# DIR (default /tmp/cmal-lcd-slurm) holds slurm.conf, the daemons' pid files, logs and spool;
# nothing is written to /etc. Client commands (sbatch, sinfo, squeue, the submitit launcher) find
# the cluster through SLURM_CONF=DIR/slurm.conf. One node (this host, 127.0.0.1) with every CPU
# and 90% of the memory, one partition `debug`, no accounting (sacct is off: the launcher then
# reads job states from squeue, cmal_lcd/slurm.py). Needs root and no systemd (cgroups are not
# used: proctrack/linuxproc, task/none). Every wait is bounded; a daemon that does not come up
# is reported with its log and the script exits 1. Notes: ../shared/design/slurm_notes.md.
set -euo pipefail

command="${1:-}"
DIR="${2:-/tmp/cmal-lcd-slurm}"
WAIT_S=30
MUNGE_PID=/run/munge/cmal-lcd-munged.pid
MUNGE_LOG=/run/munge/cmal-lcd-munged.log

die() { echo "slurm_cluster.sh: $*" >&2; exit 1; }

install() {
    [ "$(id -u)" = 0 ] || die "install needs root"
    local packages="slurmctld slurmd slurm-client munge"
    # shellcheck disable=SC2086
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q $packages >/dev/null 2>&1 || {
        # a fresh machine may have no package lists yet
        apt-get update -q >/dev/null
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q $packages >/dev/null
    }
}

write_conf() {
    local host cpus mem_mb
    host="$(hostname -s)"
    cpus="$(nproc --all)"
    mem_mb="$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)"
    mkdir -p "$DIR/log" "$DIR/spool/ctld" "$DIR/spool/d" "$DIR/run"
    cat >"$DIR/slurm.conf" <<EOF
ClusterName=cmal-lcd-test
SlurmctldHost=${host}(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MinJobAge=600
SlurmctldPidFile=$DIR/run/slurmctld.pid
SlurmdPidFile=$DIR/run/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
StateSaveLocation=$DIR/spool/ctld
SlurmdSpoolDir=$DIR/spool/d
SlurmctldPort=6817
SlurmdPort=6818
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
NodeName=${host} NodeAddr=127.0.0.1 CPUs=${cpus} RealMemory=${mem_mb} State=UNKNOWN
PartitionName=debug Nodes=${host} Default=YES MaxTime=INFINITE State=UP
EOF
}

wait_for() {  # wait_for DESCRIPTION LOG COMMAND...: poll COMMAND for WAIT_S seconds
    local what="$1" log="$2"
    shift 2
    for _ in $(seq 1 "$WAIT_S"); do
        if "$@" >/dev/null 2>&1; then return 0; fi
        sleep 1
    done
    echo "slurm_cluster.sh: $what did not come up in ${WAIT_S} s; last lines of $log:" >&2
    tail -n 20 "$log" >&2 2>/dev/null || true
    stop
    exit 1
}

start() {
    [ "$(id -u)" = 0 ] || die "start needs root (the daemons run as root here)"
    for tool in munged slurmctld slurmd sinfo; do
        command -v "$tool" >/dev/null || die "$tool not found; run: $0 install"
    done
    write_conf
    export SLURM_CONF="$DIR/slurm.conf"
    # munge: its key comes with the package; its socket folder must belong to its user
    # (its files live there too: the munge user may not reach DIR). One munged per machine:
    # one already answering is used and left running.
    mkdir -p /run/munge
    chown munge:munge /run/munge
    if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
        runuser -u munge -- munged --pid-file="$MUNGE_PID" --log-file="$MUNGE_LOG"
        wait_for munged "$MUNGE_LOG" sh -c 'munge -n | unmunge'
        cp "$MUNGE_PID" "$DIR/run/munged.pid"
    fi
    slurmctld -f "$SLURM_CONF"
    wait_for slurmctld "$DIR/log/slurmctld.log" scontrol ping
    slurmd -f "$SLURM_CONF"
    wait_for "the node" "$DIR/log/slurmd.log" \
        sh -c "sinfo -h -N -o '%T' | grep -Eq '^(idle|mixed|allocated)'"
    echo "export SLURM_CONF=$SLURM_CONF"
}

stop_pid() {  # stop_pid PIDFILE: TERM, then KILL after 10 s
    local file="$1" pid
    [ -s "$file" ] || return 0
    pid="$(cat "$file")"
    if kill -0 "$pid" 2>/dev/null; then
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 10); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
        kill -9 "$pid" 2>/dev/null || true
    fi
    rm -f "$file"
}

stop() {
    stop_pid "$DIR/run/slurmd.pid"
    stop_pid "$DIR/run/slurmctld.pid"
    stop_pid "$DIR/run/munged.pid"  # only when this script started it
}

case "$command" in
    install) install ;;
    start) start ;;
    stop) stop ;;
    *) die "usage: $0 install | start [DIR] | stop [DIR]" ;;
esac
