"""A private one-node Slurm cluster for tests that submit real jobs (tools/task under sbatch): its
own munged, slurmctld and slurmd, started as root in a folder of the test's, with a munge key and
socket of its own, free TCP ports and every state file, spool and log inside that folder (the
sockets and spool in a folder of /tmp when the folder's path is too long for a Unix socket).
Nothing else changes and nothing is mocked: when a daemon cannot start here, entering the context
raises RuntimeError whose first line names the daemon and its last error, then the end of its
log.

    reason = why_not_available()
    if reason:
        pytest.skip(reason)
    with local_slurm(tmp_path / "slurm") as cluster:
        job = cluster.sbatch(["--array=0-3", "-D", str(tmp_path), "--wrap", "tools/task ..."])
        assert set(cluster.wait(job, timeout=120).values()) == {"COMPLETED"}

Leaving the context, also when its body raised, cancels every job, then stops slurmd, slurmctld
and munged (SIGTERM to each one's process group, SIGKILL after a few seconds) and reaps them: no
daemon outlives it. Job steps run as root, so jobs can write anywhere under the folder.

Made for Debian 12's Slurm 22.05 (slurm-wlm, slurmctld, slurmd, munge). On a 2-core machine the
node is idle 0.3 s after the start; the first job starts about 3 s after the start (the
controller's first scheduling pass), later ones at once; the exit takes 0.3 s, or up to 2 s with
jobs running (cancelled, then waiting for pid 1 to reap their slurmstepd). A requeued job
(scontrol requeue: of a running, cancelled, failed or completed array task alike) starts again
requeue_delay_s + 1 s later, or at once after `scontrol update JobId=J_I StartTime=now`."""

import contextlib
import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time

DAEMONS = ("munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "squeue", "scontrol", "sinfo", "scancel")
# the daemons live in sbin, which a test's PATH may lack
SEARCH_PATH = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin"])
# seconds a daemon gets between SIGTERM and SIGKILL
STOP_GRACE_S = 5
# seconds the cluster gets to come up (node idle), and jobs to leave after scancel on exit
START_TIMEOUT_S = 30
CANCEL_TIMEOUT_S = 15
# seconds to wait on exit for init to reap the job processes (slurmstepd is a child of pid 1,
# a zombie until pid 1 reaps it; this is only so that `pgrep slurm` is empty after the exit)
REAP_WAIT_S = 2
# bytes a Unix socket's path may hold
SOCKET_PATH_MAX = 107


def _program(name):
    return shutil.which(name, path=SEARCH_PATH)


def why_not_available():
    """None when a private cluster can start here, else the reason it cannot (for pytest.skip):
    not root, or a Slurm or munge program missing."""
    if os.geteuid() != 0:
        return "a private Slurm cluster needs root (slurmd runs job steps as their user)"
    missing = [name for name in DAEMONS + CLIENTS if _program(name) is None]
    if missing:
        return ("no %s on PATH or in /usr/sbin (Debian: apt-get install slurm-wlm slurmctld "
                "slurmd munge)" % ", ".join(missing))
    return None


def _free_tcp_ports(count):
    """count distinct TCP ports that nothing is bound to right now (bound at once, then freed)."""
    sockets = []
    try:
        for _ in range(count):
            bound = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sockets.append(bound)
            bound.bind(("", 0))
        return [bound.getsockname()[1] for bound in sockets]
    finally:
        for bound in sockets:
            bound.close()


def _tail(path, lines=15):
    try:
        with open(path, errors="replace") as file:
            return "".join(file.readlines()[-lines:]).rstrip()
    except OSError as error:
        return "(no log: %s)" % error


def _expand_indices(text):
    """Array task indices of an ArrayTaskId field: "3", "0-3", "0,2-5:2", "0-7%2"."""
    indices = []
    for part in text.split("%")[0].split(","):
        span, _, step = part.partition(":")
        first, _, last = span.partition("-")
        indices.extend(range(int(first), int(last or first) + 1, int(step or 1)))
    return indices


def _job_processes(conf):
    """Pids of the processes that slurmd started for this cluster's jobs and that are still
    alive: slurmstepd (which leaves slurmd's process group) and the job steps. Both carry
    SLURM_CONF=conf in their environment; steps also SLURM_JOB_ID."""
    marker = ("SLURM_CONF=" + conf).encode()
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            with open("/proc/%s/environ" % entry, "rb") as file:
                environment = file.read().split(b"\0")
            with open("/proc/%s/comm" % entry) as file:
                command = file.read().strip()
        except OSError:
            continue
        if marker in environment and (command == "slurmstepd" or any(
                variable.startswith(b"SLURM_JOB_ID=") for variable in environment)):
            pids.append(int(entry))
    return pids


def _unreaped(pids):
    """Whether one of pids still exists, or any slurmstepd zombie does."""
    if any(os.path.exists("/proc/%d" % pid) for pid in pids):
        return True
    for entry in os.listdir("/proc"):
        try:
            with open("/proc/%s/stat" % entry) as file:
                stat = file.read()
        except OSError:
            continue
        # "pid (comm) state ..."
        if stat.partition(" (")[2].startswith("slurmstepd) Z"):
            return True
    return False


def _kill_job_processes(conf):
    """SIGKILL to every process _job_processes finds, then waits (up to STOP_GRACE_S) until they
    are gone (a zombie waiting for init counts as gone)."""
    deadline = time.monotonic() + STOP_GRACE_S
    while time.monotonic() < deadline:
        pids = _job_processes(conf)
        if not pids:
            return
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.05)


class _Daemon:
    """One daemon in a process group of its own, its stdout and stderr in OUT; it logs to LOG
    (the same file for munged, which logs to stderr in the foreground)."""

    def __init__(self, name, args, env, log, out):
        self.name = name
        self.log = log
        self.out = out
        with open(out, "ab") as file:
            self.process = subprocess.Popen([_program(name), *args], env=env,
                                            stdin=subprocess.DEVNULL, stdout=file,
                                            stderr=subprocess.STDOUT, start_new_session=True)

    def exited(self):
        """Whether the daemon has exited, without reaping it (its pid, and so its process group
        id, stay ours until stop() reaps it)."""
        try:
            return os.waitid(os.P_PID, self.process.pid,
                             os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
        except ChildProcessError:
            return True

    def failure(self, what):
        """RuntimeError: "NAME WHAT: its last error line", then the end of its log (of its
        stdout and stderr when the log is empty: it failed before opening it)."""
        path = self.log if _tail(self.log, 1) and os.path.exists(self.log) else self.out
        tail = _tail(path)
        errors = [line for line in tail.splitlines()
                  if re.search(r"\b(fatal|error)\b", line, re.IGNORECASE)]
        reason = re.sub(r"^\[[^]]*\] ", "", errors[-1]) if errors else "no error logged"
        return RuntimeError("%s %s: %s\n%s:\n%s" % (self.name, what, reason, path, tail))

    def _signal_group(self, number):
        try:
            os.killpg(self.process.pid, number)
        except (ProcessLookupError, PermissionError):
            pass

    def stop(self):
        """SIGTERM to the group, SIGKILL to it after STOP_GRACE_S or once the daemon has gone (for
        what it left), then reaps it."""
        if self.process.returncode is not None:
            return
        self._signal_group(signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        while not self.exited() and time.monotonic() < deadline:
            time.sleep(0.05)
        self._signal_group(signal.SIGKILL)
        self.process.wait()


class SlurmCluster:
    """A running private cluster (made by local_slurm). env is os.environ without the caller's
    SLURM_*, SBATCH_*, SALLOC_* and SRUN_* variables, plus SLURM_CONF naming this cluster's
    slurm.conf: pass it to any Slurm client run by hand. Job ids are strings ("12", or "12_3" for
    one array task)."""

    def __init__(self, folder, conf, env, node, logs):
        self.folder = folder
        self.conf = conf
        self.env = env
        self.node = node
        self.logs = logs

    def client(self, *args, timeout=30):
        """Runs a Slurm client (sbatch, squeue, scontrol, sinfo, scancel) on this cluster and
        returns its CompletedProcess (text); never raises for its exit status."""
        return subprocess.run([_program(args[0]), *map(str, args[1:])], env=self.env,
                              capture_output=True, text=True, timeout=timeout)

    def log_tails(self, lines=15):
        """The last lines of every daemon's log, for a failure message."""
        return "\n".join("%s:\n%s" % (path, _tail(path, lines)) for path in self.logs)

    def sbatch(self, args):
        """Submits a batch job (sbatch --parsable ARGS) and returns its job id; raises
        RuntimeError with sbatch's message when it is refused."""
        result = self.client("sbatch", "--parsable", *args)
        if result.returncode != 0:
            raise RuntimeError("sbatch %s: %s" % (" ".join(map(str, args)),
                                                  result.stderr.strip()))
        return result.stdout.strip().split(";")[0]

    def jobs(self, job_id):
        """scontrol show job JOB -o as one dict per line (pending array tasks may share one
        line); values holding spaces are cut at the first space. Raises RuntimeError when the
        controller no longer knows the job (MinJobAge: 300 s after it ended)."""
        result = self.client("scontrol", "show", "job", job_id, "-o")
        if result.returncode != 0:
            raise RuntimeError("scontrol show job %s: %s" % (job_id, result.stderr.strip()))
        return [dict(re.findall(r"(?:^|\s)(\w+)=(\S*)", line))
                for line in result.stdout.splitlines() if line.strip()]

    def states(self, job_id):
        """{array task index: JobState} for an array job or one task of it ("12_3"); {None: state}
        for a job that is not an array. States as scontrol says them: PENDING, RUNNING,
        COMPLETED, FAILED, CANCELLED, ..."""
        states = {}
        for job in self.jobs(job_id):
            task = job.get("ArrayTaskId")
            for index in _expand_indices(task) if task else [None]:
                states[index] = job.get("JobState")
        return states

    def wait(self, job_id, timeout):
        """Waits until no task of the job is pending, running or completing (squeue -h -j JOB
        lists none), then returns states(job_id) ({} when the controller has forgotten the job).
        Raises TimeoutError after timeout seconds, with the queue and the daemons' log tails."""
        deadline = time.monotonic() + timeout
        while True:
            queued = self.client("squeue", "-h", "-j", job_id, "-o", "%i %T %r")
            # a job the controller has forgotten is not queued either
            if queued.returncode == 0 and not queued.stdout.strip():
                return self.states(job_id)
            if queued.returncode != 0 and "Invalid job id" in queued.stderr:
                return {}
            if time.monotonic() > deadline:
                raise TimeoutError("job %s still queued after %g s:\n%s%s\n%s" % (
                    job_id, timeout, queued.stdout, queued.stderr, self.log_tails()))
            time.sleep(0.2)

    def cancel_all(self, timeout=CANCEL_TIMEOUT_S):
        """Cancels every job of this cluster and waits (up to timeout seconds) until the queue is
        empty; returns whether it is."""
        self.client("scancel", "--user", "root")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            queued = self.client("squeue", "-h", "-o", "%i")
            if queued.returncode != 0 or not queued.stdout.strip():
                return queued.returncode == 0
            time.sleep(0.2)
        return False


def _write_config(path, values, node_line, partition_line):
    with open(path, "w") as file:
        for key, value in values:
            file.write("%s=%s\n" % (key, value))
        file.write(node_line + "\n" + partition_line + "\n")


@contextlib.contextmanager
def local_slurm(folder, requeue_delay_s=10):
    """Starts a private one-node cluster in folder (made if absent) and yields its SlurmCluster
    once the node is idle; stops it on exit, whatever happened. Raises RuntimeError naming the
    daemon that did not start (or the node that did not become idle within START_TIMEOUT_S),
    with the end of its log. Needs root (see why_not_available).

    requeue_delay_s: seconds a requeued job (scontrol requeue) waits before it may start again,
    Slurm's AuthInfo cred_expire, which is also how long a job's launch credential lives (Slurm's
    default, 120 s, would make a test of a requeued task wait two minutes); at least 5 (Slurm
    ignores a smaller one). `scontrol update JobId=JOB_I StartTime=now` after the requeue skips
    the wait."""
    if requeue_delay_s < 5:
        raise ValueError("requeue_delay_s must be at least 5 (Slurm's least cred_expire), got %r"
                         % requeue_delay_s)
    folder = os.path.abspath(str(folder))
    node = socket.gethostname().split(".")[0]
    log = os.path.join(folder, "log")
    munge = os.path.join(folder, "munge")
    state = os.path.join(folder, "state")
    # the jobs and node states of an earlier cluster in this folder go (slurmctld would
    # recover them)
    shutil.rmtree(state, ignore_errors=True)
    for path in (folder, log, state):
        os.makedirs(path, exist_ok=True)
    os.makedirs(munge, mode=0o700, exist_ok=True)
    os.chmod(munge, 0o700)
    # the sockets (munged's, and in the spool slurmd's steps' "<node>_<job>.<step>") under
    # folder when its path is short enough, else in a folder of /tmp removed on exit
    short = None
    if len(folder) + len("/run/spool/%s_4294967295.4294967295" % node) > SOCKET_PATH_MAX:
        short = tempfile.mkdtemp(prefix="slurm-")
        os.chmod(short, 0o755)
    sockets = os.path.join(short or folder, "run")
    os.makedirs(sockets, mode=0o755, exist_ok=True)
    munge_socket = os.path.join(sockets, "munge.sock")
    spool = os.path.join(sockets, "spool")
    shutil.rmtree(spool, ignore_errors=True)
    os.makedirs(spool)

    # a munge key of this cluster's own: 128 random bytes, mode 600
    key = os.path.join(munge, "munge.key")
    with open(os.open(key, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "wb") as file:
        file.write(os.urandom(128))

    conf = os.path.join(folder, "slurm.conf")
    controller_port, node_port = _free_tcp_ports(2)
    _write_config(conf, [
        ("ClusterName", "stackgen"),
        ("SlurmctldHost", "%s(127.0.0.1)" % node),
        ("SlurmUser", "root"),
        ("SlurmdUser", "root"),
        ("AuthType", "auth/munge"),
        ("CredType", "cred/munge"),
        ("AuthInfo", "socket=%s,cred_expire=%d" % (munge_socket, requeue_delay_s)),
        ("SlurmctldPort", controller_port),
        ("SlurmdPort", node_port),
        ("StateSaveLocation", state),
        ("SlurmdSpoolDir", spool),
        ("SlurmctldPidFile", os.path.join(state, "slurmctld.pid")),
        ("SlurmdPidFile", os.path.join(state, "slurmd.pid")),
        ("SlurmctldLogFile", os.path.join(log, "slurmctld.log")),
        ("SlurmdLogFile", os.path.join(log, "slurmd.log")),
        ("ProctrackType", "proctrack/linuxproc"),
        ("TaskPlugin", "task/none"),
        ("SelectType", "select/cons_tres"),
        ("SelectTypeParameters", "CR_Core"),
        ("SchedulerType", "sched/backfill"),
        # a requeued job waits for the main scheduler's periodic pass (default every 60 s) once its
        # delay is over: pass each second
        ("SchedulerParameters", "sched_interval=1"),
        ("JobAcctGatherType", "jobacct_gather/none"),
        ("AccountingStorageType", "accounting_storage/none"),
        ("JobCompType", "jobcomp/none"),
        ("MpiDefault", "none"),
        ("ReturnToService", "2"),
        ("MailProg", "/bin/true"),
    ], "NodeName=%s NodeAddr=127.0.0.1 CPUs=%d State=UNKNOWN" % (node, os.cpu_count() or 1),
       "PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP")

    env = {name: value for name, value in os.environ.items()
           if not name.startswith(("SLURM_", "SBATCH_", "SALLOC_", "SRUN_"))}
    env["SLURM_CONF"] = conf
    logs = [os.path.join(log, "munged.out"), os.path.join(log, "slurmctld.log"),
            os.path.join(log, "slurmd.log")]
    cluster = SlurmCluster(folder, conf, env, node, logs)
    daemons = []

    def start(name, args):
        daemon = _Daemon(name, args, env, logs[DAEMONS.index(name)],
                         os.path.join(log, name + ".out"))
        daemons.append(daemon)
        return daemon

    def answered(ready):
        try:
            return ready()
        except subprocess.TimeoutExpired:
            return False

    def wait_until(daemon, ready, what):
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if daemon.exited():
                raise daemon.failure("exited at start")
            if answered(ready):
                return
            if time.monotonic() > deadline:
                raise daemon.failure("not %s after %d s" % (what, START_TIMEOUT_S))
            time.sleep(0.1)

    try:
        # munged in the foreground (-F), so it stays our child, logging to stderr; -f lets it
        # run with its files in folders that it would otherwise find insecure
        munged = start("munged", [
            "-F", "-f", "--key-file=" + key, "--socket=" + munge_socket,
            "--pid-file=" + os.path.join(munge, "munged.pid"),
            "--seed-file=" + os.path.join(munge, "seed")])
        wait_until(munged, lambda: os.path.exists(munge_socket), "listening")

        # the controller (-i: no complaint about the state files it lacks); ready when scontrol
        # ping says UP
        controller = start("slurmctld", ["-D", "-i", "-f", conf])
        wait_until(controller,
                   lambda: "is UP" in cluster.client("scontrol", "ping", timeout=5).stdout,
                   "answering scontrol ping")

        # the node daemon; ready when the node is idle (ReturnToService=2 makes it so once it
        # has registered)
        node_daemon = start("slurmd", ["-D", "-f", conf, "-N", node])
        wait_until(node_daemon,
                   lambda: cluster.client("sinfo", "-h", "-o", "%T", timeout=5).stdout.strip()
                   == "idle",
                   "idle in sinfo")
        yield cluster
    finally:
        # jobs first, then slurmd, what its jobs left (slurmstepd leaves slurmd's group),
        # slurmctld, munged
        running = _job_processes(conf)
        try:
            if len(daemons) >= 2 and not daemons[1].exited():
                # a client that hangs must not keep the daemons up nor hide the body's error
                with contextlib.suppress(subprocess.SubprocessError, OSError):
                    cluster.cancel_all()
        finally:
            try:
                if len(daemons) == 3:
                    daemons.pop().stop()
                _kill_job_processes(conf)
            finally:
                while daemons:
                    daemons.pop().stop()
                if short:
                    shutil.rmtree(short, ignore_errors=True)
                deadline = time.monotonic() + REAP_WAIT_S
                while _unreaped(running) and time.monotonic() < deadline:
                    time.sleep(0.05)
