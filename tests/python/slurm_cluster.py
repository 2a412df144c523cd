"""A one-node Slurm cluster on this machine for tests: munged, slurmctld and slurmd from Debian's
munge and slurm-wlm, all in the foreground (-F, -D) under one temporary folder (their own key,
socket, slurm.conf, state, spool and logs; free ports), as root. The node is this machine with its
real CPUs and memory (slurmd -C) and one GPU in gres.conf (File=/dev/null: a name for the
scheduler to hand out; the test maps it to lavapipe). Nothing outside the folder is read or
changed: /etc/munge and /etc/slurm are not used. Clients reach it through SLURM_CONF (env())."""
import ctypes
import os
import shutil
import signal
import socket
import subprocess
import time

DAEMONS = ("munged", "mungekey", "slurmctld", "slurmd", "sinfo", "sbatch", "squeue", "scancel", "scontrol")
PR_SET_PDEATHSIG = 1


class SlurmError(RuntimeError):
    """Slurm could not be started here; the message says why, with the daemons' last log lines."""


def die_with_parent():
    # A daemon must not outlive a test killed with SIGKILL (a CTest timeout).
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tail(path, lines=15):
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-lines:])
    except OSError as e:
        return f"({e})"


class LocalSlurm:
    def __init__(self, root):
        self.root = root
        self.conf = os.path.join(root, "slurm.conf")
        self.socket = os.path.join(root, "munge", "munge.socket")
        self.jobcomp = os.path.join(root, "log", "jobcomp.txt")
        self.node = socket.gethostname().split(".")[0]
        self.procs = {}

    def env(self, base=None):
        e = dict(os.environ if base is None else base)
        e["SLURM_CONF"] = self.conf
        return e

    def _need_tools(self):
        missing = [t for t in DAEMONS if shutil.which(t) is None and not os.path.exists(f"/usr/sbin/{t}")]
        if missing:
            raise SlurmError(f"not installed: {', '.join(missing)} (Debian 12's slurm-wlm and munge; "
                             "bash scripts/bootstrap.sh test installs them)")
        if os.geteuid() != 0:
            raise SlurmError("slurmd runs jobs as their user and needs root; this test runs as uid "
                             f"{os.geteuid()}")

    def _node_line(self):
        r = subprocess.run(["slurmd", "-C"], capture_output=True, text=True, timeout=30)
        first = r.stdout.splitlines()[0] if r.stdout else ""
        if r.returncode != 0 or not first.startswith("NodeName="):
            raise SlurmError(f"slurmd -C (the node's CPUs and memory) failed: {r.stdout}{r.stderr}")
        hw = first.split(None, 1)[1]  # CPUs=.. Boards=.. ... RealMemory=..
        return f"NodeName={self.node} NodeAddr=127.0.0.1 {hw} Gres=gpu:1 State=UNKNOWN"

    def _write_config(self):
        r = self.root
        for d in ("munge", "state", "spool", "log"):
            os.makedirs(os.path.join(r, d), exist_ok=True)
        os.chmod(r, 0o755)  # munged wants every folder above its socket searchable by all
        os.chmod(os.path.join(r, "munge"), 0o755)
        key = os.path.join(r, "munge", "munge.key")
        if not os.path.exists(key):
            self._check(["mungekey", "--create", "--keyfile", key], "mungekey (the munge key)")
        lines = [
            "ClusterName=vkunrolltest",
            f"SlurmctldHost={self.node}(127.0.0.1)",
            "SlurmUser=root", "SlurmdUser=root",
            f"SlurmctldPort={_free_port()}", f"SlurmdPort={_free_port()}",
            "AuthType=auth/munge", "CredType=cred/munge", f"AuthInfo=socket={self.socket}",
            f"StateSaveLocation={r}/state", f"SlurmdSpoolDir={r}/spool",
            f"SlurmctldPidFile={r}/slurmctld.pid", f"SlurmdPidFile={r}/slurmd.pid",
            f"SlurmctldLogFile={r}/log/slurmctld.log", f"SlurmdLogFile={r}/log/slurmd.log",
            # No cgroups: the processes are tracked from /proc and tasks are not confined.
            "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "JobAcctGatherType=jobacct_gather/none",
            "MpiDefault=none", "SelectType=select/cons_tres", "SelectTypeParameters=CR_Core",
            # No slurmdbd, so no sacct: every finished job is one line of this file.
            "AccountingStorageType=accounting_storage/none", "JobCompType=jobcomp/filetxt", f"JobCompLoc={self.jobcomp}",
            "ReturnToService=2", "SchedulerParameters=sched_interval=2", "MinJobAge=600",
            "GresTypes=gpu",
            self._node_line(),
            "PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP",
        ]
        with open(self.conf, "w") as f:
            f.write("\n".join(lines) + "\n")
        with open(os.path.join(r, "gres.conf"), "w") as f:
            f.write("Name=gpu File=/dev/null\n")

    def _check(self, cmd, what):
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=30, env=self.env())
        if r.returncode != 0:
            raise SlurmError(f"{what}: {' '.join(cmd)} exited {r.returncode}: {r.stdout}{r.stderr}")
        return r.stdout

    def _spawn(self, name, cmd):
        out = open(os.path.join(self.root, "log", f"{name}.out"), "w")
        self.procs[name] = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=self.env(),
                                            cwd=self.root, preexec_fn=die_with_parent)

    def _wait(self, what, ready, timeout_s):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise SlurmError(f"{name} exited {p.returncode} while waiting for {what}:\n{self.logs(name)}")
            if ready():
                return
            time.sleep(0.3)
        raise SlurmError(f"no {what} after {timeout_s} s:\n{self.logs()}")

    def logs(self, *names):
        names = names or tuple(self.procs)
        return "\n".join(f"--- {n} (last lines of {self.root}/log/{n}.out)\n{_tail(os.path.join(self.root, 'log', n + '.out'))}"
                         for n in names)

    def node_state(self):
        r = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True, timeout=30,
                           env=self.env())
        return r.stdout.strip() if r.returncode == 0 else ""

    def start(self):
        self._need_tools()
        self._write_config()
        r = self.root
        self._spawn("munged", ["munged", "-F", f"--socket={self.socket}", f"--key-file={r}/munge/munge.key",
                               f"--pid-file={r}/munge/munged.pid", f"--seed-file={r}/munge/munged.seed",
                               f"--log-file={r}/log/munged.log"])
        self._wait("munge socket", lambda: os.path.exists(self.socket), 20)
        self._spawn("slurmctld", ["slurmctld", "-D", "-i", "-f", self.conf])
        self._spawn("slurmd", ["slurmd", "-D", "-f", self.conf, "-N", self.node])
        self._wait(f"idle node {self.node} in sinfo", lambda: self.node_state() == "idle", 60)
        return self

    def sweep(self):
        """Kills whatever still has this cluster's SLURM_CONF in its environment (slurmstepd, job
        steps); returns their descriptions."""
        mark = f"SLURM_CONF={self.conf}".encode()
        killed = []
        for pid in (int(p) for p in os.listdir("/proc") if p.isdigit()):
            if pid == os.getpid():
                continue
            try:
                with open(f"/proc/{pid}/environ", "rb") as f:
                    if mark not in f.read().split(b"\0"):
                        continue
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmd = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
                os.kill(pid, signal.SIGKILL)
                killed.append(f"{pid} {cmd}")
            except (OSError, ProcessLookupError):
                continue
        return killed

    def stop(self):
        """Cancels every job, stops the daemons (SIGTERM, then SIGKILL after 15 s) and kills what is
        left; returns the processes that had to be killed after the daemons stopped."""
        if "slurmctld" in self.procs and self.procs["slurmctld"].poll() is None:
            subprocess.run(["scancel", "--partition=test"], capture_output=True, timeout=30, env=self.env())
            deadline = time.monotonic() + 15  # let slurmd end the job steps it runs
            while time.monotonic() < deadline and self.jobs():
                time.sleep(0.3)
        for name in ("slurmd", "slurmctld", "munged"):
            p = self.procs.get(name)
            if p is not None and p.poll() is None:
                p.terminate()
        for name, p in self.procs.items():
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        return self.sweep()

    def jobs(self):
        """squeue's jobs as (id, name, state) tuples."""
        r = subprocess.run(["squeue", "-h", "-o", "%i|%j|%T"], capture_output=True, text=True, timeout=30,
                           env=self.env())
        return [tuple(line.split("|")) for line in r.stdout.splitlines()] if r.returncode == 0 else []

    def finished_jobs(self):
        """jobcomp's lines as dicts (JobId, JobName, JobState, NodeList, Tres, ExitCode, WorkDir...)."""
        if not os.path.exists(self.jobcomp):
            return []
        rows = []
        with open(self.jobcomp) as f:
            for line in f:
                rows.append(dict(kv.split("=", 1) for kv in line.split() if "=" in kv))
        return rows

    def __enter__(self):
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc):
        self.stop()
        return False
