"""Run every benchmark in this folder and collect their markdown output in ``benchmarks/RESULTS.md``.

    python benchmarks/run_all.py            # all benchmarks (the paper tables take ~15 min)
    python benchmarks/run_all.py --quick    # shorter settings for the long ones (~10 min in all)
    python benchmarks/run_all.py fk ik      # only bench_fk.py and bench_ik.py

Each ``bench_*.py`` prints its own tables (with ratios against peers measured in the same run);
this script records the date, machine and versions above them.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent


def machine() -> str:
    import numpy
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {numpy.__version__}, "
        f"torch {torch.__version__}"
    )


# Arguments each script needs (and, with --quick, the shorter settings of the long ones).
ARGS = {"bench_region.py": ["all"]}
QUICK_ARGS = {
    "bench_paper.py": ["--quick"],
    "bench_hybrid.py": ["--no-paper"],
    "bench_real.py": ["--no-cv"],
    "bench_region.py": ["all"],
    "bench_hybrid_ik.py": ["-n", "2000"],
    "bench_payload.py": ["--quick"],
    "bench_plan.py": ["--seeds", "0", "--min-steps", "3000"],
    "bench_transfer.py": ["--min-steps", "5000", "--beside-n", "2000"],
}


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    argv = [a for a in argv if a != "--quick"]
    names = [f"bench_{a}.py" for a in argv] if argv else sorted(p.name for p in HERE.glob("bench_*.py"))
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = [f"# hykin benchmark results\n\n{stamp}; {machine()}\n"]
    status = 0
    for name in names:
        t0 = time.perf_counter()
        print(f"== {name}", flush=True)
        extra = (QUICK_ARGS if quick else ARGS).get(name, [])
        proc = subprocess.run([sys.executable, str(HERE / name), *extra], capture_output=True, text=True)
        dt = time.perf_counter() - t0
        print(proc.stdout, flush=True)
        if proc.returncode != 0:
            status = 1
            print(proc.stderr[-3000:], file=sys.stderr)
        cmd = " ".join(["python", f"benchmarks/{name}", *extra])
        out.append(f"\n## {name} ({dt:.0f} s{', FAILED' if proc.returncode else ''})\n\n`{cmd}`\n\n{proc.stdout.strip()}\n")
    (HERE / "RESULTS.md").write_text("".join(out), encoding="utf-8")
    print(f"wrote {HERE / 'RESULTS.md'}")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
