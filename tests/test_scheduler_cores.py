"""The installed Snakemake keeps to --cores: two jobs that each claim both cores never run side by side.

Snakemake 9.10 to at least 9.15 started them together (its issue 3913), so the default run had three
one-thread jobs on two cores and the trainings on its longest chain got about half a core each.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

SNAKEFILE = textwrap.dedent('''
    rule final:
        input: "a.txt", "b.txt"

    rule prepare:
        output: "common"
        threads: 2
        shell: "touch {output}"

    rule work:
        input: "common"
        output: "{name}.txt"
        threads: 2
        shell: "python -c 'import time; print(time.time())' > {output}; sleep 1.5; python -c 'import time; print(time.time())' >> {output}"
''')


@pytest.mark.parametrize("scheduler", ["greedy", "ilp"])
def test_two_jobs_claiming_both_cores_do_not_overlap(tmp_path, scheduler):
    (tmp_path / "Snakefile").write_text(SNAKEFILE)
    r = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", "--scheduler", scheduler, "-q"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    (a0, a1), (b0, b1) = ([float(v) for v in (tmp_path / f"{n}.txt").read_text().split()] for n in "ab")
    first_end, second_start = (a1, b0) if a0 <= b0 else (b1, a0)
    assert second_start >= first_end - 0.05, (a0, a1, b0, b1)
