"""``python -m dem analyse`` on a 3D dump of a frictional sphere packing written by LAMMPS itself
(issue 26): the mean field, the hierarchy's interval and the exact tensor, and the exact moduli
inside the interval.

The file, ``tests/data/sph3d_packing300.dump``, is the ``final.dump`` of the project's 3D LAMMPS
deck (300 spheres, radii 0.5 (1 +- 0.2), ``gran/hooke/history`` kn = kt = 1, mu 0.5, pD/kn = 1e-3;
``tests/data/README.md``): a per-atom ``dump custom id type radius x y z ... c_cn``, the file a
user writes, with LAMMPS's own contact count per sphere (``compute contact/atom``).

The references do not come from the code under test: the contacts and their count per sphere are
LAMMPS's (``c_cn``), and the mean field is recomputed here from the raw columns (brute-force
periodic contacts, the rattler rule as an explicit loop, the Voigt formulas of docs/spheres.md).
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DUMP = ROOT / "tests" / "data" / "sph3d_packing300.dump"


def _raw(path):
    """(positions (N, 3), radii (N,), box lengths (3,), LAMMPS's contact counts (N,)) read with
    numpy from the dump's text (orthogonal box; not dem.io)."""
    lines = path.read_text().splitlines()
    lo_hi = np.array([[float(v) for v in lines[k].split()[:2]] for k in (5, 6, 7)])
    cols = lines[8].split()[2:]
    a = np.array([[float(v) for v in ln.split()] for ln in lines[9:]])
    a = a[np.argsort(a[:, cols.index("id")])]
    x = a[:, [cols.index(c) for c in ("x", "y", "z")]]
    return x, a[:, cols.index("radius")], lo_hi[:, 1] - lo_hi[:, 0], a[:, cols.index("c_cn")].astype(int)


def _brute_contacts(x, r, L):
    """Pairs (i < j) with |x_j - x_i| <= r_i + r_j under the minimum image, and their branch
    lengths."""
    d = x[None, :, :] - x[:, None, :]
    d -= L * np.round(d / L)
    dist = np.linalg.norm(d, axis=2)
    i, j = np.nonzero(np.triu(dist <= r[:, None] + r[None, :], k=1))
    return i, j, dist[i, j]


def _voigt(x, r, L, kn=1.0, kt=1.0):
    """The mean field of docs/spheres.md from scratch: rattlers removed iteratively (fewer than 2
    contacts, every contact frictional), K = sum kn l^2 / (9V), G = sum (2kn + 3kt) l^2 / (30V)."""
    i, j, l = _brute_contacts(x, r, L)
    keep = np.ones(len(x), bool)
    while True:
        act = keep[i] & keep[j]
        cnt = np.bincount(np.r_[i[act], j[act]], minlength=len(x))
        drop = keep & (cnt < 2)
        if not drop.any():
            break
        keep &= ~drop
    act = keep[i] & keep[j]
    V = float(np.prod(L))
    l2 = l[act] ** 2
    return kn * l2.sum() / (9 * V), (2 * kn + 3 * kt) * l2.sum() / (30 * V), int((~keep).sum())


def _cli(*args):
    out = subprocess.run([sys.executable, "-m", "dem", "analyse", str(DUMP), "--kn", "1", "--kt", "1",
                          *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_the_file_is_lammps_s_packing():
    """The network dem.io builds has LAMMPS's own contacts, sphere by sphere (compute contact/atom)."""
    from dem import io
    x, r, L, cn = _raw(DUMP)
    i, j, _ = _brute_contacts(x, r, L)
    assert len(x) == 300 and np.array_equal(np.bincount(np.r_[i, j], minlength=300), cn)
    cfg = io.read(DUMP)
    assert cfg.dim == 3
    net = cfg.sorted_by_id().network(kn=1.0, kt=1.0)
    assert np.array_equal(np.bincount(net.pairs.ravel(), minlength=300), cn)
    assert net.n_contacts == cn.sum() // 2 == 600


def test_dem_analyse_prints_mean_field_interval_exact_and_containment():
    """End to end, the command line: the JSON's mean field equals the one recomputed from the raw
    columns, the hierarchy's interval is certified and holds the exact K and G, and the table has
    the three rows and says so."""
    x, r, L, _ = _raw(DUMP)
    K_mf, G_mf, n_rat = _voigt(x, r, L)
    res = json.loads(_cli("--json"))
    st, hi, ex = res["structural"], res["hierarchy"], res["stiffness"]
    assert st["K_affine"] == pytest.approx(K_mf, rel=1e-12) and st["G_affine"] == pytest.approx(G_mf, rel=1e-12)
    assert st["n_rattlers"] == n_rat == ex["n_rattlers"]
    assert res["comparison"]["K_mf_over_exact"] == pytest.approx(K_mf / ex["K"], rel=1e-12)
    assert hi["certified"] and hi["valid"] and hi["K_lower"] is not None
    for m in ("K", "G"):
        assert hi[f"{m}_lower"] <= ex[m] <= hi[f"{m}_upper"]
        assert (hi[f"{m}_upper"] - hi[f"{m}_lower"]) <= 0.01 * hi[f"{m}_upper"]
        assert ex[m] < hi[f"{m}_first_order"] < st[f"{m}_affine"]     # the mean field is too stiff
    assert np.shape(ex["C_mandel"]) == (6, 6)
    assert any("'radius'" in n and "the hierarchy uses the same arms" in n for n in res["notes"])
    text = _cli()
    assert "mean field (Voigt, fabric)" in text and "rigorous lower bound" in text
    assert "exact (dem.analysis.stiffness)" in text and "exact C (Mandel [xx, yy, zz" in text
    assert "exact inside the hierarchy's interval: K yes, G yes" in text
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("mean field (Voigt"))
    assert float(row.split()[4]) == pytest.approx(K_mf, rel=1e-5)


def test_the_hierarchy_brackets_the_exact_tensor_of_its_own_spin_arms():
    """The hierarchy and the exact solver on the same kinematics: with either spin arm (LAMMPS's
    radius, the theory's contact point) the exact K and G lie in the interval at tol 1e-3, and the
    two arms give tensors that differ by more than round-off (so the arm reaches the hierarchy)."""
    import warnings

    from dem import io
    from dem.analysis.stiffness import stiffness
    from microhom.hierarchy import relaxation_hierarchy
    net = io.read(DUMP).network(kn=1.0, kt=1.0)
    got = {}
    for arm in ("radius", "contact"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            h = relaxation_hierarchy(net, tol=1e-3, spin_arm=arm)
        ex = stiffness(net, spin_arm=arm)
        assert h.certified
        for m in ("K", "G"):
            e = getattr(h, m)
            assert e.lower <= getattr(ex, m) <= e.upper
        got[arm] = (h, ex)
    # the arms differ by 2.6e-4 in G here, and so do the hierarchy's first orders (every sphere
    # relaxed alone: the spins enter) while its order 0 (affine, no spin) is the same
    assert abs(got["radius"][1].G / got["contact"][1].G - 1) > 1e-4
    (hr, _), (hc, _) = got["radius"], got["contact"]
    assert abs(hr.G_first_order / hc.G_first_order - 1) > 1e-5
    np.testing.assert_array_equal(hr.C_orders[0], hc.C_orders[0])
    with pytest.raises(ValueError, match="spin_arm"):
        relaxation_hierarchy(net, spin_arm="surface")


def test_contacts_of_a_lammps_3d_file_are_lammps_s(tmp_path):
    """A pair at a gap of 5e-10 D is no contact for LAMMPS (compute contact/atom: d <= r_i + r_j)
    and none for dem analyse on a 3D LAMMPS file; an overlap of 1e-12 D is one."""
    from dem.analysis.analyse import load_network
    rows = [(1, 0.5, 1.0, 1.0, 1.0), (2, 0.5, 2.0 + 5e-10, 1.0, 1.0),       # gap 5e-10
            (3, 0.5, 1.0, 3.0, 2.0), (4, 0.5, 1.0, 4.0 - 1e-12, 2.0)]       # overlap 1e-12
    text = ("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n4\nITEM: BOX BOUNDS pp pp pp\n"
            + "0 5\n" * 3 + "ITEM: ATOMS id type radius x y z\n"
            + "".join(f"{i} 1 {r!r} {x!r} {y!r} {z!r}\n" for i, r, x, y, z in rows))
    path = tmp_path / "pair.dump"
    path.write_text(text)
    net, info = load_network(path, kn=1.0, kt=1.0)
    assert net.dim == 3 and net.n_contacts == 1
    assert sorted(net.pairs[0].tolist()) == [2, 3]
    assert any("LAMMPS's own test" in n for n in info["notes"])
