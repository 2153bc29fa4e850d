"""The tracking process sets its own thread counts: one by default, --threads N otherwise."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROBE = """
import json, sys
from unittest import mock
import graphtrack.commands.track as track_cmd
from graphtrack.cli import main

def report(args):
    import cv2, torch
    from threadpoolctl import threadpool_info
    import os
    print(json.dumps({"torch": torch.get_num_threads(), "cv2": cv2.getNumThreads(),
                      "omp": os.environ.get("OMP_NUM_THREADS"),
                      "blas": sorted({p["num_threads"] for p in threadpool_info()})}))
    return 0

with mock.patch.object(track_cmd, "run", report):
    sys.exit(main(["track", "SEQ", "--out", "O"] + sys.argv[1:]))
"""


@pytest.mark.parametrize("extra,n", [([], 1), (["--threads", "2"], 2), (["--threads=3"], 3)])
def test_track_sets_torch_opencv_and_blas_threads(extra, n):
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", PROBE, *extra], capture_output=True, text=True, env=env,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["torch"] == n and got["cv2"] == n and got["omp"] == str(n)
    assert got["blas"] in ([], [n])
