"""A real one-node SLURM cluster on this machine, for testing the cluster profiles.

Every daemon runs in the foreground as a child of this process, with all state (keys, configs,
databases, spool, logs, sockets) under one folder: munged (authentication), MariaDB and slurmdbd
(job accounting, so that `sacct` shows every job as on a production cluster), slurmctld and slurmd.
Ports are free ports on 127.0.0.1, picked at start. The node is this machine: its hostname, cores and
memory (`slurmd -C`), and one generic GPU resource without a device (`gres/gpu`, count 1) so that a
job asking for a GPU (`--gpus=1`, the GPU profile's `gpu: 1`) is accepted and scheduled; it runs on
the CPU.

Accounting: `accounting_storage/none` leaves `sacct` without history, and `jobcomp/filetxt` only
feeds `sacct --completion`, which the SLURM executor plugin does not use (it asks `sacct` for job
states). slurmdbd with MariaDB is what clusters run, so that is what this uses.

Needs root (slurmd starts jobs as their user) and Debian's slurmctld, slurmd, slurm-client, slurmdbd,
munge and mariadb-server (`scripts/system_packages.sh slurm`). Used as a context manager; `stop()`
ends the daemons it started and removes their state.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

#: Binaries the cluster needs (Debian paths are on PATH for root; /usr/sbin added for other users).
BINARIES = ("munged", "mungekey", "mariadbd", "mariadb-install-db", "mariadb", "slurmdbd", "slurmctld",
            "slurmd", "sbatch", "srun", "scancel", "sacct", "sacctmgr", "squeue", "sinfo")
CLUSTER = "sonardet"
PARTITION = "main"


def _which(name: str) -> str | None:
    return shutil.which(name, path=os.environ.get("PATH", "") + os.pathsep + "/usr/sbin:/sbin")


def missing_binaries() -> list[str]:
    """The binaries of BINARIES that are not installed."""
    return [b for b in BINARIES if _which(b) is None]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(what: str, check, timeout: float, log: Path | None = None) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if check():
            return
        time.sleep(0.5)
    tail = log.read_text()[-3000:] if log is not None and log.exists() else ""
    raise RuntimeError(f"local SLURM: {what} not ready after {timeout:.0f} s\n{tail}")


def node_line() -> dict:
    """This machine as a SLURM node, from `slurmd -C` (hostname, CPUs, topology, memory)."""
    out = subprocess.run([_which("slurmd"), "-C"], capture_output=True, text=True, check=True).stdout
    fields = dict(kv.split("=", 1) for kv in out.split("\n")[0].split())
    return fields


class LocalSlurm:
    """munged + MariaDB + slurmdbd + slurmctld + slurmd under `root` (see the module docstring)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.procs: list[tuple[str, subprocess.Popen]] = []
        self.node = node_line()
        self.hostname = self.node["NodeName"]
        self.ports = {k: _free_port() for k in ("slurmctld", "slurmd", "slurmdbd", "mariadb")}
        self.conf = self.root / "etc" / "slurm.conf"
        #: Environment for SLURM clients (sbatch, sacct, snakemake --executor slurm) and the daemons.
        self.env = dict(os.environ, SLURM_CONF=str(self.conf),
                        PATH=os.pathsep.join([str(self.root / "bin"), os.environ.get("PATH", ""), "/usr/sbin:/sbin"]))

    # -- lifecycle ---------------------------------------------------------------------------------

    def __enter__(self) -> "LocalSlurm":
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        for d in ("bin", "etc", "log", "munge", "mysql", "state", "spool", "run"):
            (self.root / d).mkdir(parents=True, exist_ok=True)
        self._write_srun_wrapper()
        self._start_munge()
        self._start_mariadb()
        self._write_configs()
        self._start_slurmdbd()
        self._start_slurm()

    def stop(self) -> None:
        """Cancel the jobs still queued or running (a job's processes outlive slurmd), then SIGTERM to
        every daemon started here (newest first), SIGKILL after 20 s; then remove the database, key,
        spool and state (the configs and logs stay)."""
        self._cancel_jobs()
        for name, proc in reversed(self.procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        self.procs.clear()
        for d in ("mysql", "munge", "state", "spool", "run"):
            shutil.rmtree(self.root / d, ignore_errors=True)

    def _jobs(self) -> list[str]:
        out = subprocess.run([_which("squeue"), "-h", "-o", "%A"], capture_output=True, text=True, env=self.env)
        return out.stdout.split() if out.returncode == 0 else []

    def _cancel_jobs(self) -> None:
        running = dict(self.procs)
        if not all(n in running and running[n].poll() is None for n in ("slurmctld", "slurmd")):
            return
        jobs = self._jobs()
        if jobs:
            subprocess.run([_which("scancel"), *jobs], capture_output=True, env=self.env)
            t0 = time.monotonic()
            while self._jobs() and time.monotonic() - t0 < 60:
                time.sleep(1)

    def _spawn(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.root / "log" / f"{name}.out", "ab")
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                start_new_session=True)
        self.procs.append((name, proc))
        return proc

    def _alive(self, name: str) -> bool:
        proc = dict(self.procs)[name]
        if proc.poll() is not None:
            out = (self.root / "log" / f"{name}.out").read_text()[-3000:]
            raise RuntimeError(f"local SLURM: {name} exited with {proc.returncode}\n{out}")
        return True

    # -- daemons -----------------------------------------------------------------------------------

    def _start_munge(self) -> None:
        d = self.root / "munge"
        d.chmod(0o700)
        key = d / "munge.key"
        subprocess.run([_which("mungekey"), "--create", f"--keyfile={key}"], check=True, env=self.env)
        key.chmod(0o600)
        self.munge_socket = d / "munge.socket.2"
        self._spawn("munged", [_which("munged"), "--foreground", "--force", f"--key-file={key}",
                               f"--socket={self.munge_socket}", f"--pid-file={d / 'munged.pid'}",
                               f"--log-file={self.root / 'log' / 'munged.log'}",
                               f"--seed-file={d / 'munged.seed'}"])
        _wait("munged", lambda: self._alive("munged") and self.munge_socket.exists(), 30,
              self.root / "log" / "munged.log")

    def _mariadb_args(self) -> list[str]:
        return ["--no-defaults", f"--datadir={self.root / 'mysql'}", "--user=root"]

    def _start_mariadb(self) -> None:
        sock = self.root / "run" / "mariadb.sock"
        subprocess.run([_which("mariadb-install-db"), *self._mariadb_args(), "--skip-test-db",
                        "--auth-root-authentication-method=socket"],
                       check=True, capture_output=True, env=self.env)
        self._spawn("mariadb", [_which("mariadbd"), *self._mariadb_args(), f"--socket={sock}",
                                f"--port={self.ports['mariadb']}", "--bind-address=127.0.0.1",
                                "--skip-name-resolve", f"--pid-file={self.root / 'run' / 'mariadb.pid'}",
                                "--innodb-buffer-pool-size=64M", "--skip-log-bin",
                                f"--log-error={self.root / 'log' / 'mariadb.log'}"])
        client = [_which("mariadb"), "--no-defaults", f"--socket={sock}", "-u", "root"]
        _wait("MariaDB", lambda: self._alive("mariadb") and subprocess.run(
            client + ["-e", "SELECT 1"], capture_output=True).returncode == 0, 60,
            self.root / "log" / "mariadb.log")
        self.db_password = os.urandom(12).hex()
        sql = (f"CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY '{self.db_password}';"
               "GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';")
        subprocess.run(client + ["-e", sql], check=True, capture_output=True)

    def _write_configs(self) -> None:
        r, node = self.root, self.node
        memory = int(node["RealMemory"]) - 1024  # leave the system its share
        auth = f"AuthType=auth/munge\nAuthInfo=socket={self.munge_socket}\n"
        self.conf.write_text(
            f"ClusterName={CLUSTER}\n"
            f"SlurmctldHost={self.hostname}(127.0.0.1)\n"
            f"SlurmctldPort={self.ports['slurmctld']}\nSlurmdPort={self.ports['slurmd']}\n"
            "SlurmUser=root\nSlurmdUser=root\n" + auth + "CredType=cred/munge\n"
            f"StateSaveLocation={r / 'state'}\nSlurmdSpoolDir={r / 'spool'}\n"
            f"SlurmctldPidFile={r / 'run' / 'slurmctld.pid'}\nSlurmdPidFile={r / 'run' / 'slurmd.pid'}\n"
            f"SlurmctldLogFile={r / 'log' / 'slurmctld.log'}\nSlurmdLogFile={r / 'log' / 'slurmd.log'}\n"
            "ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nMpiDefault=none\n"
            "SwitchType=switch/none\nJobAcctGatherType=jobacct_gather/linux\nJobAcctGatherFrequency=10\n"
            "SchedulerType=sched/backfill\nSelectType=select/cons_tres\n"
            "SelectTypeParameters=CR_Core_Memory\nReturnToService=2\n"
            "AccountingStorageType=accounting_storage/slurmdbd\nAccountingStorageHost=127.0.0.1\n"
            f"AccountingStoragePort={self.ports['slurmdbd']}\nAccountingStorageTRES=gres/gpu\n"
            # the munge socket for talking to slurmdbd (AuthInfo covers only the cluster's daemons)
            f"AccountingStoragePass={self.munge_socket}\n"
            "AccountingStoreFlags=job_comment\nJobCompType=jobcomp/none\nGresTypes=gpu\n"
            "SlurmctldTimeout=30\nSlurmdTimeout=60\nInactiveLimit=0\nMinJobAge=300\nKillWait=10\n"
            "SchedulerParameters=sched_interval=2\n"
            f"NodeName={self.hostname} NodeAddr=127.0.0.1 CPUs={node['CPUs']} "
            f"Boards={node['Boards']} SocketsPerBoard={node['SocketsPerBoard']} "
            f"CoresPerSocket={node['CoresPerSocket']} ThreadsPerCore={node['ThreadsPerCore']} "
            f"RealMemory={memory} Gres=gpu:1 State=UNKNOWN\n"
            f"PartitionName={PARTITION} Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n")
        (r / "etc" / "gres.conf").write_text(f"NodeName={self.hostname} Name=gpu File=/dev/null\n")
        dbd = r / "etc" / "slurmdbd.conf"
        dbd.write_text(
            auth + f"DbdHost={self.hostname}\nDbdAddr=127.0.0.1\nDbdPort={self.ports['slurmdbd']}\n"
            "SlurmUser=root\nStorageType=accounting_storage/mysql\nStorageHost=127.0.0.1\n"
            f"StoragePort={self.ports['mariadb']}\nStorageUser=slurm\nStoragePass={self.db_password}\n"
            f"StorageLoc=slurm_acct_db\nLogFile={r / 'log' / 'slurmdbd.log'}\n"
            f"PidFile={r / 'run' / 'slurmdbd.pid'}\n")
        dbd.chmod(0o600)

    def _write_srun_wrapper(self) -> None:
        """srun that finds this cluster's configuration. A job of the SLURM executor runs its rule
        with a nested srun, after the jobstep plugin has dropped every SLURM_ variable but the job's
        identity, SLURM_CONF included; on a cluster the configuration is at the default path
        (/etc/slurm) or served by slurmctld, here it is under `root`. The job inherits PATH."""
        wrapper = self.root / "bin" / "srun"
        wrapper.write_text(f"#!/bin/sh\nSLURM_CONF={self.conf} exec {_which('srun')} \"$@\"\n")
        wrapper.chmod(0o755)

    def _sacctmgr(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([_which("sacctmgr"), "-i", *args], capture_output=True, text=True, env=self.env)

    def _start_slurmdbd(self) -> None:
        self._spawn("slurmdbd", [_which("slurmdbd"), "-D"])
        _wait("slurmdbd", lambda: self._alive("slurmdbd") and self._sacctmgr("list", "cluster").returncode == 0,
              60, self.root / "log" / "slurmdbd.log")
        self._sacctmgr("add", "cluster", CLUSTER)

    def _start_slurm(self) -> None:
        self._spawn("slurmctld", [_which("slurmctld"), "-D", "-i"])
        self._spawn("slurmd", [_which("slurmd"), "-D", "-N", self.hostname])

        def node_idle() -> bool:
            self._alive("slurmctld")
            self._alive("slurmd")
            out = subprocess.run([_which("sinfo"), "-h", "-N", "-o", "%T"], capture_output=True, text=True,
                                 env=self.env).stdout.strip()
            return out == "idle"

        _wait("the node", node_idle, 90, self.root / "log" / "slurmctld.log")

    # -- queries -----------------------------------------------------------------------------------

    def sacct(self, *fields: str) -> list[dict]:
        """Every job the cluster ran (allocations, not steps), from the accounting database."""
        out = subprocess.run([_which("sacct"), "-a", "-X", "-P", "-n", "--starttime", "2000-01-01",
                              "-o", ",".join(fields)], capture_output=True, text=True, check=True,
                             env=self.env).stdout
        return [dict(zip(fields, line.split("|"))) for line in out.splitlines() if line]
