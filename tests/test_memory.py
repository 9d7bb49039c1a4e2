"""Freed memory kept for reuse (`testbed.memory`): measured by the page faults of a work array
allocated, written and freed over and over, as a simulation's are, in a fresh interpreter set
as Dask's nanny sets its workers (`MALLOC_TRIM_THRESHOLD_=65536`)."""

import json
import os
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc's mallopt"
)

MEASURE = """
import json, resource
import numpy as np
from testbed.memory import keep_freed_memory

def faults(rounds=200, size=400_000):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        np.ones(size // 8)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

pages = 200 * 400_000 // resource.getpagesize()
as_dask = faults()
kept = keep_freed_memory()
faults()  # the heap grows once
print(json.dumps({"pages": pages, "as_dask": as_dask, "kept": kept, "after": faults()}))
"""


def test_a_dask_worker_s_setting_faults_every_array_and_keeping_freed_memory_stops_it():
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    done = subprocess.run(
        [sys.executable, "-c", MEASURE], env=env, capture_output=True, text=True, check=True
    )
    m = json.loads(done.stdout)
    assert m["as_dask"] > 0.5 * m["pages"]  # each array's pages faulted in afresh
    assert m["kept"] is True
    assert m["after"] < 0.05 * m["pages"]
