"""workflow/Snakefile end to end on three tiny simulated sequences, locally with --cores 2: every
sequence unrolled with summary.json as the marker, the table made, a second run does nothing, a
deleted output is redone (reusing its GS frames through --resume) and nothing else is."""
import csv
import json
import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
CLI = os.environ.get("VKUNROLL_CLI", str(ROOT / "build" / "vkunroll"))


def snakemake(tmp, *extra):
    cmd = ["snakemake", "-s", str(ROOT / "workflow" / "Snakefile"), "--cores", "2", "--directory", str(tmp),
           "--config", f"sequences={tmp / 'seqs'}", f"out={tmp / 'out'}", f"vkunroll={CLI}", "threads=1",
           "unroll_args=--times 0.25,0.75 --quiet --no-video", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


@pytest.mark.skipif(not os.path.exists("/usr/bin/snakemake"), reason="snakemake (Debian package) not installed")
def test_workflow_runs_resumes_and_redoes_only_what_is_missing(tmp_path):
    names = ["a", "b", "c"]
    for i, n in enumerate(names):
        subprocess.run([CLI, "simulate", "--out", str(tmp_path / "seqs" / n), "--preset", "clean", "--size", "48x32",
                        "--frames", "2", "--gt-per-frame", "1", "--seed", str(i + 1), "--quiet"], check=True)
    r = snakemake(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "out"
    with open(out / "metrics_all.csv") as f:
        rows = list(csv.DictReader(f))
    assert [row["sequence"] for row in rows] == names
    assert all(int(row["gs_frames"]) == 4 for row in rows)

    r = snakemake(tmp_path)
    assert r.returncode == 0, r.stderr
    assert "Nothing to be done" in r.stdout + r.stderr

    mtimes = {n: os.stat(out / n / "summary.json").st_mtime_ns for n in names}
    os.remove(out / "b" / "summary.json")
    r = snakemake(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    redone = json.load(open(out / "b" / "summary.json"))
    assert redone["resume"]["reused"] == 4  # the frames of the first run, still valid
    for n in ("a", "c"):
        assert os.stat(out / n / "summary.json").st_mtime_ns == mtimes[n], n
