"""What writing the run file costs: a scene run with and without `-o`, alternately, `--repeat`
times each; prints the median ms a step of both (the stepping, from the run's summary) and the
median whole run (the process, timed here: it includes the writer's last frames, written after
the last step, and closing the file), with their ratios (one machine, one run).

    .venv/bin/python benches/output_overhead.py [SCENE.toml] [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
MOREAU = ROOT / "target" / "release" / "moreau"


def measure(scene: pathlib.Path, out: pathlib.Path | None) -> tuple[float, float]:
    """(ms a step, whole run in s) of one run."""
    args = [str(MOREAU), "run", str(scene), "--quiet", "--summary-json", "-"]
    if out is not None:
        args += ["-o", str(out), "--force"]
    start = time.perf_counter()
    proc = subprocess.run(args, capture_output=True, text=True, check=True,
                          stdin=subprocess.DEVNULL)
    whole = time.perf_counter() - start
    return json.loads(proc.stdout)["ms_per_step"], whole


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("scene", nargs="?", type=pathlib.Path,
                        default=ROOT / "data" / "scenes" / "room-150.toml")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    without, with_file = [], []
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "run.h5"
        for _ in range(args.repeat):
            without.append(measure(args.scene, None))
            with_file.append(measure(args.scene, out))
        size = out.stat().st_size
    a, b = (statistics.median(m for m, _ in runs) for runs in (without, with_file))
    wa, wb = (statistics.median(w for _, w in runs) for runs in (without, with_file))
    print("| scene | ms a step without -o | with -o | ratio | whole run without -o (s) "
          "| with -o | ratio | file |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {args.scene.name} | {a:.3f} | {b:.3f} | {b / a:.2f} | {wa:.2f} | {wb:.2f} "
          f"| {wb / wa:.2f} | {size / 1e6:.2f} MB |")


if __name__ == "__main__":
    main()
