"""Per-pixel ray casting of the tool straight into the RAW (distorted) image.

Rays. For every raw pixel centre (u, v) the plumb-bob model is inverted once per
camera (``cv2.undistortPoints``, 50 iterations) to its unit-camera point
(x, y); the pixel's ray is D = (x, y, 1) from the optical centre, so the ray
parameter t of a hit P = t D is its depth Z (metres). Silhouettes are therefore
exactly those of the 3-D geometry seen through the distorting lens.

Primitives (camera frame, metres):

* finite cylinder: axis point c, unit axis a, radius r, axial range
  s in [s0, s1] (s = (P - c) . a), with a flat cap at s1. Near root of
      t^2 (D.D - (D.a)^2) - 2 t (D.c - (D.a)(c.a)) + (c.c - (c.a)^2 - r^2) = 0
* capsule: segment p -> q with radius r = cylinder body on [0, |q - p|]
  plus spheres at p and q:  t^2 D.D - 2 t D.m + m.m - r^2 = 0.

Painted markers are discs on the shaft surface: a shaft hit with link-4
coordinates (angle phi, axial z) belongs to marker k when
(r wrap(phi - phi_k))^2 + (z - z_k)^2 <= R_k^2 (arc length on the surface, so
the disc is painted, not floating; R_k: the point feature's ``radius``).

Work is limited to candidate pixels: each primitive's segment is clipped to
the view frustum (planes pushed out by r), and only pixels whose ray lies
within r / z_min (1 + rho^2) of the projected segment (unit-camera plane) are
intersected. Pixels on a silhouette or marker border are re-cast with 3 x 3
sub-pixel rays (bilinear in the ray table) and averaged (anti-aliasing).

Shading: point light at the optical centre (the endoscope), so light and view
directions coincide, l = v = -P/|P| and the Blinn-Phong half vector h = v:
    colour = gain(P) (base (k_a + k_d max(0, n.v)) + k_s max(0, n.v)^shininess)
with gain(P) = light (d_ref / |P|)^falloff times the vignetting at the pixel.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

MARKER_ID = 100
_SUB = np.array([-1.0, 0.0, 1.0]) / 3.0


@dataclass
class Material:
    """Base colour BGR (0..255), ambient, diffuse, specular strength (0..255), shininess."""

    color: tuple
    ka: float
    kd: float
    ks: float
    shininess: float


@dataclass
class Primitive:
    """kind 'cyl' (axial range [s0, s1] along a from p, cap at s1) or 'cap' (p -> q)."""

    kind: str
    p: np.ndarray
    a: np.ndarray
    r: float
    s0: float
    s1: float
    material: str
    shaft: bool = False  # carries the painted markers
    frame: tuple | None = None  # (origin, x, y, z) of the marker link (shaft only)

    @property
    def ends(self):
        return self.p + self.s0 * self.a, self.p + self.s1 * self.a


class RayTable:
    """Unit-camera coordinates (x, y) of every raw pixel, padded by one pixel."""

    def __init__(self, camera):
        H, W = camera.height, camera.width
        self.H, self.W, self.Wp = H, W, W + 2
        u, v = np.meshgrid(np.arange(-1, W + 1, dtype=np.float64), np.arange(-1, H + 1, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
        xy = cv2.undistortPoints(pts, camera.K, camera.dist,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
        xy = xy.reshape(H + 2, W + 2, 2)
        self.x = np.ascontiguousarray(xy[..., 0])
        self.y = np.ascontiguousarray(xy[..., 1])
        self.x32, self.y32 = self.x.astype(np.float32), self.y.astype(np.float32)
        inner = xy[1:-1, 1:-1]
        self.extent = (inner[..., 0].min(), inner[..., 0].max(), inner[..., 1].min(), inner[..., 1].max())
        self.camera = camera
        self.f = min(camera.fx, camera.fy)

    def sub_rays(self, idx: np.ndarray):
        """3x3 sub-pixel rays of padded flat pixels idx -> x, y of shape (len, 9)."""
        v, u = np.divmod(idx, self.Wp)
        du, dv = np.meshgrid(_SUB, _SUB)
        uf = u[:, None] + du.ravel()[None]
        vf = v[:, None] + dv.ravel()[None]
        u0 = np.clip(np.floor(uf).astype(np.int64), 0, self.Wp - 2)
        v0 = np.clip(np.floor(vf).astype(np.int64), 0, self.H)
        fu, fv = uf - u0, vf - v0

        def bil(T):
            return ((1 - fv) * ((1 - fu) * T[v0, u0] + fu * T[v0, u0 + 1])
                    + fv * ((1 - fu) * T[v0 + 1, u0] + fu * T[v0 + 1, u0 + 1]))

        return bil(self.x), bil(self.y)


# -- intersections (rays D = (x, y, 1)) -----------------------------------------------
def _sphere(x, y, dd, m, r):
    b = x * m[0] + y * m[1] + m[2]
    disc = b * b - dd * (m @ m - r * r)
    ok = disc >= 0
    t = (b - np.sqrt(np.where(ok, disc, 0.0))) / dd
    return np.where(ok & (t > 0), t, np.inf)


def _body(x, y, dd, c, a, r, s0, s1):
    da = x * a[0] + y * a[1] + a[2]
    ca = c @ a
    A = dd - da * da
    B = x * c[0] + y * c[1] + c[2] - da * ca
    C = c @ c - ca * ca - r * r
    disc = B * B - A * C
    ok = (disc >= 0) & (A > 1e-15)
    t = (B - np.sqrt(np.where(ok, disc, 0.0))) / np.where(ok, A, 1.0)
    s = t * da - ca
    return np.where(ok & (t > 0) & (s >= s0) & (s <= s1), t, np.inf), da


def intersect(prim: Primitive, x, y):
    """Depth t (inf on a miss) and part code (0 body, 1 cap/start sphere, 2 end sphere)."""
    dd = x * x + y * y + 1.0
    t, da = _body(x, y, dd, prim.p, prim.a, prim.r, prim.s0, prim.s1)
    part = np.zeros(t.shape, np.int8)
    if prim.kind == "cyl":
        e = prim.p + prim.s1 * prim.a
        ea = e @ prim.a
        safe = np.where(np.abs(da) > 1e-12, da, 1e-12)
        tc = ea / safe
        px, py, pz = tc * x - e[0], tc * y - e[1], tc - e[2]
        okc = (tc > 0) & (px * px + py * py + pz * pz <= prim.r ** 2)
        tc = np.where(okc, tc, np.inf)
        part = np.where(tc < t, 1, part).astype(np.int8)
        t = np.minimum(t, tc)
    else:
        for code, m in ((1, prim.p + prim.s0 * prim.a), (2, prim.p + prim.s1 * prim.a)):
            ts = _sphere(x, y, dd, m, prim.r)
            part = np.where(ts < t, code, part).astype(np.int8)
            t = np.minimum(t, ts)
    return t, part


def normals(prim: Primitive, P: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Unit outward normals (M, 3) at hit points P (M, 3)."""
    rel = P - prim.p
    n = rel - (rel @ prim.a)[:, None] * prim.a
    if prim.kind == "cyl":
        n = np.where((part == 1)[:, None], prim.a, n)
    else:
        n = np.where((part == 1)[:, None], P - (prim.p + prim.s0 * prim.a), n)
        n = np.where((part == 2)[:, None], P - (prim.p + prim.s1 * prim.a), n)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)


class ToolRenderer:
    """Renders primitives over a background, re-using one camera's ray table."""

    def __init__(self, camera, materials: dict, light: float = 1.0, falloff: float = 0.0,
                 d_ref: float = 0.1, vignette: np.ndarray | None = None, antialias: bool = True):
        self.rays = RayTable(camera)
        self.materials = materials
        self.light, self.falloff, self.d_ref = light, falloff, d_ref
        H, W = camera.height, camera.width
        n = (H + 2) * (W + 2)
        self.zbuf = np.full(n, np.inf)
        self.wid = np.zeros(n, np.int16)
        self.mark = np.zeros(n, np.int32)
        self.part = np.zeros(n, np.int8)
        self.stamp = 0
        self.vignette = None if vignette is None else np.pad(vignette, 1, mode="edge").ravel()
        self.antialias = antialias
        self.markers = np.zeros((0, 3))  # (phi, z, disc radius) on the shaft, set by the scene

    # -- candidate pixels --------------------------------------------------------------
    def _clip(self, prim: Primitive, z_near: float = 0.005):
        p, q = prim.ends
        xmin, xmax, ymin, ymax = self.rays.extent
        lo, hi = 0.0, 1.0
        planes = [(np.array([1.0, 0, -xmin]), prim.r), (np.array([-1.0, 0, xmax]), prim.r),
                  (np.array([0, 1.0, -ymin]), prim.r), (np.array([0, -1.0, ymax]), prim.r),
                  (np.array([0, 0, 1.0]), -z_near)]
        for nrm, off in planes:
            nrm = nrm / np.linalg.norm(nrm)
            f0, f1 = nrm @ p + off, nrm @ q + off  # want f0 + lam (f1 - f0) >= 0
            if f0 < 0 and f1 < 0:
                return None
            if f0 < 0:
                lo = max(lo, f0 / (f0 - f1))
            elif f1 < 0:
                hi = min(hi, f0 / (f0 - f1))
        if lo > hi:
            return None
        return p + lo * (q - p), p + hi * (q - p)

    def _candidates(self, prim: Primitive):
        seg = self._clip(prim)
        if seg is None:
            return None
        a3, b3 = seg
        a, b = a3[:2] / a3[2], b3[:2] / b3[2]
        rho2 = max(a @ a, b @ b)
        m = prim.r / min(a3[2], b3[2]) * (1.0 + rho2) * 1.05 + 1.5 / self.rays.f
        lam = np.linspace(0.0, 1.0, 24)[:, None]
        s = a3[None] + lam * (b3 - a3)[None]
        uv = self.rays.camera.project_raw(s)
        pad = m * self.rays.f * 1.1 + 2.0
        H, W = self.rays.H, self.rays.W
        u0 = int(max(0, np.floor(uv[:, 0].min() - pad)))
        u1 = int(min(W - 1, np.ceil(uv[:, 0].max() + pad)))
        v0 = int(max(0, np.floor(uv[:, 1].min() - pad)))
        v1 = int(min(H - 1, np.ceil(uv[:, 1].max() + pad)))
        if u0 > u1 or v0 > v1:
            return None
        X = self.rays.x32[v0 + 1:v1 + 2, u0 + 1:u1 + 2]
        Y = self.rays.y32[v0 + 1:v1 + 2, u0 + 1:u1 + 2]
        e = (b - a).astype(np.float32)
        L2 = float(e @ e)
        dx, dy = X - np.float32(a[0]), Y - np.float32(a[1])
        if L2 > 1e-18:
            lamp = np.clip((dx * e[0] + dy * e[1]) / np.float32(L2), 0, 1)
            dx -= lamp * e[0]
            dy -= lamp * e[1]
        rr, cc = np.nonzero(dx * dx + dy * dy <= np.float32(m * m))
        return (rr + v0 + 1) * self.rays.Wp + (cc + u0 + 1)

    # -- shading -----------------------------------------------------------------------
    def _markers(self, prim: Primitive, P: np.ndarray) -> np.ndarray:
        if prim.frame is None or len(self.markers) == 0:
            return np.zeros(len(P), bool)
        o, x4, y4, z4 = prim.frame
        z = (P - o) @ z4
        out = np.zeros(len(P), bool)
        near = np.nonzero((z >= (self.markers[:, 1] - self.markers[:, 2]).min())
                          & (z <= (self.markers[:, 1] + self.markers[:, 2]).max()))[0]
        if len(near) == 0:
            return out
        rel, z = P[near] - o, z[near]
        phi = np.arctan2(rel @ y4, rel @ x4)
        r = np.hypot(rel @ x4, rel @ y4)
        m = np.zeros(len(near), bool)
        for pk, zk, rk in self.markers:
            d = (phi - pk + np.pi) % (2 * np.pi) - np.pi
            m |= (r * d) ** 2 + (z - zk) ** 2 <= rk ** 2
        out[near] = m
        return out

    def _cast(self, prims, x, y):
        """Nearest hit over all primitives: (t, index or -1, part) for rays x, y."""
        best = np.full(x.shape, np.inf)
        which = np.full(x.shape, -1, np.int16)
        part = np.zeros(x.shape, np.int8)
        for k, pr in enumerate(prims):
            t, pt = intersect(pr, x, y)
            better = t < best
            best = np.where(better, t, best)
            which = np.where(better, k, which)
            part = np.where(better, pt, part)
        return best, which, part

    def _shade(self, prims, x, y, t, which, part, flat_idx):
        """Colours (M, 3) float and ids (M,) for hits (which >= 0)."""
        P = np.stack([t * x, t * y, t], -1)
        col = np.zeros((len(t), 3))
        ids = (which + 1).astype(np.int16)
        dist = np.linalg.norm(P, axis=1)
        v = -P / dist[:, None]
        gain = self.light * (self.d_ref / dist) ** self.falloff
        if self.vignette is not None:
            gain = gain * self.vignette[flat_idx]
        for k, pr in enumerate(prims):
            sel = np.nonzero(which == k)[0]
            if len(sel) == 0:
                continue
            n = normals(pr, P[sel], part[sel])
            ndv = np.clip(np.sum(n * v[sel], 1), 0.0, 1.0)
            mat = np.full(len(sel), 0)
            if pr.shaft:
                mk = self._markers(pr, P[sel]) & (part[sel] == 0)
                ids[sel[mk]] = MARKER_ID
                mat = mk.astype(int)
            for j, name in enumerate((pr.material, "marker") if pr.shaft else (pr.material,)):
                s2 = mat == j
                m = self.materials[name]
                c = (np.asarray(m.color, float)[None] * (m.ka + m.kd * ndv[s2])[:, None]
                     + (m.ks * ndv[s2] ** m.shininess)[:, None])
                col[sel[s2]] = c * gain[sel[s2]][:, None]
        return col, ids

    # -- frame ---------------------------------------------------------------------------
    def render(self, prims: list[Primitive], background: np.ndarray, probes=()):
        """Draw prims over ``background`` (H, W, 3 uint8, modified in place and returned).

        probes: raw pixels (u, v) whose hit depth (m, inf for none) and hit id
        (primitive index + 1, MARKER_ID, 0 for none) are returned: (depths, ids).
        Each primitive is intersected on its own candidate pixels only; a
        z-buffer over the padded image keeps the nearest hit. Afterwards
        ``self.drawn`` = (v, u, id) of the pixels written (id 0: an
        anti-aliased border pixel whose centre missed).
        """
        self.stamp += 1
        Wp = self.rays.Wp
        X, Y = self.rays.x.ravel(), self.rays.y.ravel()
        union = []
        for k, pr in enumerate(prims):
            c = self._candidates(pr)
            if c is None or len(c) == 0:
                continue
            t, pt = intersect(pr, X[c], Y[c])
            better = t < self.zbuf[c]
            cb = c[better]
            self.zbuf[cb] = t[better]
            self.wid[cb] = k + 1
            self.part[cb] = pt[better]
            new = c[self.mark[c] != self.stamp]
            self.mark[new] = self.stamp
            union.append(new)
        self.drawn = (np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int16))
        if not union:
            return background, (np.full(len(probes), np.inf), np.zeros(len(probes), int))
        allc = np.concatenate(union)
        xs, ys = X[allc], Y[allc]
        which = self.wid[allc].astype(np.int16) - 1
        t = self.zbuf[allc]
        part = self.part[allc]
        hit = which >= 0
        col, ids = self._shade(prims, xs[hit], ys[hit], t[hit], which[hit], part[hit], allc[hit])
        hidx = allc[hit]
        self.zbuf[hidx] = t[hit]
        self.wid[hidx] = ids
        colours = col
        out_idx = hidx
        if self.antialias:
            w = self.wid
            e = (w[allc] != w[allc - 1]) | (w[allc] != w[allc + 1]) | \
                (w[allc] != w[allc - Wp]) | (w[allc] != w[allc + Wp])
            eidx = allc[e]
            if len(eidx):
                sx, sy = self.rays.sub_rays(eidx)
                st, sw, sp = self._cast(prims, sx.ravel(), sy.ravel())
                rep = np.repeat(eidx, 9)
                sh = sw >= 0
                scol = np.zeros((len(st), 3))
                c2, _ = self._shade(prims, sx.ravel()[sh], sy.ravel()[sh], st[sh], sw[sh], sp[sh], rep[sh])
                scol[sh] = c2
                v, u = np.divmod(rep[~sh], Wp)
                scol[~sh] = background[v - 1, u - 1]
                ecol = scol.reshape(-1, 9, 3).mean(1)
                keep = ~e[hit]
                out_idx = np.concatenate([hidx[keep], eidx])
                colours = np.concatenate([col[keep], ecol])
        v, u = np.divmod(out_idx, Wp)
        background[v - 1, u - 1] = np.clip(colours + 0.5, 0, 255).astype(np.uint8)
        self.drawn = (v - 1, u - 1, self.wid[out_idx].copy())
        depth, pid = [], []
        for (pu, pv) in probes:
            iu, iv = int(round(pu)), int(round(pv))
            ok = 0 <= iu < self.rays.W and 0 <= iv < self.rays.H
            depth.append(self.zbuf[(iv + 1) * Wp + iu + 1] if ok else np.inf)
            pid.append(int(self.wid[(iv + 1) * Wp + iu + 1]) if ok else 0)
        self.zbuf[hidx] = np.inf
        self.wid[hidx] = 0
        return background, (np.array(depth), np.array(pid, int))
