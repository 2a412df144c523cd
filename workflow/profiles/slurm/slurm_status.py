#!/usr/bin/python3
"""Snakemake's cluster-status command for Slurm: slurm_status.py JOBID prints running, success or
failed. scontrol knows a job until MinJobAge (300 s by default) after its end; sacct after that,
where the cluster keeps accounting. A scheduler that does not answer is "running" (asked again);
a job that neither knows is "failed", said on stderr."""
import subprocess
import sys

RUNNING = {"PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "SUSPENDED", "REQUEUED", "REQUEUE_FED",
           "REQUEUE_HOLD", "RESIZING", "SIGNALING", "STAGE_OUT", "STOPPED", "RESV_DEL_HOLD"}
FAILED = {"FAILED", "CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL", "BOOT_FAIL", "DEADLINE", "PREEMPTED",
          "REVOKED", "SPECIAL_EXIT"}


def ask(cmd):
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, str(e)
    return (r.stdout if r.returncode == 0 else None), r.stderr.strip()


def state_of(jobid):
    """The job's state word, '' where Slurm no longer knows it, None where Slurm did not answer."""
    out, err = ask(["scontrol", "show", "job", "-o", jobid])
    if out is not None:
        for field in out.split():
            if field.startswith("JobState="):
                return field.split("=", 1)[1]
    elif "Invalid job id" not in err:
        print(f"slurm_status.py: scontrol show job {jobid}: {err}; asking again later", file=sys.stderr)
        return None
    out, err = ask(["sacct", "-X", "-n", "-P", "-o", "State", "-j", jobid])
    if out is None or not out.strip():
        return ""
    return out.split()[0]  # "CANCELLED by 0" -> CANCELLED


def main(argv):
    if len(argv) != 2:
        sys.exit("usage: slurm_status.py JOBID (as sbatch --parsable printed it)")
    jobid = argv[1].split(";")[0]  # --parsable prints "id;cluster" on a federation
    state = state_of(jobid)
    if state is None or state in RUNNING:
        print("running")
    elif state == "COMPLETED":
        print("success")
    else:
        if state not in FAILED:
            print(f"slurm_status.py: job {jobid}: state '{state}' (unknown to Slurm or not a known state)",
                  file=sys.stderr)
        print("failed")


if __name__ == "__main__":
    main(sys.argv)
