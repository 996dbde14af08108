"""MuJoCo states to RGB frames: MuJoCo's own renderer, or a matplotlib drawing of the geoms.

Both renderers look at the motion through the same orthographic camera
(:class:`View`), chosen from the poses to be drawn:

- *up* is against gravity (world z when the model has none);
- the view direction is the horizontal direction along which the geoms
  move least (the smallest principal axis of their horizontal displacements
  over all frames), so a system moving in a vertical plane is seen face on:
  the bundled pendulum and cart-pole in the x-z plane;
- the frame fits every pose drawn (geom bounding spheres), with a margin.

:class:`MujocoRenderer` is ``mujoco.Renderer`` on the OpenGL backend that
``MUJOCO_GL`` selects (``egl`` on GPU machines, ``glfw`` on desktops, the
default, ``osmesa``); :func:`make_renderer` falls back to
:class:`GeomRenderer` when no context can be created. The fallback runs
``mj_kinematics`` on each pose and draws every visible geom (groups 0-2, as
MuJoCo shows by default) as its silhouette under the orthographic
projection, in the model's colours (``geom_rgba``, or the material's),
farthest first: spheres and ellipsoids as ellipses, capsules as stadia,
cylinders and boxes as the convex hull of their ends or corners, meshes as
the convex hull of their vertices, height fields by their bounding box, and
planes as a floor. Models without a plane get a floor line under the
motion; slide joints get their rail and hinges a pivot dot.

Each pose to draw is a :class:`Layer`: the main pose opaque, others (the
target, noisy episodes) translucent copies behind it.
"""

from __future__ import annotations

import copy
import math
import os
import warnings
from typing import NamedTuple, Optional, Sequence

import mujoco
import numpy as np

RENDERERS = ("auto", "mujoco", "matplotlib")

_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)
_BACKGROUND = (0.965, 0.97, 0.978)
_FLOOR = (0.86, 0.87, 0.885)
_FLOOR_LINE = (0.45, 0.47, 0.5)


class _GEOM:
    """mjtGeom values as plain ints (a pybind enum does not compare equal to a NumPy integer)."""

    mjGEOM_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
    mjGEOM_HFIELD = int(mujoco.mjtGeom.mjGEOM_HFIELD)
    mjGEOM_SPHERE = int(mujoco.mjtGeom.mjGEOM_SPHERE)
    mjGEOM_CAPSULE = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
    mjGEOM_ELLIPSOID = int(mujoco.mjtGeom.mjGEOM_ELLIPSOID)
    mjGEOM_CYLINDER = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
    mjGEOM_BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
    mjGEOM_MESH = int(mujoco.mjtGeom.mjGEOM_MESH)
    mjGEOM_SDF = int(mujoco.mjtGeom.mjGEOM_SDF)


class View(NamedTuple):
    """An orthographic camera: image x along ``right``, image y along ``up``."""

    right: np.ndarray  # [3]
    up: np.ndarray  # [3]
    forward: np.ndarray  # [3] the view direction (into the image)
    center: np.ndarray  # [3] the world point at the image centre
    half_width: float  # world units from the centre to the image edge
    half_height: float
    floor: Optional[float]  # height (along up, relative to center) of the floor line; None with a plane geom
    top: bool = False  # looking down (motion in a horizontal plane); else from the side, up against gravity

    def project(self, p: np.ndarray) -> np.ndarray:
        """World points [..., 3] to image-plane coordinates [..., 2] (world units)."""
        d = p - self.center
        return np.stack([d @ self.right, d @ self.up], axis=-1)

    def depth(self, p: np.ndarray) -> np.ndarray:
        return (p - self.center) @ self.forward


class Layer(NamedTuple):
    """One pose to draw: qpos [nq], an opacity and an optional colour tint."""

    qpos: np.ndarray
    alpha: float = 1.0
    tint: Optional[tuple[float, float, float]] = None  # blend the geom colours towards this
    static: bool = True  # also draw the geoms that do not move (world, welded bodies)


def _kinematics(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray) -> None:
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)


def visible_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Indices of the geoms MuJoCo shows by default: groups 0-2, not fully transparent."""
    rgba = geom_colors(model)
    return np.flatnonzero((model.geom_group < 3) & (rgba[:, 3] > 0))


def geom_colors(model: mujoco.MjModel) -> np.ndarray:
    """[ngeom, 4] RGBA of each geom: its material's where it has one and its
    own rgba is MuJoCo's default (as MuJoCo colours it), else its own."""
    rgba = np.array(model.geom_rgba, dtype=float)
    for g in range(model.ngeom):
        mat = model.geom_matid[g]
        if mat >= 0 and np.allclose(model.geom_rgba[g], _DEFAULT_RGBA):
            rgba[g] = model.mat_rgba[mat]
    return rgba


def _up_axis(model: mujoco.MjModel) -> np.ndarray:
    g = np.array(model.opt.gravity, dtype=float)
    n = np.linalg.norm(g)
    return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])


def _geom_points(model, data, finite, poses) -> tuple[list[np.ndarray], list[np.ndarray]]:
    pts, radii = [], []
    for q in poses:
        for qpos in np.atleast_2d(np.asarray(q, dtype=float)):
            if not np.all(np.isfinite(qpos)):
                continue
            _kinematics(model, data, qpos)
            pts.append(np.array(data.geom_xpos[finite]))
            radii.append(np.array(model.geom_rbound[finite]))
    return pts, radii


def choose_view(
    model: mujoco.MjModel,
    poses: Sequence[np.ndarray],
    width: int,
    height: int,
    margin: float = 0.12,
    extra: Sequence[np.ndarray] = (),
    header: int = 0,
) -> View:
    """The camera for drawing ``poses`` (arrays of qpos, [N_i, nq] each) at
    width x height pixels (see the module docstring). ``extra`` poses (noisy
    episodes) widen the frame by at most half its size on each side and do
    not steer the view direction. The top ``header`` pixels are left free
    (for text)."""
    data = mujoco.MjData(model)
    geoms = visible_geoms(model)
    finite = geoms[model.geom_type[geoms] != _GEOM.mjGEOM_PLANE]
    up = _up_axis(model)
    # Two horizontal axes: world x projected off `up` (or y when up is along x).
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    h1 = ref - (ref @ up) * up
    h1 /= np.linalg.norm(h1)
    h2 = np.cross(up, h1)
    pts, radii = _geom_points(model, data, finite, poses)
    if not pts or finite.size == 0:  # nothing finite to frame: MuJoCo's extent around the origin
        pts = [np.zeros((1, 3))]
        radii = [np.array([model.stat.extent])]
    P = np.stack(pts)  # [F, G, 3]
    rad = np.stack(radii)
    disp = (P - P.mean(axis=0)).reshape(-1, 3)
    H = np.stack([disp @ h1, disp @ h2], axis=1)
    w, v = np.linalg.eigh(H.T @ H)
    vertical = float(np.sum((disp @ up) ** 2))
    top = w[0] > 1e-12 and vertical < 0.25 * w[0]  # moves in a horizontal plane, spread both ways
    if top:  # look down, world h2 (y for z-up models) up the image
        forward, image_up = -up, h2
    else:
        if w[1] <= 1e-12 * max(1.0, abs(w).max()) or w[1] - w[0] <= 1e-9 * w[1]:
            a, b = 0.0, 1.0  # no preferred vertical plane: look along h2 (world y for z-up models)
        else:
            a, b = v[:, 0]  # the horizontal direction of least motion
        forward, image_up = a * h1 + b * h2, up
    right = np.cross(forward, image_up)
    if not top and right[np.argmax(np.abs(right))] < 0:  # keep image right along a positive world axis
        forward, right = -forward, -right
    up = image_up

    def box(P, rad):
        flat, r = P.reshape(-1, 3), rad.reshape(-1)
        x, y = flat @ right, flat @ up
        return np.array([np.min(x - r), np.min(y - r)]), np.array([np.max(x + r), np.max(y + r)])

    lo, hi = box(P, rad)
    flat = P.reshape(-1, 3)
    if finite.size:
        e_pts, e_rad = _geom_points(model, data, finite, extra)
        if e_pts:
            e_lo, e_hi = box(np.stack(e_pts), np.stack(e_rad))
            span = hi - lo
            lo, hi = np.maximum(np.minimum(lo, e_lo), lo - span / 2), np.minimum(np.maximum(hi, e_hi), hi + span / 2)
    has_plane = bool(np.any(model.geom_type[geoms] == _GEOM.mjGEOM_PLANE))
    span = np.maximum(hi - lo, 1e-3 * max(1.0, float(model.stat.extent)))
    floor_world = None if has_plane or top else lo[1] - 0.04 * span.max()
    if floor_world is not None:
        lo[1] = floor_world - 0.02 * span.max()
    mid = (lo + hi) / 2
    half = (hi - lo) / 2 * (1 + margin) + 0.02 * span.max()
    content = max(1, height - int(header))
    aspect = width / content
    if half[0] / half[1] < aspect:
        half[0] = half[1] * aspect
    else:
        half[1] = half[0] / aspect
    total = half[1] * height / content  # the whole image's half-height: the content sits below the header
    mid[1] += total - half[1]
    half[1] = total
    depth_mid = float(np.mean(flat @ forward))
    center = mid[0] * right + mid[1] * up + depth_mid * forward
    floor = None if floor_world is None else float(floor_world - mid[1])
    return View(right, up, forward, center, float(half[0]), float(half[1]), floor, bool(top))


# ------------------------------------------------------------ silhouettes
def _circle(n: int = 24) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.stack([np.cos(t), np.sin(t)], axis=1)


_UNIT = _circle(24)


def convex_hull(points: np.ndarray) -> np.ndarray:
    """The 2-D convex hull of points [N, 2], counter-clockwise (monotone chain)."""
    pts = sorted(set(map(tuple, np.round(np.asarray(points, dtype=float), 12).tolist())))
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def half(seq):
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2:
                (ax, ay), (bx, by) = out[-2], out[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0:
                    break
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _ellipse(view: View, c: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The projection of {c + M s : |s| <= 1} (M [3, 3]) as a polygon."""
    A = np.stack([view.right, view.up]) @ M  # [2, 3]
    S = A @ A.T
    w, v = np.linalg.eigh(S)
    L = v * np.sqrt(np.maximum(w, 0.0))
    return view.project(c) + _UNIT @ L.T


def _disc_points(c: np.ndarray, R: np.ndarray, r: float) -> np.ndarray:
    return c + r * (_UNIT[:, :1] * R[:, 0] + _UNIT[:, 1:] * R[:, 1])


def _mesh_vertices(model: mujoco.MjModel, mesh: int, limit: int = 400) -> np.ndarray:
    adr, n = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    verts = np.array(model.mesh_vert[adr : adr + n], dtype=float)
    if n > limit:  # a hull of a spread-out subset is close enough for a silhouette
        verts = verts[:: int(math.ceil(n / limit))]
    return verts


def silhouette(model: mujoco.MjModel, view: View, g: int, pos: np.ndarray, R: np.ndarray) -> Optional[np.ndarray]:
    """Polygon [K, 2] of geom ``g`` at position ``pos`` [3], orientation ``R``
    [3, 3], projected by ``view``; None for a plane (drawn as a floor) or an
    unsupported type."""
    t = int(model.geom_type[g])
    size = np.array(model.geom_size[g], dtype=float)
    G = _GEOM
    if t == G.mjGEOM_SPHERE:
        return _ellipse(view, pos, size[0] * np.eye(3))
    if t == G.mjGEOM_ELLIPSOID:
        return _ellipse(view, pos, R * size[:3])
    if t == G.mjGEOM_CAPSULE:
        ends = [pos + s * size[1] * R[:, 2] for s in (-1, 1)]
        pts = np.concatenate([view.project(e) + size[0] * _UNIT for e in ends])
        return convex_hull(pts)
    if t == G.mjGEOM_CYLINDER:
        ends = [pos + s * size[1] * R[:, 2] for s in (-1, 1)]
        pts = np.concatenate([view.project(_disc_points(e, R, size[0])) for e in ends])
        return convex_hull(pts)
    if t == G.mjGEOM_BOX:
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float) * size
        return convex_hull(view.project(pos + corners @ R.T))
    if t == G.mjGEOM_MESH and model.geom_dataid[g] >= 0:
        verts = _mesh_vertices(model, model.geom_dataid[g])
        return convex_hull(view.project(pos + verts @ R.T))
    if t in (G.mjGEOM_HFIELD, G.mjGEOM_MESH, G.mjGEOM_SDF):  # their bounding box
        aabb = np.array(model.geom_aabb[g], dtype=float)
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float) * aabb[3:]
        return convex_hull(view.project(pos + (aabb[:3] + corners) @ R.T))
    return None


# -------------------------------------------------------------- renderers
class GeomRenderer:
    """The matplotlib fallback: every visible geom's silhouette (module docstring)."""

    name = "matplotlib"

    def __init__(self, model: mujoco.MjModel, view: View, width: int, height: int) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import PolyCollection
        from matplotlib.figure import Figure

        self.model, self.view, self.width, self.height = model, view, width, height
        self.data = mujoco.MjData(model)
        self.geoms = visible_geoms(model)
        self.rgba = geom_colors(model)
        self.static = model.body_weldid[model.geom_bodyid] == 0  # geoms that never move
        dpi = 100
        self.fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor=_BACKGROUND)
        self.canvas = FigureCanvasAgg(self.fig)
        ax = self.fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.set_axis_off()
        ax.set_xlim(-view.half_width, view.half_width)
        ax.set_ylim(-view.half_height, view.half_height)
        ax.set_facecolor(_BACKGROUND)
        self.ax = ax
        self.scale = view.half_height / (height / 2)  # world units per pixel
        self._floor()
        self._rails()
        self.polys = PolyCollection([], closed=True, linewidths=0.9, antialiased=True, zorder=3)
        ax.add_collection(self.polys)

    def _floor(self) -> None:
        ax, v = self.ax, self.view
        W = v.half_width
        if v.floor is not None:
            ax.fill_between([-W, W], -v.half_height, v.floor, color=_FLOOR, lw=0, zorder=0)
            ax.plot([-W, W], [v.floor, v.floor], color=_FLOOR_LINE, lw=1.2, zorder=1)
            return
        _kinematics(self.model, self.data, self.model.qpos0)
        for g in self.geoms:
            if self.model.geom_type[g] != _GEOM.mjGEOM_PLANE:
                continue
            self._plane(g, np.array(self.data.geom_xpos[g]), np.array(self.data.geom_xmat[g]).reshape(3, 3))

    def _plane(self, g: int, pos: np.ndarray, R: np.ndarray) -> None:
        """A plane seen edge on: a line through it and its back side shaded;
        a plane facing the camera (a wall) is left out."""
        v = self.view
        normal = R[:, 2]
        n2 = np.array([normal @ v.right, normal @ v.up])
        if np.linalg.norm(n2) < 0.3:  # seen face on (a floor from above, a wall): its rectangle
            if normal @ v.forward < 0:  # facing the camera
                half = np.array(self.model.geom_size[g][:2], dtype=float)
                half = np.where(half > 0, half, 4 * max(v.half_width, v.half_height))
                corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
                corners[:, :2] *= half
                poly = v.project(pos + corners @ R.T)
                colour = np.clip(0.45 * self.rgba[g, :3] + 0.55 * np.array(_FLOOR), 0, 1)
                self.ax.fill(poly[:, 0], poly[:, 1], color=colour, lw=0, zorder=0)
            return
        n2 /= np.linalg.norm(n2)
        along = np.array([-n2[1], n2[0]])
        c = v.project(pos)
        half = np.array(self.model.geom_size[g][:2], dtype=float)
        reach = 4 * max(v.half_width, v.half_height)
        if half[0] <= 0 or half[1] <= 0:
            extent = reach
        else:  # the projected half-length of the finite rectangle along the line
            axes = np.stack([[R[:, i] @ v.right, R[:, i] @ v.up] for i in (0, 1)])
            extent = float(np.sum(half * np.abs(axes @ along)))
        a, b = c - extent * along, c + extent * along
        if n2[1] > 0.9 and not v.top:  # a floor seen from the side: shade what lies under it
            deep = reach * n2
            colour = np.clip(0.55 * self.rgba[g, :3] + 0.45 * np.array(_FLOOR), 0, 1)
            xs = [a[0], b[0], b[0] - deep[0], a[0] - deep[0]]
            ys = [a[1], b[1], b[1] - deep[1], a[1] - deep[1]]
            self.ax.fill(xs, ys, color=colour, lw=0, zorder=0)
            self.ax.plot([a[0], b[0]], [a[1], b[1]], color=_FLOOR_LINE, lw=1.2, zorder=1)
        else:  # a wall seen edge on
            colour = np.clip(0.7 * self.rgba[g, :3], 0, 1)
            self.ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=2.0, zorder=1, solid_capstyle="butt")

    def _rails(self) -> None:
        """A line along the axis of each carriage's slide joint, through its range (or across the frame)."""
        m = self.model
        slide = m.jnt_type == int(mujoco.mjtJoint.mjJNT_SLIDE)
        per_body = np.bincount(m.jnt_bodyid[slide], minlength=m.nbody)
        # a carriage (a body on one slide joint); bodies sliding in x and y are free floaters
        slides = [j for j in np.flatnonzero(slide) if per_body[m.jnt_bodyid[j]] == 1]
        if not slides:
            return
        _kinematics(m, self.data, m.qpos0)
        for j in slides:
            anchor = np.array(self.data.xanchor[j])
            axis = np.array(self.data.xaxis[j])
            a2 = np.array([axis @ self.view.right, axis @ self.view.up])
            if np.linalg.norm(a2) < 0.3:  # moving towards the camera: no visible rail
                continue
            reach = 4 * max(self.view.half_width, self.view.half_height)
            lo, hi = (m.jnt_range[j] - self.data.qpos[m.jnt_qposadr[j]]) if m.jnt_limited[j] else (-reach, reach)
            ends = self.view.project(np.stack([anchor + lo * axis, anchor + hi * axis]))
            self.ax.plot(ends[:, 0], ends[:, 1], color=(0.35, 0.36, 0.38), lw=2.0, zorder=2, solid_capstyle="butt")

    def _layer_polys(self, layer: Layer, polys: list, faces: list, edges: list, pivots: bool) -> None:
        m, d, v = self.model, self.data, self.view
        _kinematics(m, d, layer.qpos)
        items = []
        for g in self.geoms:
            if (self.static[g] and not layer.static) or m.geom_type[g] == _GEOM.mjGEOM_PLANE:
                continue
            pos = np.array(d.geom_xpos[g])
            poly = silhouette(m, v, g, pos, np.array(d.geom_xmat[g]).reshape(3, 3))
            if poly is None or len(poly) < 3:
                continue
            items.append((float(v.depth(pos)), poly, self.rgba[g]))
        items.sort(key=lambda it: -it[0])  # farthest first
        for _, poly, rgba in items:
            rgb = np.array(rgba[:3])
            if layer.tint is not None:
                rgb = 0.45 * rgb + 0.55 * np.array(layer.tint)
            alpha = float(rgba[3]) * layer.alpha
            polys.append(poly)
            faces.append((*rgb, alpha))
            edges.append((*(0.55 * rgb), min(1.0, 1.3 * alpha)) if layer.alpha >= 1 else (*rgb, 0.0))
        if pivots:
            r = 2.2 * self.scale
            for j in np.flatnonzero(m.jnt_type == int(mujoco.mjtJoint.mjJNT_HINGE)):
                axis = np.array(d.xaxis[j])
                if abs(axis @ v.forward) < 0.7:  # only hinges that turn in the image plane
                    continue
                polys.append(v.project(np.array(d.xanchor[j])) + r * _UNIT)
                faces.append((0.2, 0.2, 0.22, 1.0))
                edges.append((1.0, 1.0, 1.0, 1.0))

    def render(self, layers: Sequence[Layer]) -> np.ndarray:
        """One frame [height, width, 3] uint8: the layers in order (the last on top)."""
        polys: list = []
        faces: list = []
        edges: list = []
        for i, layer in enumerate(layers):
            self._layer_polys(layer, polys, faces, edges, pivots=i == len(layers) - 1 and layer.alpha >= 1)
        self.polys.set_verts(polys)
        self.polys.set_facecolor(faces)
        self.polys.set_edgecolor(edges)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        self.fig.clear()


class MujocoRenderer:
    """``mujoco.Renderer`` with the same orthographic camera; translucent
    layers are added to its scene as extra (dynamic) geoms."""

    name = "mujoco"

    def __init__(self, model: mujoco.MjModel, view: View, width: int, height: int) -> None:
        m = copy.deepcopy(model)
        m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), width)
        m.vis.global_.offheight = max(int(m.vis.global_.offheight), height)
        m.vis.global_.orthographic = 1  # the free camera is orthographic ...
        m.vis.global_.fovy = 2 * view.half_height  # ... and fovy its height in length units
        self.model, self.view = m, view
        self.data = mujoco.MjData(m)
        self.extra = mujoco.MjData(m)
        self.renderer = mujoco.Renderer(m, height, width, max_geom=max(1000, 40 * m.ngeom))
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        f = view.forward
        cam.azimuth = math.degrees(math.atan2(f[1], f[0]))
        cam.elevation = math.degrees(math.asin(max(-1.0, min(1.0, f[2]))))
        cam.distance = 4 * max(view.half_width, view.half_height, float(m.stat.extent))
        cam.lookat[:] = view.center
        self.camera = cam
        self.option = mujoco.MjvOption()
        self.perturb = mujoco.MjvPerturb()
        self.reach = cam.distance

    def _backdrop(self, scene) -> None:
        """The fallback's background and floor, as unlit boxes behind and under the scene."""
        v = self.view
        far = 0.9 * self.reach
        W = 3 * max(v.half_width, v.half_height)
        frame = np.stack([v.right, v.up, v.forward], axis=1).reshape(-1)
        boxes = [(v.center + far * v.forward, [W, W, 0.01], _BACKGROUND)]
        if v.floor is not None:
            depth = 0.8 * self.reach
            boxes.append((v.center + (v.floor - W) * v.up, [W, W, depth], _FLOOR))
        for pos, size, rgb in boxes:
            if scene.ngeom >= scene.maxgeom:
                return
            g = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(
                g, mujoco.mjtGeom.mjGEOM_BOX, np.array(size), np.array(pos), frame, np.array([*rgb, 1.0], np.float32)
            )
            g.emission = 1.0
            g.specular = 0.0
            g.rgba[:3] = np.array(rgb) / 1.1  # emission 1 plus the headlight ambient ~ the colour
            scene.ngeom += 1

    def render(self, layers: Sequence[Layer]) -> np.ndarray:
        main = layers[-1]
        _kinematics(self.model, self.data, main.qpos)
        self.renderer.update_scene(self.data, self.camera, self.option)
        scene = self.renderer.scene
        self._backdrop(scene)
        for layer in layers[:-1]:
            _kinematics(self.model, self.extra, layer.qpos)
            start = scene.ngeom
            mujoco.mjv_addGeoms(
                self.model, self.extra, self.option, self.perturb, mujoco.mjtCatBit.mjCAT_DYNAMIC, scene
            )
            for i in range(start, scene.ngeom):
                rgba = np.array(scene.geoms[i].rgba)
                if layer.tint is not None:
                    rgba[:3] = 0.45 * rgba[:3] + 0.55 * np.array(layer.tint)
                rgba[3] *= layer.alpha
                scene.geoms[i].rgba[:] = rgba
        return np.array(self.renderer.render())

    def close(self) -> None:
        self.renderer.close()


_GL_FAILURE: Optional[str] = None  # why MuJoCo's renderer failed in this process (it is not retried)


def make_renderer(
    model: mujoco.MjModel, view: View, width: int, height: int, renderer: str = "auto"
) -> tuple[GeomRenderer | MujocoRenderer, str]:
    """A renderer and a note on the choice. ``"auto"`` tries MuJoCo's renderer
    (the OpenGL backend that ``MUJOCO_GL`` selects) and falls back to the
    matplotlib drawing when no context can be created; ``"mujoco"`` fails
    if it cannot; ``"matplotlib"`` never tries OpenGL."""
    from ..errors import ConfigError

    if renderer not in RENDERERS:
        raise ConfigError(f"`renderer` must be one of {', '.join(RENDERERS)}; got {renderer!r}.")
    global _GL_FAILURE
    if renderer != "matplotlib":
        try:
            if _GL_FAILURE is not None:  # a second try at a failed GL context can abort the process
                raise RuntimeError(_GL_FAILURE)
            return _try_mujoco(model, view, width, height), "MuJoCo's renderer"
        except Exception as exc:  # no display, no EGL device, no OSMesa ...
            reason = _GL_FAILURE or f"{type(exc).__name__}: {exc}".strip().splitlines()[0][:200]
            _GL_FAILURE = reason
            if renderer == "mujoco":
                raise ConfigError(
                    f"MuJoCo's renderer could not start ({reason}). Select a working OpenGL backend with "
                    "MUJOCO_GL=egl|glfw|osmesa, or use the matplotlib renderer (--renderer matplotlib)."
                ) from None
            gl = os.environ.get("MUJOCO_GL") or "unset, so glfw"
            note = (
                f"matplotlib drawing of the geoms; MuJoCo's renderer did not start with MUJOCO_GL={gl} ({reason[:60]})"
            )
            return GeomRenderer(model, view, width, height), note
    return GeomRenderer(model, view, width, height), "matplotlib drawing of the geoms"


def _try_mujoco(model, view, width, height) -> MujocoRenderer:
    """Create the MuJoCo renderer with its warnings and failed-cleanup noise silenced."""
    import gc
    import sys

    hook = sys.unraisablehook
    sys.unraisablehook = lambda _unraisable: None  # a half-built Renderer's __del__ raises on collection
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # glfw warns before it fails without a display
            try:
                r = MujocoRenderer(model, view, width, height)
                try:
                    r.render([Layer(np.array(model.qpos0))])  # a context can exist and still fail to draw
                except Exception:
                    r.close()
                    raise
                return r
            finally:
                gc.collect()
    finally:
        sys.unraisablehook = hook
