"""sonardet.allocator: freed memory stays in the process, so a second large block costs no page faults."""

import json
import subprocess
import sys
import textwrap

import pytest

from sonardet.detect.sasa import DEFAULTS
from sonardet.detect.sasa.config import RUNTIME_KEYS

# Allocates, frees and allocates again a 256 MB block and reports the minor page faults of the second
# allocation (first touch of every page): in a fresh process, so that the setting does not stay in the
# test process.
_PROBE = textwrap.dedent("""
    import json, resource, sys
    import numpy as np
    from sonardet.allocator import retain_freed_memory
    ok = retain_freed_memory() if sys.argv[1] == "retain" else None
    n = 64 * 2**20  # float32 values: 256 MB
    a = np.ones(n, dtype=np.float32); del a
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones(n, dtype=np.float32)
    f1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    print(json.dumps({"ok": ok, "faults": f1 - f0, "again": retain_freed_memory()}))
""")


def _probe(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_a_freed_block_is_reused_without_page_faults():
    pages = 256 * 2**20 // 4096
    plain, kept = _probe("system"), _probe("retain")
    # glibc's default: the block is unmapped on free, so every page of the new one faults again
    # (with numpy's transparent huge pages fewer, hundreds: 640 on the project's VM).
    assert plain["faults"] > 100, (plain, pages)
    assert kept["ok"] is True and kept["again"] is True  # in force, and idempotent
    assert kept["faults"] < 50


def test_the_setting_is_a_runtime_key_on_by_default():
    # It changes no number, so a model trained with it may be loaded without it and the other way round.
    assert DEFAULTS["retain_freed_memory"] is True
    assert "retain_freed_memory" in RUNTIME_KEYS
