"""Surface colours (albedo) of every material, the sky, and simple sun + ambient lighting."""

from __future__ import annotations

import numpy as np

from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.texture import band, fbm, hash01, periodic_band, smoothstep, value_noise

HORIZON = np.array([0.80, 0.85, 0.90])
ZENITH = np.array([0.30, 0.50, 0.82])


def sky_color(world: W.World, dirs: np.ndarray) -> np.ndarray:
    """(N, 3) sky colour for (N, 3) unit road-frame directions: a gradient with drifting-free clouds."""
    up = np.clip(dirs[:, 2], -1.0, 1.0)
    t = np.sqrt(np.clip(up, 0.0, 1.0))[:, None]
    color = HORIZON * (1 - t) + ZENITH * t
    # Clouds on a plane 1 km up: fixed in the world, so they move consistently with the camera.
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = 1000.0 / np.maximum(up, 0.02)
    cx, cy = dirs[:, 0] * scale, dirs[:, 1] * scale
    cover = smoothstep(0.52, 0.78, fbm(world.noise, cx, cy + 5000.0, 700.0, 4, footprint=scale * 0.002))
    cover *= smoothstep(0.0, 0.08, up)
    return color * (1 - 0.8 * cover[:, None]) + 0.95 * 0.8 * cover[:, None]


def _ground(world: W.World, p: np.ndarray, fp: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    ay = np.abs(y)
    dx = x - world.x_int
    in_cross = np.abs(dx) <= W.CROSS_HALF
    asphalt = 0.30 + 0.10 * (fbm(world.noise, x, y, 3.0, 7, fp) - 0.5) * 2
    asphalt += 0.05 * (fbm(world.noise, x + 900.0, y, 0.4, 4, fp) - 0.5) * 2
    asphalt -= 0.04 * band(ay, 0.0, W.LANE * 2 + 0.5, fp) * (fbm(world.noise, x, y * 3, 6.0, 2, fp) > 0.55)
    parking = band(ay, W.ROAD_HALF, W.CURB_Y, fp) * (1 - in_cross)
    gray = asphalt * (1 - 0.12 * parking)
    main = ~in_cross
    paint = np.zeros_like(x)
    # Centre double line, dashed lane dividers (3 m paint, 6 m gap), solid edge lines.
    paint += main * (band(y, 0.08, 0.20, fp) + band(y, -0.20, -0.08, fp))
    paint += main * band(ay, W.LANE - 0.08, W.LANE + 0.08, fp) * periodic_band(x, 9.0, 0.0, 3.0, fp)
    paint += main * band(ay, W.ROAD_HALF - 0.2, W.ROAD_HALF, fp)
    # Zebra crossing before the intersection, a dashed centre line on the crossing road.
    zebra = band(dx, -W.CROSS_HALF - 4.0, -W.CROSS_HALF - 0.5, fp) * band(ay, 0.0, W.ROAD_HALF, fp)
    paint += zebra * periodic_band(y, 1.2, 0.0, 0.6, fp)
    paint += in_cross * band(dx, -0.08, 0.08, fp) * periodic_band(y, 9.0, 0.0, 3.0, fp) * (ay > W.CURB_Y)
    paint = np.clip(paint, 0.0, 1.0) * (0.75 + 0.25 * fbm(world.noise, x * 2, y * 2, 1.0, 3, fp))
    color = gray[:, None] * np.array([1.0, 1.0, 1.02]) * (1 - paint[:, None]) + paint[:, None] * 0.85
    grass = (ay > W.SIDEWALK_OUTER) & ~in_cross
    if grass.any():
        g = fbm(world.noise, x[grass], y[grass], 2.0, 5, fp[grass])
        color[grass] = np.array([0.25, 0.38, 0.16]) * (0.7 + 0.6 * g)[:, None]
    return color


def _sidewalk(world: W.World, p: np.ndarray, n: np.ndarray, fp: np.ndarray) -> np.ndarray:
    x, y = p[:, 0], p[:, 1]
    slabs = 1.0 - 0.35 * np.maximum(periodic_band(x, 1.5, 1.45, 1.5, fp), periodic_band(y, 1.5, 1.45, 1.5, fp))
    base = 0.60 * (0.85 + 0.3 * fbm(world.noise, x, y + 300.0, 1.5, 5, fp)) * slabs
    curb = np.abs(n[:, 2]) < 0.5
    base = np.where(curb, 0.70 * (0.9 + 0.2 * fbm(world.noise, x, p[:, 2] * 5, 0.5, 3, fp)), base)
    return base[:, None] * np.array([1.0, 0.99, 0.95])


def _building(world: W.World, p: np.ndarray, n: np.ndarray, fp: np.ndarray, color: np.ndarray,
              prim: np.ndarray) -> np.ndarray:
    roof = n[:, 2] > 0.5
    along = np.where(np.abs(n[:, 1]) > 0.5, p[:, 0], p[:, 1]) + 17.0 * hash01(prim, 1)
    z = p[:, 2]
    wall = color * (0.85 + 0.3 * fbm(world.noise, along, z + 50 * hash01(prim, 2), 2.0, 6, fp))[:, None]
    spacing = 2.6 + 0.8 * hash01(prim, 3)
    upper = periodic_band(along, spacing, 0.6, spacing - 0.6, fp) * periodic_band(z, 3.2, 1.0, 2.4, fp) * (z > 3.0)
    shop = periodic_band(along, 6.0, 0.5, 5.0, fp) * band(z, 0.5, 2.7, fp)
    window = np.clip(upper + shop, 0.0, 1.0)
    cell = np.floor(along / spacing) * 31 + np.floor(z / 3.2)
    glass = np.array([0.16, 0.20, 0.26]) * (0.6 + 0.9 * hash01(cell.astype(np.int64), 4))[:, None]
    out = wall * (1 - window[:, None]) + glass * window[:, None]
    out[roof] = 0.35 * (0.8 + 0.4 * fbm(world.noise, p[roof, 0], p[roof, 1], 3.0, 4, fp[roof]))[:, None]
    return out


def _car(world: W.World, p: np.ndarray, n: np.ndarray, fp: np.ndarray, color: np.ndarray,
         material: np.ndarray, obj: np.ndarray, time: float) -> np.ndarray:
    """Body colour with a dark sill, lights and a door seam; glass cabin with a coloured roof; tyres."""
    local = np.zeros_like(p)
    local_n = np.zeros_like(n)
    lengths = np.zeros(len(p))
    for car in world.movers:
        sel = obj == car.index
        if sel.any():
            pose = car.pose(time)
            local[sel] = (p[sel] - pose[:3, 3]) @ pose[:3, :3]
            local_n[sel] = n[sel] @ pose[:3, :3]
            lengths[sel] = car.length
    lx, ly, lz = local.T
    grime = 0.93 + 0.14 * fbm(world.noise, lx * 3 + ly * 2, lz * 3 + 40.0 * obj, 0.5, 3, fp)
    out = color * grime[:, None]
    body = material == W.CAR_BODY
    sill = band(lz, 0.0, 0.45, fp) * body
    out = out * (1 - 0.65 * sill[:, None])
    front = body & (local_n[:, 0] > 0.5)
    rear = body & (local_n[:, 0] < -0.5)
    lamp = band(np.abs(ly), 0.45, 0.8, fp) * band(lz, 0.62, 0.80, fp)
    out[front] = out[front] * (1 - lamp[front, None]) + np.array([0.95, 0.95, 0.88]) * lamp[front, None]
    out[rear] = out[rear] * (1 - lamp[rear, None]) + np.array([0.75, 0.05, 0.04]) * lamp[rear, None]
    side = body & (np.abs(local_n[:, 1]) > 0.5)
    seam = band(lx, 0.02 * lengths - 0.03, 0.02 * lengths + 0.03, fp) * side
    out *= (1 - 0.5 * seam)[:, None]
    cabin = material == W.CAR_CABIN
    glass = cabin & (local_n[:, 2] < 0.5)
    out[glass] = np.array([0.10, 0.12, 0.15]) * (0.8 + 0.5 * smoothstep(0.95, 1.6, lz[glass]))[:, None]
    wheel = material == W.WHEEL
    if wheel.any():
        # Distance to the wheel centre in the side view; hub caps on the outer faces.
        axle_x = np.where(lx > 0, 0.32, -0.32) * lengths
        r = np.hypot(lx - axle_x, lz - 0.35)
        hub = band(r, -1.0, 0.17, fp) * (np.abs(local_n[:, 1]) > 0.5)
        tyre = 0.06 * (1 - hub) + 0.5 * hub
        out[wheel] = tyre[wheel, None] * np.ones(3)
    return out


def albedo(world: W.World, material: np.ndarray, obj: np.ndarray, prim: np.ndarray, color: np.ndarray,
           p: np.ndarray, n: np.ndarray, fp: np.ndarray, time: float) -> np.ndarray:
    """(N, 3) albedo in 0..1 of N hit points.

    Args:
        material, obj, prim: (N,) material id, owning object, primitive index.
        color: (N, 3) the primitive's base colour. p, n: (N, 3) road-frame point and normal.
        fp: (N,) pixel footprint on the surface (m), for anti-aliasing. time: seconds (car poses).
    """
    out = np.zeros((len(p), 3))
    for mat in np.unique(material):
        sel = material == mat
        ps, ns, fs = p[sel], n[sel], fp[sel]
        if mat == W.GROUND:
            out[sel] = _ground(world, ps, fs)
        elif mat == W.SIDEWALK:
            out[sel] = _sidewalk(world, ps, ns, fs)
        elif mat == W.BUILDING:
            out[sel] = _building(world, ps, ns, fs, color[sel], prim[sel])
        elif mat in W.VEHICLE_MATERIALS or mat in W.FIGURE_MATERIALS:
            continue
        elif mat == W.POLE:
            out[sel] = color[sel] * (0.8 + 0.3 * value_noise(world.noise, ps[:, 2] * 2, ps[:, 0]))[:, None]
        elif mat == W.TRUNK:
            bark = fbm(world.noise, ps[:, 2] * 4, ps[:, 0] + ps[:, 1], 0.3, 3, fs)
            out[sel] = color[sel] * (0.7 + 0.6 * bark)[:, None]
        elif mat == W.FOLIAGE:
            # Two projections blended so the pattern has no preferred direction on the sphere.
            leaves = 0.5 * (fbm(world.noise, ps[:, 0], ps[:, 2], 0.5, 4, fs)
                            + fbm(world.noise, ps[:, 1] + 71.0, ps[:, 2] + 13.0, 0.5, 4, fs))
            out[sel] = color[sel] * (0.45 + 1.0 * leaves)[:, None]
    vehicle = np.isin(material, W.VEHICLE_MATERIALS)
    if vehicle.any():
        out[vehicle] = _car(world, p[vehicle], n[vehicle], fp[vehicle], color[vehicle], material[vehicle],
                            obj[vehicle], time)
    figure = np.isin(material, W.FIGURE_MATERIALS)
    if figure.any():
        out[figure] = _figure(world, p[figure], fp[figure], color[figure], obj[figure], time)
    return np.clip(out, 0.0, 1.0)


def _figure(world: W.World, p: np.ndarray, fp: np.ndarray, color: np.ndarray, obj: np.ndarray,
            time: float) -> np.ndarray:
    """(N, 3) pedestrians and cyclists: the part's colour with a fine fabric-like noise fixed to the
    body (in its own frame, so the texture moves with it)."""
    local = np.zeros_like(p)
    for mover in world.movers:
        sel = obj == mover.index
        if sel.any():
            pose = mover.pose(time)
            local[sel] = (p[sel] - pose[:3, 3]) @ pose[:3, :3]
    lx, ly, lz = local.T
    grain = 0.85 + 0.3 * fbm(world.noise, lx * 4 + ly * 3 + 17.0 * obj, lz * 4, 0.3, 3, fp)
    return color * grain[:, None]


def lit(world: W.World, albedo_rgb: np.ndarray, n: np.ndarray, material: np.ndarray,
        distance: np.ndarray) -> np.ndarray:
    """(N, 3) shaded colour: ambient + Lambert sun (no shadows), and a distance haze."""
    sun = np.clip(n @ world.sun, 0.0, 1.0)
    # Sphere normals point outwards; foliage also scatters light, so it never goes fully dark.
    sun = np.where(material == W.FOLIAGE, 0.3 + 0.7 * sun, sun)
    ambient = 0.50 + 0.12 * n[:, 2]
    shaded = albedo_rgb * (ambient + 0.62 * sun)[:, None]
    haze = (1 - np.exp(-distance / 700.0))[:, None]
    return shaded * (1 - haze) + HORIZON * haze
