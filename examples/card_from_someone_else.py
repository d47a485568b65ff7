"""A design card from someone else: what `uiofmu build` does with it.

A colleague sends a card. It may have been edited on the way, by mistake or on purpose. The
script designs seed 000 Example 1, then builds four versions of its card with the command line:

1. the card as designed: builds;
2. a name that closes a C comment and carries code: builds, and the code is nowhere in the FMU's
   sources (the name reaches the FMU only as an escaped string and a whitelisted identifier);
3. ``certificate.verified`` still true but a gain made faster than the design: refused, because
   `build` re-checks the certificate at the card's own matrices;
4. a family that would rewrite the pythonfmu slave's class line: refused by the card schema.

An existing FMU at the output path survives every refused build. Writes into
examples/out/card_from_someone_else/ ($UIOFMU_EXAMPLES_OUT/card_from_someone_else/ when set).
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

from _common import OUT, ROOT


def build(card: dict, out_dir, name: str, fmu: str = "observer.fmu") -> subprocess.CompletedProcess:
    path = out_dir / f"{name}.json"
    path.write_text(json.dumps(card))
    return subprocess.run([sys.executable, "-m", "uiofmu", "build", str(path), "-o", str(out_dir / fmu)],
                          capture_output=True, text=True)


def main():
    out = OUT / "card_from_someone_else"
    out.mkdir(parents=True, exist_ok=True)
    design = subprocess.run([sys.executable, "-m", "uiofmu", "design", str(ROOT / "examples" / "seed000_example1.toml"),
                             "-o", str(out / "designed.json")], capture_output=True, text=True)
    if design.returncode:
        sys.exit(design.stderr)
    card = json.loads((out / "designed.json").read_text())

    res = build(card, out, "as_designed")
    print(f"1. as designed               exit {res.returncode}: {res.stdout.strip() or res.stderr.strip()}")
    before = (out / "observer.fmu").read_bytes()

    hostile = dict(card, name='x **// __attribute__((constructor)) static void f(void) { system("touch PWNED"); } /*')
    res = build(hostile, out, "hostile_name", "hostile.fmu")
    with zipfile.ZipFile(out / "hostile.fmu") as z:
        source = z.read("sources/design_data.c").decode()
    print(f"2. comment-closing name       exit {res.returncode}; payload in the C sources: "
          f"{'__attribute__' in source or 'system(' in source}; model identifier "
          f"{source.split('.model = ')[1].split(',')[0]}")

    forged = json.loads(json.dumps(card))
    forged["matrices"]["N"] = [[0.5 * v for v in row] for row in forged["matrices"]["N"]]
    res = build(forged, out, "forged_gain")
    print(f"3. forged gain, verified=true exit {res.returncode}: {res.stderr.strip()}")

    injected = dict(card, family="A(__import__('os').system('touch PWNED') or Fmi2Slave):#")
    res = build(injected, out, "injected_family")
    print(f"4. code as the family         exit {res.returncode}: {res.stderr.strip()[:160]}")

    kept = (out / "observer.fmu").read_bytes() == before
    pwned = any((folder / "PWNED").exists() for folder in (out, ROOT, Path.cwd()))   # where the builds ran
    print(f"the FMU built in step 1 is unchanged after the refused builds: {kept}; PWNED exists: {pwned}")


if __name__ == "__main__":
    main()
