"""Write quflow_map.npz: quflow's own map from vorticity matrices to functions.

quflow (github.com/klasmodin/quflow, commit b42eede; Modin & Viviani) is an
independent implementation of the Zeitlin model on the sphere.  For N = 5, 8,
16 and 32 this draws a random field, takes quflow's matrix of it (``shr2mat``)
and quflow's values of that matrix's field on its sampling grid
(``shr2fun(mat2shr(W), berezin=False)``, the plain Hoppe–Yau map that quflow's
dynamics advect), with quflow's energy and enstrophy of the matrix.  quflow
measures areas with dA/4π, so its energy and enstrophy are those of ∫ dA
divided by 4π.  tests/test_zeitlin.py reads the file; this script needs quflow
on the path and is not run by the tests:

    PYTHONPATH=/path/to/quflow python data/reference/quflow_map.py
"""

from pathlib import Path

import numpy as np
import quflow as qf

out = {}
rng = np.random.default_rng(2026)
for N in (5, 8, 16, 32):
    omega = rng.standard_normal(N * N)
    omega[0] = 0.0  # no l = 0 part (W traceless)
    W = qf.shr2mat(omega, N=N)
    theta, phi = qf.sphgrid(N)
    out[f"W_{N}"] = W
    out[f"theta_{N}"] = theta
    out[f"phi_{N}"] = phi
    out[f"fun_{N}"] = qf.shr2fun(qf.mat2shr(W), N=N, berezin=False)
    out[f"energy_{N}"] = qf.energy_euler(W)
    out[f"enstrophy_{N}"] = qf.enstrophy(W)
np.savez_compressed(Path(__file__).with_name("quflow_map.npz"), **out)
