#!/usr/bin/env bash
# A real one-node Slurm cluster (Debian's slurmctld, slurmd, munge) without
# systemd, every piece of state under DIR (see shared/reference/slurm.md).
#   slurm.sh packages   Debian packages it needs (only those missing)
#   slurm.sh up DIR     start munged, slurmctld, slurmd; wait until the node is idle; write DIR/env
#   slurm.sh down DIR   cancel jobs, stop the daemons by the PIDs they recorded
set -euo pipefail

node=fdmlab-node
partition=fdmlab

case "${1:-}" in
packages)
    command -v slurmctld >/dev/null || echo slurmctld
    command -v slurmd >/dev/null || echo slurmd
    command -v sbatch >/dev/null || echo slurm-client
    command -v munged >/dev/null || echo munge
    command -v python3 >/dev/null || echo python3
    ;;
up)
    dir=$(realpath -m "${2:?usage: slurm.sh up DIR}")
    mkdir -p "$dir"
    chmod 0755 "$dir"
    mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$dir/log"
    chmod 0755 "$dir/munge"
    # munge: own key, socket, pid, seed and log under DIR.
    if [ ! -s "$dir/munge/munge.key" ]; then
        head -c 1024 /dev/urandom >"$dir/munge/munge.key"
        chmod 0400 "$dir/munge/munge.key"
    fi
    munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
        --pid-file="$dir/munge/munged.pid" --seed-file="$dir/munge/munged.seed" --log-file="$dir/munge/munged.log"
    # The node line is the hardware line slurmd prints, with more CPUs than
    # cores so a small array runs at once (config_overrides).
    # Free loopback ports, so a cluster of another checkout can run beside this one.
    read -r ctld_port slurmd_port < <(python3 -c 'import socket
s = [socket.socket() for _ in range(2)]
for x in s: x.bind(("127.0.0.1", 0))
print(*(x.getsockname()[1] for x in s))')
    hw=$(slurmd -C | head -n1 | sed -e "s/^NodeName=[^ ]*/NodeName=$node/" -e 's/CPUs=[0-9]*/CPUs=8/' -e 's/ThreadsPerCore=[0-9]*/ThreadsPerCore=4/' -e 's/RealMemory=[0-9]*/RealMemory=4000/')
    cat >"$dir/slurm.conf" <<EOF
ClusterName=fdmlab
SlurmctldHost=$(hostname -s)(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
CryptoType=crypto/munge
AuthInfo=socket=$dir/munge/munge.socket
MpiDefault=none
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerParameters=batch_sched_delay=0,sched_min_interval=0
SlurmdParameters=config_overrides
ReturnToService=2
MinJobAge=30
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
$hw NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=$partition Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
    slurmctld -f "$dir/slurm.conf" -i
    slurmd -f "$dir/slurm.conf" -N "$node"
    export SLURM_CONF="$dir/slurm.conf"
    state=
    deadline=$((SECONDS + 60))
    while [ $SECONDS -lt $deadline ]; do
        state=$(timeout 5 sinfo -h -N -n "$node" -o %t 2>/dev/null || true)
        [ "$state" = idle ] && break
        sleep 0.5
    done
    if [ "$state" != idle ]; then
        echo "slurm.sh: node $node not idle after 60 s (state '$state'); logs in $dir/log" >&2
        exit 1
    fi
    printf 'export SLURM_CONF=%q\n' "$dir/slurm.conf" >"$dir/env"
    echo "slurm.sh: one-node cluster up (SLURM_CONF=$dir/slurm.conf)" >&2
    ;;
down)
    dir=$(realpath -m "${2:?usage: slurm.sh down DIR}")
    [ -f "$dir/slurm.conf" ] && SLURM_CONF="$dir/slurm.conf" scancel --partition="$partition" 2>/dev/null || true
    stop() { # pid file: SIGTERM, then wait up to 10 s for the process to go
        [ -s "$1" ] || return 0
        local pid
        pid=$(cat "$1")
        kill "$pid" 2>/dev/null || return 0
        for _ in $(seq 1 40); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.25; done
        kill -9 "$pid" 2>/dev/null || true
    }
    stop "$dir/slurmd.pid"
    stop "$dir/slurmctld.pid"
    stop "$dir/munge/munged.pid"
    rm -f "$dir/env"
    ;;
*)
    echo "usage: slurm.sh packages | up DIR | down DIR" >&2
    exit 2
    ;;
esac
