"""workflow/Snakefile through the shipped Slurm profile (workflow/profiles/slurm) on a real
slurmctld + slurmd (Debian's slurm-wlm, one node: this machine; tests/python/slurm_cluster.py),
against a local run of the same two simulated sequences: the GS frames must be byte-equal.

The node's one "GPU" is a gres.conf entry; a stand-in nvidia-smi on PATH maps Slurm's GPU index 0
to lavapipe's Vulkan UUID, so the profile's path runs whole: --gres=gpu:1 -> SLURM_JOB_GPUS ->
workflow/scripts/gpu_device.sh -> vkunroll --device uuid:... A job held behind another GPU job is
cancelled with scancel while it waits: Snakemake must see it fail (the profile's cluster-status)
and submit it again (restart-times), not wait for ever. Where Slurm cannot start, the test fails
and says why; it does not skip."""
import json
import os
import pathlib
import re
import shutil
import signal
import subprocess
import tempfile
import time

import pytest

from slurm_cluster import LocalSlurm, SlurmError, die_with_parent  # tests/python is on sys.path under pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
CLI = os.environ.get("VKUNROLL_CLI", str(ROOT / "build" / "vkunroll"))
NAMES = ["a", "b"]
UNROLL_ARGS = "unroll_args=--times 0.25,0.75 --quiet --no-video"
WORKFLOW_TIMEOUT_S = 240  # a hang: a job Slurm ended, never seen ended


def _on_sigterm(signum, frame):
    raise SystemExit(f"SIGTERM (signal {signum}): tearing the test's Slurm down")


@pytest.fixture
def slurm():
    root = tempfile.mkdtemp(prefix="vkunroll-slurm-", dir="/tmp")  # short: munge's socket path
    cluster = LocalSlurm(root)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        try:
            cluster.start()
        except (SlurmError, OSError, subprocess.SubprocessError) as e:
            pytest.fail(f"Slurm could not start on this machine: {e}", pytrace=False)
        yield cluster
    finally:
        left = cluster.stop()
        signal.signal(signal.SIGTERM, previous)
        shutil.rmtree(root, ignore_errors=True)
    assert not left, f"processes left after the daemons stopped (killed): {left}"


def lavapipe_uuid():
    r = subprocess.run([CLI, "devices"], capture_output=True, text=True, timeout=120, check=True)
    m = re.search(r"uuid:([0-9a-f-]{36})", r.stdout)
    assert m, r.stdout
    return m.group(1)


def fake_nvidia_smi(bindir, uuid):
    bindir.mkdir()
    tool = bindir / "nvidia-smi"
    tool.write_text(
        "#!/bin/bash\n"
        "# Stand-in for nvidia-smi (no NVIDIA GPU here): Slurm's GPU 0 is lavapipe, by its Vulkan UUID.\n"
        '[[ "$*" == "--query-gpu=uuid --format=csv,noheader -i 0" ]] || '
        '{ echo "test nvidia-smi: unexpected arguments: $*" >&2; exit 2; }\n'
        f"echo GPU-{uuid}\n")
    tool.chmod(0o755)


def snakemake_cmd(workdir, seqs, out, *extra):
    return ["snakemake", "-s", str(ROOT / "workflow" / "Snakefile"), "--directory", str(workdir),
            "--config", f"sequences={seqs}", f"out={out}", f"vkunroll={CLI}", "threads=1", UNROLL_ARGS, *extra]


def output_files(out, name):
    """The files a run wrote for one sequence that must not depend on where it ran."""
    d = out / name
    files = sorted(p.relative_to(d).as_posix() for p in (d / "frames").rglob("*") if p.is_file())
    return {f: (d / f).read_bytes() for f in files + ["contact_sheet.png"]}


def wait_for(what, ready, timeout_s, slurm, proc, log_path):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        got = ready()
        if got:
            return got
        time.sleep(0.3)
    ended = "" if proc.poll() is None else f"snakemake exited {proc.returncode} first; "
    pytest.fail(f"no {what} within {timeout_s} s; {ended}squeue: {slurm.jobs()}\n"
                f"{log_path.read_text()[-4000:]}\n{slurm.logs()}", pytrace=False)


def run_through_slurm(slurm, tmp, seqs, env):
    """The profile's run, with one of its queued jobs cancelled before it starts."""
    blocker = subprocess.run(["sbatch", "--parsable", "--gres=gpu:1", "--job-name=gpu-blocker",
                              f"--output={tmp}/blocker.log", "--wrap", "sleep 600"],
                             capture_output=True, text=True, timeout=30, env=env)
    assert blocker.returncode == 0, f"sbatch of the blocking job failed: {blocker.stderr}"
    blocker_id = blocker.stdout.strip().split(";")[0]
    log_path = tmp / "snakemake_slurm.log"
    rc = None
    with open(log_path, "w") as log:
        proc = subprocess.Popen(  # dies with the test, else it polls a dead slurmctld for ever
            snakemake_cmd(tmp / "slurm_run", seqs, tmp / "slurm_run" / "out", "--profile",
                          str(ROOT / "workflow" / "profiles" / "slurm"), "--set-resources", "unroll:mem_mb=1000"),
            stdout=log, stderr=subprocess.STDOUT, env=env, preexec_fn=die_with_parent)
        try:
            def both_pending():
                ids = [j[0] for j in slurm.jobs() if j[1].startswith("vkunroll-unroll") and j[2] == "PENDING"]
                return ids if len(ids) == 2 else None

            cancelled = min(wait_for("two pending vkunroll-unroll jobs", both_pending, 60, slurm, proc, log_path),
                            key=int)
            subprocess.run(["scancel", cancelled], check=True, timeout=30, env=env)
            subprocess.run(["scancel", blocker_id], check=True, timeout=30, env=env)
            rc = proc.wait(timeout=WORKFLOW_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pass
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = log_path.read_text()
    state = (f"still running after {WORKFLOW_TIMEOUT_S} s, killed (a job Slurm cancelled never seen as failed?)"
             if rc is None else f"exit {rc}")
    assert rc == 0, f"snakemake with the Slurm profile: {state}\n{text[-6000:]}\n{slurm.logs()}"
    return cancelled, text


def test_slurm_profile_runs_the_workflow_like_a_local_run(slurm, tmp_path):
    for tool in ("snakemake", "sbatch"):
        assert shutil.which(tool) or os.path.exists(f"/usr/bin/{tool}"), f"{tool} is not installed"
    seqs = tmp_path / "seqs"
    for i, n in enumerate(NAMES):
        subprocess.run([CLI, "simulate", "--out", str(seqs / n), "--preset", "clean", "--size", "48x32",
                        "--frames", "2", "--gt-per-frame", "1", "--seed", str(i + 11), "--quiet"],
                       check=True, timeout=120)
    local = subprocess.run(snakemake_cmd(tmp_path / "local_run", seqs, tmp_path / "local_run" / "out", "--cores", "1"),
                           capture_output=True, text=True, timeout=300)
    assert local.returncode == 0, local.stdout + local.stderr

    uuid = lavapipe_uuid()
    fake_nvidia_smi(tmp_path / "bin", uuid)
    env = slurm.env()
    env["PATH"] = f"{tmp_path / 'bin'}:{env.get('PATH', '/usr/bin:/bin')}"
    cancelled, log = run_through_slurm(slurm, tmp_path, seqs, env)
    assert "Trying to restart job" in log, log[-4000:]

    # Every unroll job went through Slurm: jobcomp has each sequence COMPLETED on this node with
    # the resources the profile asked for, and the cancelled one as CANCELLED.
    done = [j for j in slurm.finished_jobs() if j.get("Name", "").startswith("vkunroll-unroll")]
    states = {(j["Name"], j["JobState"]) for j in done}
    assert {(f"vkunroll-unroll-seq={n}", "COMPLETED") for n in NAMES} <= states, done
    assert any(j["JobId"] == cancelled and j["JobState"] == "CANCELLED" for j in done), done
    for j in done:
        if j["JobState"] == "COMPLETED":
            assert j["NodeList"] == slurm.node and "mem=1000M" in j["Tres"] and j["ExitCode"] == "0:0", j
            job_log = (tmp_path / "slurm_run" / f"slurm-{j['JobId']}.log").read_text()
            assert "rule unroll:" in job_log and '--device "$gpu"' in job_log, job_log
    assert not [j for j in slurm.finished_jobs() if j.get("Name", "").startswith("vkunroll-aggregate")]
    status = str(ROOT / "workflow" / "profiles" / "slurm" / "slurm_status.py")
    for jobid, want in ((done[-1]["JobId"], "success" if done[-1]["JobState"] == "COMPLETED" else "failed"),
                        (cancelled, "failed"), ("999999", "failed")):  # the last: unknown to Slurm
        r = subprocess.run([status, jobid], capture_output=True, text=True, timeout=60, env=env)
        assert (r.returncode, r.stdout.strip()) == (0, want), (jobid, r.stdout, r.stderr)

    for n in NAMES:
        a, b = tmp_path / "local_run" / "out", tmp_path / "slurm_run" / "out"
        local_files, slurm_files = output_files(a, n), output_files(b, n)
        assert len(local_files) == 5 and local_files.keys() == slurm_files.keys(), (n, local_files.keys(), slurm_files.keys())
        for f in local_files:
            assert local_files[f] == slurm_files[f], f"{n}/{f} differs between the local and the Slurm run"
        s_local, s_slurm = (json.load(open(d / n / "summary.json")) for d in (a, b))
        assert s_local["provenance"]["options"]["device"] == ""  # device=auto: vkunroll's choice locally
        assert s_slurm["provenance"]["options"]["device"] == f"uuid:{uuid}"  # and the scheduler's GPU in a job
        assert s_slurm["device"] == s_local["device"] and s_slurm["targets"] == s_local["targets"] == 4
        assert s_slurm["gs_frames"] == s_local["gs_frames"]  # the same instants, files and taus
    rows = [(tmp_path / d / "out" / "metrics_all.csv").read_text().splitlines() for d in ("local_run", "slurm_run")]
    assert [r.split(",")[:6] for r in rows[0]] == [r.split(",")[:6] for r in rows[1]], rows
