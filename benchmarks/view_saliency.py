"""View saliency (thesis section 5.3): the interest of every visible feature of a camera view from three
normalized metrics, the view distance, the vertical view angle and the distance to a region of interest (ROI),
and a per-pixel saliency map of the view. Pure numpy, no database.

Cameras are tests.support.traverse.Camera, the CesiumJS camera api.lod_for_view takes (longitude, latitude, height
above the WGS84 ellipsoid, heading, pitch, vertical field of view, viewport), so the features the database
draws for a frame and the ones projected here share one frustum. Points are ECEF metres. The viewport is
``round(aspect × viewport_height)`` × ``viewport_height`` pixels, x to the right and y down from the top left
corner; pixel (i, j) covers [i, i + 1) × [j, j + 1).

Metrics of a feature (one point per feature: its footprint centre at mid-height for distance and angle, at
ground level for the ROI):

* normalized view distance: Euclidean distance to the camera / the largest over the frame's visible features;
* vertical view angle: between the view ray and the local horizontal at the feature, 0° seen side-on (its
  facades), 90° straight from above (its roof), normalized by 90°;
* ROI distance: the ROI is a disc on the ground (around the point the camera looks at), rasterized on a grid
  over the viewport; jump flooding (benchmarks.jfa) gives every pixel's distance to it, read at the feature's
  ground point on screen and normalized by the map's largest distance (1 when no ROI pixel is on screen).

Interest = weighted mean of (1 - metric) over the three, in [0, 1]: near, seen side-on and inside the ROI is
most interesting. A feature's saliency is its interest times the weight of the detail it is drawn with,
``(lod + 1) / 4`` (block 0.25 .. facades 1), the counterpart of the thesis' texturing of distinguished
buildings; the map paints each feature's saliency over its screen box, the nearest feature winning a pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmarks.jfa import jump_flood
from core.camera import Camera
from core.geodesy import ecef_to_geodetic, enu_rotation, geodetic_to_ecef

#: Points closer to the camera plane than this (m) are behind it.
NEAR_M = 1.0


# --- cameras -----------------------------------------------------------------------------------------------------


def viewport(cam: Camera) -> tuple[int, int]:
    """(width, height) of the viewport in pixels."""
    return int(round(cam.aspect * cam.viewport_height)), int(cam.viewport_height)


def focal_px(cam: Camera) -> float:
    """Focal length in pixels: a length l at depth z spans l × focal / z pixels."""
    return cam.focal_px()


def geodetic_up(lon: np.ndarray | float, lat: np.ndarray | float) -> np.ndarray:
    """(..., 3) ellipsoid normals (local up) at longitude/latitude in degrees."""
    lam, phi = np.radians(np.asarray(lon, float)), np.radians(np.asarray(lat, float))
    return np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1)


def ecef(lon: np.ndarray | float, lat: np.ndarray | float, h: np.ndarray | float) -> np.ndarray:
    """(..., 3) ECEF metres of longitude/latitude in degrees and height above the ellipsoid in metres."""
    return geodetic_to_ecef(np.radians(np.asarray(lon, float)), np.radians(np.asarray(lat, float)), h)


def look_at(
    lon: float,
    lat: float,
    height: float,
    target: np.ndarray,
    fov: float = 60.0,
    viewport_height: int = 1080,
    aspect: float = 16.0 / 9.0,
) -> Camera:
    """The camera at (lon, lat, height) looking at the ECEF point ``target`` (heading and pitch in the
    camera's own east-north-up frame, as CesiumJS and api.lod_for_view read them)."""
    enu = enu_rotation(math.radians(lon), math.radians(lat))
    e, n, u = enu.T @ (np.asarray(target, float) - ecef(lon, lat, height))
    heading = math.degrees(math.atan2(e, n)) % 360.0
    pitch = math.degrees(math.atan2(u, math.hypot(e, n)))
    return Camera(float(lon), float(lat), float(height), heading, pitch, fov, viewport_height, aspect)


@dataclass(frozen=True)
class PathFrame:
    """One frame of a camera path: the camera, the ground point it looks at (degrees, its height) and its
    distance to it (m)."""

    camera: Camera
    target_lon: float
    target_lat: float
    target_h: float
    distance_m: float


def camera_path(
    lon: float,
    lat: float,
    radius_m: float,
    near_m: float,
    far_m: float,
    n_frames: int = 120,
    ground_h: float = 0.0,
    fov: float = 60.0,
    viewport_height: int = 1080,
    aspect: float = 16.0 / 9.0,
    min_height_m: float = 25.0,
) -> list[PathFrame]:
    """A deterministic flight over a city centred at (lon, lat) degrees, ``radius_m`` its half extent.

    The camera looks at a ground point that loops over the city (a 2:1 Lissajous figure of 0.45 × radius_m)
    while it circles it once (heading 20° .. 380°), zooms twice from ``near_m`` out to ``far_m`` and back
    (distance to the target log-interpolated, so every scale gets frames), and tilts three times between 12°
    and 75° below the horizon; the pitch is raised where needed so the camera stays ``min_height_m`` above
    the ground. Frame i is at t = i / n_frames, so the path closes on itself.
    """
    if n_frames < 1 or not 0 < near_m <= far_m:
        raise ValueError("need n_frames >= 1 and 0 < near_m <= far_m")
    t = np.arange(n_frames) / n_frames
    tx = 0.45 * radius_m * np.sin(2 * np.pi * t)
    ty = 0.45 * radius_m * np.sin(4 * np.pi * t)
    zoom = 0.5 - 0.5 * np.cos(4 * np.pi * t)
    dist = near_m * (far_m / near_m) ** zoom
    pitch = -np.radians(12.0 + 63.0 * (0.5 - 0.5 * np.cos(6 * np.pi * t + 1.0)))
    pitch = np.minimum(pitch, -np.arcsin(np.clip(min_height_m / dist, 0.0, 1.0)))
    heading = np.radians(20.0 + 360.0 * t)
    # the camera sits behind the target along the view direction
    d_enu = np.stack([np.cos(pitch) * np.sin(heading), np.cos(pitch) * np.cos(heading), np.sin(pitch)], axis=1)
    target_enu = np.stack([tx, ty, np.zeros(n_frames)], axis=1)
    cam_enu = target_enu - dist[:, None] * d_enu
    enu = enu_rotation(math.radians(lon), math.radians(lat))
    origin = ecef(lon, lat, ground_h)
    cam_xyz = origin + cam_enu @ enu.T
    tgt_xyz = origin + target_enu @ enu.T
    cam_geo = ecef_to_geodetic(cam_xyz)
    tgt_geo = ecef_to_geodetic(tgt_xyz)
    frames = []
    for i in range(n_frames):
        c = look_at(
            math.degrees(cam_geo[i, 0]),
            math.degrees(cam_geo[i, 1]),
            float(cam_geo[i, 2]),
            tgt_xyz[i],
            fov,
            viewport_height,
            aspect,
        )
        frames.append(
            PathFrame(
                c,
                math.degrees(tgt_geo[i, 0]),
                math.degrees(tgt_geo[i, 1]),
                float(tgt_geo[i, 2]),
                float(np.linalg.norm(tgt_xyz[i] - cam_xyz[i])),
            )
        )
    return frames


# --- projection ----------------------------------------------------------------------------------------------


def project(cam: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinhole projection of ECEF points (n, 3): (x, y) viewport pixels and depth along the view direction (m);
    x and y are NaN for points less than NEAR_M in front of the camera."""
    p = np.asarray(points, float).reshape(-1, 3) - cam.position()
    d, r, u = cam.axes()
    depth = p @ d
    f = focal_px(cam)
    w, h = viewport(cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        front = depth >= NEAR_M
        x = np.where(front, w / 2.0 + f * (p @ r) / depth, np.nan)
        y = np.where(front, h / 2.0 - f * (p @ u) / depth, np.nan)
    return x, y, depth


def in_frustum(cam: Camera, points: np.ndarray) -> np.ndarray:
    """(n,) whether each ECEF point projects into the viewport, in front of the camera."""
    x, y, _ = project(cam, points)
    w, h = viewport(cam)
    with np.errstate(invalid="ignore"):
        return (x >= 0) & (x < w) & (y >= 0) & (y < h)


def vertical_view_angle(cam: Camera, points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n,) degrees between the view ray to each ECEF point and the horizontal plane at it (``up`` its unit
    normal): 0 seen side-on, 90 seen straight from above (or below)."""
    ray = np.asarray(points, float).reshape(-1, 3) - cam.position()
    norm = np.linalg.norm(ray, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.abs(np.einsum("ij,ij->i", ray, np.asarray(up, float).reshape(-1, 3))) / norm
    return np.degrees(np.arcsin(np.clip(np.nan_to_num(s, nan=1.0), 0.0, 1.0)))


def screen_boxes(
    cam: Camera, base: np.ndarray, top: np.ndarray, radius_m: np.ndarray, up: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Screen boxes of vertical cylinders (footprint circle of ``radius_m`` around ``base``, up to ``top``):
    ((n, 4) x0, y0, x1, y1 in viewport pixels, (n,) depth of the mid point). The axis from base to top spans
    its projections; the circle adds its radius in pixels sideways and that times the sine of the vertical
    view angle up and down (a disc on the ground seen side-on is flat). Rows with base or top behind the
    camera are NaN."""
    base, top = np.asarray(base, float).reshape(-1, 3), np.asarray(top, float).reshape(-1, 3)
    xb, yb, db = project(cam, base)
    xt, yt, dt = project(cam, top)
    mid = (base + top) / 2
    _, _, dm = project(cam, mid)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_px = focal_px(cam) * np.asarray(radius_m, float) / np.where(dm >= NEAR_M, dm, np.nan)
    r_v = r_px * np.sin(np.radians(vertical_view_angle(cam, mid, up)))
    boxes = np.stack(
        [np.fmin(xb, xt) - r_px, np.fmin(yb, yt) - r_v, np.fmax(xb, xt) + r_px, np.fmax(yb, yt) + r_v], axis=1
    )
    boxes[np.isnan(xb) | np.isnan(xt)] = np.nan
    return boxes, dm


def box_visible(cam: Camera, boxes: np.ndarray, min_px: float = 4.0) -> np.ndarray:
    """(n,) boxes that overlap the viewport and span at least ``min_px`` pixels (width or height)."""
    w, h = viewport(cam)
    b = np.asarray(boxes, float).reshape(-1, 4)
    with np.errstate(invalid="ignore"):
        overlap = (b[:, 2] > 0) & (b[:, 0] < w) & (b[:, 3] > 0) & (b[:, 1] < h)
        big = np.fmax(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]) >= min_px
    return overlap & big


# --- region of interest -----------------------------------------------------------------------------------------


def pixel_rays(cam: Camera, width: int) -> np.ndarray:
    """(H, W, 3) ECEF unit view rays through the pixel centres of a grid of ``width`` columns over the
    viewport (rows in proportion)."""
    vw, vh = viewport(cam)
    s = width / vw
    height = max(int(round(vh * s)), 1)
    px = (np.arange(width) + 0.5) / s - vw / 2.0
    py = (np.arange(height) + 0.5) / s - vh / 2.0
    d, r, u = cam.axes()
    f = focal_px(cam)
    rays = d + (px[None, :, None] * r - py[:, None, None] * u) / f
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def roi_disc_mask(cam: Camera, width: int, centre: np.ndarray, up: np.ndarray, radius_m: float) -> np.ndarray:
    """(H, W) boolean grid over the viewport: pixels whose ray meets the plane through ``centre`` (normal
    ``up``) in front of the camera within ``radius_m`` of it, the ROI disc on the ground."""
    rays = pixel_rays(cam, width)
    pos = cam.position()
    c, n = np.asarray(centre, float), np.asarray(up, float)
    denom = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((c - pos) @ n) / denom
    hit = pos + np.where(t > 0, t, np.nan)[..., None] * rays
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(hit - c, axis=2) <= radius_m


def roi_distance_map(mask: np.ndarray) -> np.ndarray:
    """Distance (grid pixels) of every pixel to the ROI by jump flooding (JFA+1); inf without an ROI pixel."""
    return jump_flood(mask)[0]


def sample(grid: np.ndarray, x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """``grid`` read at viewport pixel positions (x, y) scaled by ``scale`` to the grid, clipped to its edge;
    NaN positions give NaN."""
    g = np.asarray(grid)
    gx, gy = np.asarray(x, float) * scale, np.asarray(y, float) * scale
    ok = ~(np.isnan(gx) | np.isnan(gy))
    ix = np.clip(np.floor(np.where(ok, gx, 0)), 0, g.shape[1] - 1).astype(np.int64)
    iy = np.clip(np.floor(np.where(ok, gy, 0)), 0, g.shape[0] - 1).astype(np.int64)
    return np.where(ok, g[iy, ix], np.nan)


# --- metrics ---------------------------------------------------------------------------------------------------


def normalize_by_max(values: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """values / the largest finite value (over ``mask``), clipped to [0, 1]; +inf -> 1; NaN stays NaN; all
    zeros (or nothing finite) -> 0 where finite."""
    v = np.asarray(values, float)
    m = np.isfinite(v) if mask is None else (np.asarray(mask, bool) & np.isfinite(v))
    top = float(v[m].max()) if m.any() else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.clip(v / top, 0.0, 1.0) if top > 0 else np.where(np.isfinite(v), 0.0, v)
    return np.where(v == np.inf, 1.0, out)


def interest(
    distance_n: np.ndarray,
    angle_n: np.ndarray,
    roi_n: np.ndarray,
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> np.ndarray:
    """Weighted mean of (1 - metric) over the three normalized metrics, in [0, 1]."""
    wd, wa, wr = weights
    total = wd + wa + wr
    if total <= 0:
        raise ValueError("weights must sum to more than 0")
    return (
        wd * (1 - np.asarray(distance_n, float))
        + wa * (1 - np.asarray(angle_n, float))
        + wr * (1 - np.asarray(roi_n, float))
    ) / total


def lod_weight(lod: np.ndarray | int) -> np.ndarray:
    """Weight of the detail a feature is drawn with: (lod + 1) / 4, block (0) 0.25 .. facades (3) 1."""
    return (np.clip(np.asarray(lod, float), 0, 3) + 1.0) / 4.0


@dataclass
class FrameMetrics:
    """Per feature (arrays of n) and per frame (the ROI grids) results of ``frame_metrics``."""

    visible: np.ndarray  # bool: in the viewport, in front of the camera, at least min_px
    x: np.ndarray  # viewport pixels of the ground point
    y: np.ndarray
    boxes: np.ndarray  # (n, 4) screen boxes
    depth: np.ndarray
    distance_m: np.ndarray
    distance_n: np.ndarray  # NaN where not visible
    angle_deg: np.ndarray
    angle_n: np.ndarray
    roi_px: np.ndarray  # viewport pixels (grid pixels / scale)
    roi_n: np.ndarray
    interest: np.ndarray  # NaN where not visible
    roi_mask: np.ndarray  # (H, W) grid
    roi_distance: np.ndarray  # (H, W) grid pixels
    scale: float  # grid pixels per viewport pixel


def frame_metrics(
    cam: Camera,
    lon: np.ndarray,
    lat: np.ndarray,
    ground_h: np.ndarray,
    height_m: np.ndarray,
    radius_m: np.ndarray,
    roi_centre: np.ndarray,
    roi_radius_m: float,
    grid_width: int = 384,
    min_px: float = 4.0,
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> FrameMetrics:
    """The three metrics and the interest of every feature (footprint centre lon/lat degrees, ground height,
    height above it and footprint radius, m) for one camera; distances are normalized over the visible ones."""
    lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    g, hh = np.asarray(ground_h, float) + np.zeros(len(lon)), np.asarray(height_m, float)
    up = geodetic_up(lon, lat)
    base, top, mid = ecef(lon, lat, g), ecef(lon, lat, g + hh), ecef(lon, lat, g + hh / 2)
    boxes, depth = screen_boxes(cam, base, top, radius_m, up)
    visible = box_visible(cam, boxes, min_px)
    x, y, _ = project(cam, base)
    # a base behind the camera (the feature is seen from above it): read the ROI at the mid point instead
    xm, ym, _ = project(cam, mid)
    x, y = np.where(np.isnan(x), xm, x), np.where(np.isnan(y), ym, y)
    dist = np.linalg.norm(mid - cam.position(), axis=1)
    angle = vertical_view_angle(cam, mid, up)
    roi_up = geodetic_up(*np.degrees(ecef_to_geodetic(np.asarray(roi_centre, float))[:2]))
    mask = roi_disc_mask(cam, grid_width, roi_centre, roi_up, roi_radius_m)
    dmap = roi_distance_map(mask)
    scale = grid_width / viewport(cam)[0]
    roi = sample(dmap, x, y, scale)
    finite = dmap[np.isfinite(dmap)]
    far = float(finite.max()) if finite.size else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        roi_n = np.where(np.isinf(roi), 1.0, roi / far if far > 0 else 0.0 * roi)
    nan = np.where(visible, 1.0, np.nan)
    distance_n = normalize_by_max(dist, visible) * nan
    angle_n = np.clip(angle / 90.0, 0.0, 1.0) * nan
    roi_n = roi_n * nan
    return FrameMetrics(
        visible,
        x,
        y,
        boxes,
        depth,
        dist,
        distance_n,
        angle,
        angle_n,
        roi / scale,
        roi_n,
        interest(distance_n, angle_n, roi_n, weights),
        mask,
        dmap,
        scale,
    )


# --- saliency map ------------------------------------------------------------------------------------------------


def splat(
    boxes: np.ndarray, depth: np.ndarray, values: np.ndarray, width: int, height: int, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Paint each box (viewport pixels, scaled by ``scale`` to a width × height grid) with its value, the one
    of least depth winning a pixel: ((H, W) values, NaN where nothing; (H, W) index of the winning box, -1).
    NaN boxes are skipped. Vectorized: every (box, pixel) pair is listed and sorted by pixel then depth."""
    b = np.asarray(boxes, float).reshape(-1, 4) * scale
    ok = np.all(np.isfinite(b), axis=1) & np.isfinite(np.asarray(depth, float))
    idx = np.flatnonzero(ok)
    # pixel (i, j) is covered when its centre is inside the box; at least the pixel of the box centre
    x0 = np.clip(np.ceil(b[idx, 0] - 0.5), 0, width).astype(np.int64)
    x1 = np.clip(np.floor(b[idx, 2] - 0.5) + 1, 0, width).astype(np.int64)
    y0 = np.clip(np.ceil(b[idx, 1] - 0.5), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(b[idx, 3] - 0.5) + 1, 0, height).astype(np.int64)
    # a box between pixel centres still gets the pixel of its centre, per axis
    cx = np.floor((b[idx, 0] + b[idx, 2]) / 2).astype(np.int64)
    cy = np.floor((b[idx, 1] + b[idx, 3]) / 2).astype(np.int64)
    fx = (x1 <= x0) & (cx >= 0) & (cx < width)
    fy = (y1 <= y0) & (cy >= 0) & (cy < height)
    x0, x1 = np.where(fx, cx, x0), np.where(fx, cx + 1, x1)
    y0, y1 = np.where(fy, cy, y0), np.where(fy, cy + 1, y1)
    nx, ny = np.maximum(x1 - x0, 0), np.maximum(y1 - y0, 0)
    n = nx * ny
    owner = np.full(height * width, -1, dtype=np.int64)
    out = np.full(height * width, np.nan)
    if n.sum() == 0:
        return out.reshape(height, width), owner.reshape(height, width)
    k = np.repeat(np.arange(len(idx)), n)
    local = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    pix = (y0[k] + local // nx[k]) * width + x0[k] + local % nx[k]
    order = np.lexsort((np.asarray(depth, float)[idx][k], pix))
    pix, k = pix[order], k[order]
    first = np.concatenate([[True], pix[1:] != pix[:-1]])
    owner[pix[first]] = idx[k[first]]
    out[pix[first]] = np.asarray(values, float)[idx[k[first]]]
    return out.reshape(height, width), owner.reshape(height, width)
