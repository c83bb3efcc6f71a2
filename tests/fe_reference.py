"""Independent elastic reference for the mine scene (test T7): linear constant-strain triangles, plane
strain, on the same half-model geometry, solved with a sparse direct solver. It shares no code with
the hexagon method: the abutment stress and the released energy of the lattice are checked against it.

Units: SI per m of thickness. Tension positive. Incremental fields (the response to removing the
virgin support of the opening); add the virgin stress for totals.
"""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

def fe_excavation(W=26.0, H=9.5, seam=4.75, x_open=1.625, h=0.125, Er=50e9, Ec=5e9, nu=0.25, sx=-25e6 / 3,
                  sy=-25e6):
    """Linear CST plane strain: response to removing the virgin support of the opening [0,x_open]x[0,seam]."""
    nx, ny = int(round(W / h)), int(round(H / h))
    X, Y = np.meshgrid(np.arange(nx + 1) * h, np.arange(ny + 1) * h, indexing="ij")
    nid = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    tris = []
    for i in range(nx):
        for j in range(ny):
            xc, yc = (i + 0.5) * h, (j + 0.5) * h
            if xc < x_open and yc < seam:
                continue
            a, b, c, d = nid[i, j], nid[i + 1, j], nid[i + 1, j + 1], nid[i, j + 1]
            tris += [(a, b, c), (a, c, d)]
    T = np.array(tris)
    P = np.stack([X.ravel(), Y.ravel()], 1)
    xy = P[T]
    cen = xy.mean(1)
    E = np.where(cen[:, 1] < seam, Ec, Er)
    lam = E * nu / ((1 + nu) * (1 - 2 * nu)); mu = E / (2 * (1 + nu))
    x1, y1 = xy[:, 0, 0], xy[:, 0, 1]; x2, y2 = xy[:, 1, 0], xy[:, 1, 1]; x3, y3 = xy[:, 2, 0], xy[:, 2, 1]
    A2 = (x2 - x1) * (y3 - y1) - (x3 - x1) * (y2 - y1)
    b = np.stack([y2 - y3, y3 - y1, y1 - y2], 1) / A2[:, None]
    c = np.stack([x3 - x2, x1 - x3, x2 - x1], 1) / A2[:, None]
    B = np.zeros((len(T), 3, 6))
    B[:, 0, 0::2] = b; B[:, 1, 1::2] = c; B[:, 2, 0::2] = c; B[:, 2, 1::2] = b
    D = np.zeros((len(T), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = lam + 2 * mu; D[:, 0, 1] = D[:, 1, 0] = lam; D[:, 2, 2] = mu
    Ke = np.einsum("eki,ekl,elj->eij", B, D, B) * (0.5 * A2)[:, None, None]
    dof = np.stack([2 * T, 2 * T + 1], 2).reshape(len(T), 6)
    rows = np.repeat(dof, 6, 1).ravel(); cols = np.tile(dof, 6).ravel()
    ndof = 2 * len(P)
    K = sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(ndof, ndof))
    f = np.zeros(ndof)
    # unload: the removed material pushed on the wall with sigma0 . n_into_body; removing it applies -(that)
    # vertical face x = x_open, 0 <= y <= seam: normal into the opening n = (-1, 0); traction on body = sigma0.n
    ia = int(round(x_open / h)); js = int(round(seam / h))
    for j in range(js):
        for k in (nid[ia, j], nid[ia, j + 1]):
            f[2 * k] -= 0.5 * h * (sx * -1.0)
    for i in range(ia):
        for k in (nid[i, js], nid[i + 1, js]):
            f[2 * k + 1] -= 0.5 * h * (sy * -1.0)
    fixed = np.zeros(ndof, bool)
    fixed[2 * nid[0, :]] = True; fixed[2 * nid[-1, :]] = True; fixed[2 * nid[:, 0] + 1] = True
    used = np.zeros(ndof, bool); used[dof.ravel()] = True
    free = used & ~fixed
    u = np.zeros(ndof)
    u[free] = spla.spsolve(K[free][:, free].tocsc(), f[free])
    eps = np.einsum("eij,ej->ei", B, u[dof])
    sig = np.einsum("eij,ej->ei", D, eps)
    return dict(cen=cen, sig=sig, W=0.5 * f @ u, u=u, P=P)


def seam_profile(res, xs, y_mid=2.375, half=0.25):
    """Mean incremental sigma_yy [Pa] of the triangles in the band |y - y_mid| < half around each x."""
    cen, s = res["cen"], res["sig"]
    band = np.abs(cen[:, 1] - y_mid) < half + 0.01
    return np.array([s[band & (np.abs(cen[:, 0] - x) < half), 1].mean() for x in xs])
