#!/usr/bin/env python3
"""Builds the FMUs of moreau: `python3 fmu/package.py` (from anywhere) runs the release build
of the FMU library and writes

    target/fmu/moreau-crowd-fmi2.fmu   (FMI 2.0 co-simulation, binaries/linux64/)
    target/fmu/moreau-crowd-fmi3.fmu   (FMI 3.0 co-simulation, binaries/x86_64-linux/)

each a zip of modelDescription.xml (from fmu/fmi2 or fmu/fmi3, the same text the binary
embeds, so GUID and instantiation token agree), binaries/<platform>/moreau_fmu.so and
resources/room-150.toml (the default scene). Standard library only.
"""

import argparse
import pathlib
import re
import subprocess
import sys
import tomllib
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
IDENTIFIER = "moreau_fmu"
PLATFORMS = {"2": "linux64", "3": "x86_64-linux"}


def package(version: str, library: pathlib.Path, out: pathlib.Path) -> pathlib.Path:
    description = ROOT / "fmu" / f"fmi{version}" / "modelDescription.xml"
    text = description.read_text()
    if f'modelIdentifier="{IDENTIFIER}"' not in text:
        sys.exit(f"{description}: modelIdentifier is not {IDENTIFIER}")
    # FMI 3 sizes its arrays by the structural parameter n_people, whose start value (what
    # importers that read only the XML size the arrays with) is the shipped scene's count.
    scene = tomllib.loads((ROOT / "data" / "scenes" / "room-150.toml").read_text())
    people = sum(g.get("count", len(g.get("positions", []))) for g in scene["groups"])
    for start in re.findall(r'<UInt64 name="n_people"[^>]* start="(\d+)"', text):
        if int(start) != people:
            sys.exit(f"{description}: n_people starts at {start}, the scene has {people} people")
    target = out / f"moreau-crowd-fmi{version}.fmu"
    tmp = target.with_suffix(".fmu.partial")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("modelDescription.xml", text)
        z.write(library, f"binaries/{PLATFORMS[version]}/{IDENTIFIER}.so")
        z.write(ROOT / "data" / "scenes" / "room-150.toml", "resources/room-150.toml")
        z.writestr("documentation/index.html",
                   "<html><body><p>moreau crowd FMU: see README.md of the moreau repository, "
                   "section 'The FMU'.</p></body></html>\n")
    tmp.replace(target)
    return target


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmi", choices=["2", "3", "all"], default="all")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "target" / "fmu")
    parser.add_argument("--no-build", action="store_true", help="use the library as built")
    args = parser.parse_args()
    if not args.no_build:
        subprocess.run(["cargo", "build", "--release", "--locked", "-p", "moreau-fmu"],
                       cwd=ROOT, check=True)
    library = ROOT / "target" / "release" / f"lib{IDENTIFIER}.so"
    if not library.is_file():
        sys.exit(f"{library} is missing: build it with cargo build --release -p moreau-fmu")
    args.out.mkdir(parents=True, exist_ok=True)
    versions = ["2", "3"] if args.fmi == "all" else [args.fmi]
    for v in versions:
        print(f"wrote {package(v, library, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
