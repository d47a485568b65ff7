"""``make fmus``: build the FMU catalogue into fmus/, check every FMU, and write fmus/README.md.

An observer FMU and its plant FMU for every example of every family (and the MuJoCo quarter-car
plant), each validated and run in our master, fmpy and ecospy, and alone in the FMU Compliance Checker
and fmusim where they are found (../shared/importers/): see :mod:`uiofmu.catalogue`.

    python examples/build_fmus.py                        # everything; writes fmus/README.md
    python examples/build_fmus.py --only quarter-car     # one example's FMUs and checks (no README)
    python examples/build_fmus.py --out /tmp/fmus        # another folder (its README.md there)
"""

import sys

from _common import ROOT, main_guard


def main():
    from uiofmu.catalogue import main as catalogue

    sys.exit(catalogue(sys.argv[1:], root=ROOT))


if __name__ == "__main__":
    main_guard(main)
