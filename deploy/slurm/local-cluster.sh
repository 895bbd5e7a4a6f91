#!/usr/bin/env bash
# A real one-node Slurm cluster on this Debian machine — munge for
# authentication, slurmctld and slurmd on localhost — then
# deploy/slurm/sylva.sbatch submitted with several worker tasks, and a
# check that the image arrives. Run as root (it installs slurm-wlm and
# munge and writes /etc/slurm/slurm.conf, unless one not written by this
# script is there). Usage:
#   deploy/slurm/local-cluster.sh [SCENE] [TASKS] [OUT]
# Defaults: examples/tree.json, 3 worker tasks, sylva-out/slurm/tree.png.
# The daemons are stopped at the end unless KEEP_SLURM=1.
set -euo pipefail
cd "$(dirname "$0")/../.."
SCENE=${1:-examples/tree.json}
TASKS=${2:-3}
OUT=$(realpath -m "${3:-sylva-out/slurm/$(basename "${SCENE%.*}").png}")
mkdir -p "$(dirname "$OUT")"
LOG=$(dirname "$OUT")/slurm-job.log
rm -f "$OUT" "$LOG"

bash scripts/install-deps.sh
export PATH="$HOME/.cargo/bin:$PATH"
missing=()
for p in slurm-wlm munge; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  apt-get update -q
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
export SYLVA=${SYLVA:-$PWD/target/release/sylva}
[ -x "$SYLVA" ] || cargo build --release --locked -p sylva

# munge: one key for the one node.
if [ ! -s /etc/munge/munge.key ]; then
  dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
fi
chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
mkdir -p /run/munge && chown munge:munge /run/munge
pgrep -x munged >/dev/null || runuser -u munge -- /usr/sbin/munged
munge -n | unmunge >/dev/null

# Slurm: this host as the controller and the one compute node. No cgroups
# (containers often have none to give): processes are tracked by parentage.
conf=/etc/slurm/slurm.conf
marker="# written by sylva deploy/slurm/local-cluster.sh"
if [ -e "$conf" ] && ! grep -qF "$marker" "$conf"; then
  echo "$conf exists and was not written by this script; not touching it" >&2
  exit 1
fi
host=$(hostname -s)
mem=$(free -m | awk '/^Mem:/ { print int($2 * 0.8) }')
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat > "$conf" <<CONF
$marker
ClusterName=sylva-local
SlurmctldHost=$host
AuthType=auth/munge
SlurmUser=root
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
# The node offers a slot per worker task, whatever its core count: lavapipe
# workers share the cores (config_overrides keeps it from being drained).
SlurmdParameters=config_overrides
NodeName=$host NodeAddr=127.0.0.1 CPUs=$((TASKS > $(nproc) ? TASKS : $(nproc))) RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
stop() {
  scontrol shutdown >/dev/null 2>&1 || true
  pkill -x slurmd 2>/dev/null || true
}
[ "${KEEP_SLURM:-0}" = 1 ] || trap stop EXIT
pgrep -x slurmctld >/dev/null || slurmctld
pgrep -x slurmd >/dev/null || slurmd
for _ in $(seq 1 60); do
  sinfo -h -o %t 2>/dev/null | grep -qE '^(idle|mix)' && break
  sleep 0.5
done
sinfo

echo "sbatch: $TASKS worker tasks, $SCENE -> $OUT" >&2
t0=$(date +%s)
sbatch --wait --ntasks="$TASKS" --output="$LOG" deploy/slurm/sylva.sbatch "$SCENE" "$OUT" || {
  echo "the Slurm job failed; its log:" >&2
  cat "$LOG" >&2
  exit 1
}
cat "$LOG"
# The image arrived: a PNG of the scene's size.
head -c 8 "$OUT" | od -An -tx1 | grep -q "89 50 4e 47 0d 0a 1a 0a" || { echo "no PNG at $OUT" >&2; exit 1; }
echo "slurm: the image arrived at $OUT ($(stat -c %s "$OUT") bytes) in $(($(date +%s) - t0)) s"
