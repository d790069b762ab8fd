"""Write a small multi-loop B(H) file for the README's joint-fit command: three closed
loops of the classic Jiles–Atherton model (Table 1 material, no actuator) at field
amplitudes 10, 20 and 40 kA/m, 81 samples each, columns ``loop, H [A/m], B [T]``.

    python examples/make_bh_loops.py bh_loops.csv
    jaxhyst identify bh_loops.csv --joint --per-loop c --output B --variant classic
"""

import sys

import numpy as np

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR

MU0 = 4e-7 * np.pi


def main(path: str = "bh_loops.csv") -> None:
    rows = ["loop,H [A/m],B [T]"]
    for i, amplitude in enumerate((10e3, 20e3, 40e3)):
        H = amplitude * np.cos(2 * np.pi * np.arange(81) / 80)
        sim = jh.simulate(jh.TABLE1_TRUE, NO_ACTUATOR, jh.drive_from_record(None, H),
                          variant=jh.ClassicJA(), substeps=4)
        B = MU0 * (H + np.asarray(sim.observed("M")))
        rows += [f"{i},{h:.6g},{b:.6g}" for h, b in zip(H, B, strict=True)]
    with open(path, "w") as fh:
        fh.write("\n".join(rows) + "\n")
    print(f"wrote {path}: 3 loops x 81 samples")


if __name__ == "__main__":
    main(*sys.argv[1:2])
