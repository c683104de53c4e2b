#!/usr/bin/env python3
"""Builds the FMUs of moreau: `python3 fmu/package.py` (from anywhere) runs the release build
of the FMU library and writes its FMI 2 and FMI 3 FMUs into target/fmu/:

    target/fmu/moreau-crowd-fmi2.fmu   (FMI 2.0 co-simulation, binaries/linux64/)
    target/fmu/moreau-crowd-fmi3.fmu   (FMI 3.0 co-simulation, binaries/x86_64-linux/)

each a zip of modelDescription.xml (from fmu/fmi2 or fmu/fmi3, the same text the binary
embeds, so GUID and instantiation token agree), binaries/<platform>/moreau_fmu.so and
resources/room-150.toml (the default scene). Standard library only.

With `--scene FILE` it builds the FMUs of that scene instead,

    target/fmu/moreau-crowd-<scene>-fmi2.fmu, target/fmu/moreau-crowd-<scene>-fmi3.fmu

with the scene as resources/<scene>.toml (the FMU's default scene: the one scene file in its
resources; a scene file named room-150.toml goes in as room-150-scene.toml, since the FMU
takes resources/room-150.toml for the room's FMU, which declares no scene's variables) and a
model description generated from the shipped one for the scene: n_people starts at the
scene's count (FMI 3), the default experiment stops at its horizon, and every
moving body (`[[moving]]`) is a continuous Real input `moving.<name>` with value reference
1000 + its index in the scene: the body's keyframe parameter, from its first keyframe's time
(the start value) to its last. Every exit is a Boolean input `exit_open.<name>` (value
reference 2000 + its index; exit 0's is the same input as `door_open`) and an Integer output
`passed.<name>` (3000 + its index): how many have passed it. The binary is the same (it
serves the inputs of whatever scene it runs), and so is the GUID / instantiation token it
checks; it refuses, through the `scene` parameter, a scene whose exits or moving bodies are
not the ones such an FMU declares (those of the one scene file in its resources).
"""

import argparse
import pathlib
import re
import subprocess
import sys
import tomllib
import zipfile
from xml.sax.saxutils import escape, quoteattr

ROOT = pathlib.Path(__file__).resolve().parents[1]
IDENTIFIER = "moreau_fmu"
PLATFORMS = {"2": "linux64", "3": "x86_64-linux"}
ROOM = ROOT / "data" / "scenes" / "room-150.toml"
# The value reference of the first moving body's position (fmu/src/model.rs, vr::MOVING).
MOVING = 1000
# The value references of the first exit's input and output (vr::EXIT_OPEN, vr::EXIT_PASSED).
EXIT_OPEN = 2000
EXIT_PASSED = 3000


def people_of(scene: dict) -> int:
    """The people a scene places at the start: its groups' counts (or listed positions); 0 for
    a scene of sources alone (it has no `groups`: a KeyError stopped the build half done)."""
    return sum(g.get("count", len(g.get("positions", []))) for g in scene.get("groups", []))


def substitute(text: str, pattern: str, replacement: str, where: pathlib.Path) -> str:
    """`text` with the one match of `pattern` replaced; a template that changed stops the build."""
    out, n = re.subn(pattern, lambda _: replacement, text)
    if n != 1:
        sys.exit(f"{where}: {n} matches of {pattern!r} (expected 1): the template changed")
    return out


def resource_name(scene: pathlib.Path) -> str:
    """The name of scene file `scene` in the resources of its FMU: its own, unless that is the
    room's (the FMU runs resources/room-150.toml as the room's FMU, with no scene variables
    declared, so it would not check another scene against the ones this FMU declares)."""
    return f"{scene.stem}-scene.toml" if scene.name == ROOM.name else scene.name


def for_scene(version: str, text: str, path: pathlib.Path, where: pathlib.Path) -> str:
    """The shipped model description `text` made the description of the FMU of scene `path`."""
    scene = tomllib.loads(path.read_text())
    file = resource_name(path)
    text = substitute(text, r"Default scene: [^\"]*?\(resources/room-150\.toml\)\.",
                      escape(f"Default scene: {scene.get('name', path.stem)} (resources/{file}).",
                             {'"': "&quot;"}), where)
    text = substitute(text, r"empty: resources/room-150\.toml", escape(f"empty: resources/{file}"),
                      where)
    horizon = scene.get("time", {}).get("horizon")
    if horizon is not None:
        text = substitute(text, r'stopTime="[^"]*"', f'stopTime="{float(horizon)!r}"', where)
    if version == "3":
        start = re.search(r'<UInt64 name="n_people"[^>]* start="\d+"', text)
        if start is None:
            sys.exit(f"{where}: no start value of n_people: the template changed")
        text = text.replace(start.group(0), re.sub(r'start="\d+"', f'start="{people_of(scene)}"',
                                                   start.group(0)))
    variables = []
    index = len(re.findall(r"<ScalarVariable ", text))
    for b, body in enumerate(scene.get("moving", [])):
        keys = body["keyframes"]
        first, last = float(keys[0]["t"]), float(keys[-1]["t"])
        name = quoteattr(f"moving.{body['name']}")
        description = quoteattr(
            f"Position of the moving body '{body['name']}': its keyframe parameter, from "
            f"{first!r} to {last!r} (the scene's keyframe times). The value set at a "
            f"communication point t is where the body is at t + h: it moves there linearly "
            f"during the step. Never set: held at {first!r}, where the scene puts it at the start")
        vr = MOVING + b
        if version == "2":
            index += 1
            variables.append(
                f'    <!-- {index} --><ScalarVariable name={name} valueReference="{vr}" '
                f'causality="input" variability="continuous" description={description}>\n'
                f'      <Real start="{first!r}" min="{first!r}" max="{last!r}"/>\n'
                f'    </ScalarVariable>\n')
        else:
            variables.append(
                f'    <Float64 name={name} valueReference="{vr}" causality="input" '
                f'variability="continuous" start="{first!r}" min="{first!r}" max="{last!r}" '
                f'description={description}/>\n')
    # The exits: whether each is open (a Boolean input; exit 0's is door_open under another
    # name) and how many passed it (an Integer output, listed in the model structure).
    outputs, unknowns = [], []
    for k, exit_ in enumerate(scene.get("exits", [])):
        name = exit_["name"]
        opened, passed = quoteattr(f"exit_open.{name}"), quoteattr(f"passed.{name}")
        said = (f"Whether the exit '{name}' is open (closed: a wall across it)"
                + ("; the same input as door_open" if k == 0 else ""))
        counted = f"People who have passed the exit '{name}'"
        if version == "2":
            variables.append(
                f'    <!-- {index + 1} --><ScalarVariable name={opened} '
                f'valueReference="{EXIT_OPEN + k}" causality="input" variability="discrete" '
                f'description={quoteattr(said)}>\n      <Boolean start="true"/>\n'
                f'    </ScalarVariable>\n'
                f'    <!-- {index + 2} --><ScalarVariable name={passed} '
                f'valueReference="{EXIT_PASSED + k}" causality="output" variability="discrete" '
                f'initial="calculated" description={quoteattr(counted)}>\n      <Integer/>\n'
                f'    </ScalarVariable>\n')
            index += 2
            outputs.append(f'      <Unknown index="{index}"/>\n')
            unknowns.append(f'      <Unknown index="{index}"/>\n')
        else:
            variables.append(
                f'    <Boolean name={opened} valueReference="{EXIT_OPEN + k}" causality="input" '
                f'variability="discrete" start="true" description={quoteattr(said)}/>\n'
                f'    <Int32 name={passed} valueReference="{EXIT_PASSED + k}" '
                f'causality="output" variability="discrete" description={quoteattr(counted)}/>\n')
            outputs.append(f'    <Output valueReference="{EXIT_PASSED + k}"/>\n')
            unknowns.append(f'    <InitialUnknown valueReference="{EXIT_PASSED + k}"/>\n')
    text = substitute(text, r"  </ModelVariables>", "".join(variables) + "  </ModelVariables>",
                      where)
    if version == "2":
        text = substitute(text, r"    </Outputs>", "".join(outputs) + "    </Outputs>", where)
        return substitute(text, r"    </InitialUnknowns>",
                          "".join(unknowns) + "    </InitialUnknowns>", where)
    last_output = text.rindex("<Output ")
    end = text.index("\n", last_output) + 1
    text = text[:end] + "".join(outputs) + text[end:]
    return substitute(text, r"  </ModelStructure>", "".join(unknowns) + "  </ModelStructure>",
                      where)


def package(version: str, library: pathlib.Path, out: pathlib.Path,
            scene: pathlib.Path | None = None) -> pathlib.Path:
    description = ROOT / "fmu" / f"fmi{version}" / "modelDescription.xml"
    text = description.read_text()
    if f'modelIdentifier="{IDENTIFIER}"' not in text:
        sys.exit(f"{description}: modelIdentifier is not {IDENTIFIER}")
    # FMI 3 sizes its arrays by the structural parameter n_people, whose start value (what
    # importers that read only the XML size the arrays with) is the shipped scene's count.
    people = people_of(tomllib.loads(ROOM.read_text()))
    for start in re.findall(r'<UInt64 name="n_people"[^>]* start="(\d+)"', text):
        if int(start) != people:
            sys.exit(f"{description}: n_people starts at {start}, the scene has {people} people")
    if scene is None:
        target, shipped, name = out / f"moreau-crowd-fmi{version}.fmu", ROOM, ROOM.name
    else:
        text = for_scene(version, text, scene, description)
        target, shipped = out / f"moreau-crowd-{scene.stem}-fmi{version}.fmu", scene
        name = resource_name(scene)
    tmp = target.with_suffix(".fmu.partial")
    # The release profile keeps line tables for profiling (Cargo.toml); the FMU ships the
    # library without them: 47 MB against 6 MB, and fmpy's cross-check refuses FMUs over 10 MB.
    stripped = target.with_suffix(".so.partial")
    subprocess.run(["strip", "--strip-debug", "-o", str(stripped), str(library)], check=True)
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("modelDescription.xml", text)
        z.write(stripped, f"binaries/{PLATFORMS[version]}/{IDENTIFIER}.so")
        z.write(shipped, f"resources/{name}")
        z.writestr("documentation/index.html",
                   "<html><body><p>moreau crowd FMU: see README.md of the moreau repository, "
                   "section 'The FMU'.</p></body></html>\n")
    stripped.unlink()
    tmp.replace(target)
    return target


def main() -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--fmi", choices=["2", "3", "all"], default="all")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "target" / "fmu")
    parser.add_argument("--no-build", action="store_true", help="use the library as built")
    parser.add_argument("--scene", type=pathlib.Path,
                        help="build the FMUs of this scene (its moving bodies become inputs)")
    args = parser.parse_args()
    if args.scene is not None and not args.scene.is_file():
        sys.exit(f"{args.scene}: no such scene file")
    if not args.no_build:
        subprocess.run(["cargo", "build", "--release", "--locked", "-p", "moreau-fmu"],
                       cwd=ROOT, check=True)
    library = ROOT / "target" / "release" / f"lib{IDENTIFIER}.so"
    if not library.is_file():
        sys.exit(f"{library} is missing: build it with cargo build --release -p moreau-fmu")
    args.out.mkdir(parents=True, exist_ok=True)
    versions = ["2", "3"] if args.fmi == "all" else [args.fmi]
    for v in versions:
        print(f"wrote {package(v, library, args.out, args.scene)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
