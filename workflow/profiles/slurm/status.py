#!/usr/bin/env python3
"""Snakemake cluster-status script for Slurm: prints running, success or failed for a job id."""
import subprocess
import sys

job = sys.argv[1]
try:
    out = subprocess.run(["sacct", "-j", job, "--format=State", "--noheader", "--parsable2"],
                         capture_output=True, text=True, check=True).stdout.split()
except (OSError, subprocess.CalledProcessError):
    print("running")  # sacct may lag behind a fresh job: ask again later
    sys.exit(0)
state = out[0] if out else "PENDING"
if state.startswith("COMPLETED"):
    print("success")
elif state.split()[0] in {"PENDING", "RUNNING", "REQUEUED", "RESIZING", "SUSPENDED", "CONFIGURING", "COMPLETING"}:
    print("running")
else:
    print("failed")
