"""What writing the run file costs: a scene run with and without `-o`, alternately, `--repeat`
times each; prints the median ms a step of both and their ratio (one machine, one run).

    .venv/bin/python benches/output_overhead.py [SCENE.toml] [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
MOREAU = ROOT / "target" / "release" / "moreau"


def ms_per_step(scene: pathlib.Path, out: pathlib.Path | None) -> float:
    args = [str(MOREAU), "run", str(scene), "--quiet", "--summary-json", "-"]
    if out is not None:
        args += ["-o", str(out), "--force"]
    proc = subprocess.run(args, capture_output=True, text=True, check=True,
                          stdin=subprocess.DEVNULL)
    return json.loads(proc.stdout)["ms_per_step"]


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
            without.append(ms_per_step(args.scene, None))
            with_file.append(ms_per_step(args.scene, out))
        size = out.stat().st_size
    a, b = statistics.median(without), statistics.median(with_file)
    print(f"| scene | without -o (ms/step) | with -o (ms/step) | ratio | file |")
    print(f"|---|---|---|---|---|")
    print(f"| {args.scene.name} | {a:.3f} | {b:.3f} | {b / a:.2f} | {size / 1e6:.2f} MB |")


if __name__ == "__main__":
    main()
