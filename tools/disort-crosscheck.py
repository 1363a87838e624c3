#!/usr/bin/env python3
"""Cross-check of dom's slab reference against DISORT (issue 13), run beside the tests, never in CI.

DISORT (Stamnes et al.; CDISORT through the `nanodisort` bindings on PyPI, GPL, so installed
by hand and never vendored: `pip install nanodisort`) solves the plane-parallel slab that
tests/slab_reference.rs solves with its own double-precision discrete ordinates. This prints
DISORT's reflected and transmitted fluxes per unit incident flux (the transmitted one includes
the unscattered beam) for the slabs the tests use; docs/dom.md records them beside ours.

Usage: tools/disort-crosscheck.py
"""
import math

import nanodisort as nd
from nanodisort.utils import phase_functions as pf


def slab(tau, albedo, g, mu0, nstr=32):
    s = nd.DisortState()
    s.nstr = nstr
    s.nlyr = 1
    s.nmom = nstr
    s.ntau = 2
    s.numu = 0
    s.nphi = 0
    s.usrtau = True
    s.usrang = False
    s.onlyfl = True
    s.lamber = True
    s.planck = False
    s.quiet = True
    s.allocate()
    s.dtauc[0] = tau
    s.ssalb[0] = albedo
    mom = pf.getmom(pf.PhaseFunction.HENYEY_GREENSTEIN, g, nstr)
    for k in range(nstr + 1):
        s.pmom[k, 0] = mom[k]
    s.utau[0] = 0.0
    s.utau[1] = tau
    s.umu0 = mu0
    s.phi0 = 0.0
    s.fbeam = 1.0 / mu0  # so that the incident flux mu0 fbeam is 1
    s.albedo = 0.0
    s.fisot = 0.0
    s.solve()
    incident = mu0 * s.fbeam
    r = s.flup[0] / incident
    t = (s.rfldir[1] + s.rfldn[1]) / incident
    return r, t


if __name__ == "__main__":
    print("tau  albedo  g     mu0   R (DISORT)  T (DISORT)")
    for tau, albedo, g, mu0 in [(2.0, 0.8, 0.0, 1.0), (2.0, 0.8, 0.75, 1.0), (1.0, 0.9, 0.5, 0.5), (2.0, 1.0, 0.75, 1.0)]:
        r, t = slab(tau, albedo, g, mu0)
        print(f"{tau:<4} {albedo:<7} {g:<5} {mu0:<5} {r:.6f}    {t:.6f}")
