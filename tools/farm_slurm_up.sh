#!/bin/bash
# Starts munged, slurmctld, slurmd in the foreground under $T (as tests/farm_jobs.rs does).
T=${T:-/tmp/farm-slurm-try}
rm -rf $T; mkdir -p $T/munge $T/state $T/spool; chmod 755 $T; chown munge:munge $T/munge; chmod 755 $T/munge
runuser -u munge -- mungekey -c -k $T/munge/munge.key
runuser -u munge -- munged -F --socket=$T/munge/munge.socket --key-file=$T/munge/munge.key --log-file=$T/munge/munged.log --pid-file=$T/munge/munged.pid --seed-file=$T/munge/munged.seed &
sleep 0.5
cat > $T/slurm.conf <<CONF
ClusterName=strata
SlurmctldHost=localhost
SlurmUser=root
SlurmdUser=root
SlurmctldPort=16817
SlurmdPort=16818
AuthType=auth/munge
AuthInfo=socket=$T/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/slurmctld.log
SlurmdLogFile=$T/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MailProg=/bin/true
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
NodeName=localhost NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN
PartitionName=strata Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$T/slurm.conf
slurmctld -D -i &
slurmd -D -N localhost &
wait
