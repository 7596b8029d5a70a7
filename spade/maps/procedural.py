"""Procedural occupancy maps that look like SLAM maps of warehouses, offices and industrial halls.

Every generator draws a floor plan in metres (walls, racks, rooms, pillars, pallets) onto a grid that starts
UNKNOWN, then "SLAM-ifies" it (``_slamify``): interiors of solid obstacles become unknown (a lidar only sees
their outline), obstacle edges become ragged (1-2 px of noisy, spatially correlated thickening), small unknown
shadows appear beside obstacles, and a few unknown / occupied speckles are sprinkled on the floor. Open doors in
the outer wall let free space leak outside, ending raggedly in unknown space.

Each generator reserves an open zone of at least ``OPEN_ZONE_M`` x ``OPEN_ZONE_M`` metres (loading-dock staging
area, office lobby, a pillar-free bay of the hall) that no clutter or speckle enters, so that a 0.22 m radius
robot always has room for 6 m L/U manoeuvres (see ``spade.maps.analysis.max_clear_square_m``).

All randomness comes from one ``numpy.random.Generator`` seeded by ``seed``: the same seed and parameters give
byte-identical grids. The canonical plan is finally rotated by a random multiple of 90 degrees (the requested
width/height are kept).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import ndimage
from skimage.draw import disk

from spade.maps.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap

OPEN_ZONE_M = 7.2
"""Side of the reserved open zone (metres): 6 m of manoeuvre room + 2 x 0.22 m robot radius + ragged-edge slack."""

MIN_SIZE_M = 14.0
"""Smallest width/height accepted by the generators (the building must hold the open zone plus walls)."""

DEFAULT_RESOLUTION = 0.05

_FOUR = ndimage.generate_binary_structure(2, 1)

Box = tuple[float, float, float, float]  # (x0, y0, x1, y1) metres; x right, y down from the image's top-left


class _Plan:
    """A floor plan being drawn: the code grid plus masks that steer clutter and noise placement."""

    def __init__(self, width_m: float, height_m: float, resolution: float, rng: np.random.Generator) -> None:
        self.res = resolution
        self.rng = rng
        self.h = max(1, int(round(height_m / resolution)))
        self.w = max(1, int(round(width_m / resolution)))
        self.grid = np.full((self.h, self.w), UNKNOWN, dtype=np.uint8)
        self.protected = np.zeros((self.h, self.w), dtype=bool)  # open zones: no clutter, no noise
        self.keepclear = np.zeros((self.h, self.w), dtype=bool)  # doorways: no furniture
        self.doorways = np.zeros((self.h, self.w), dtype=bool)  # door openings: no walls across them
        self.leaks: list[Box] = []  # outside regions seen through open doors

    def sl(self, box: Box) -> tuple[slice, slice]:
        """Row/column slices of a metric box, clipped to the grid, at least one pixel wide."""
        x0, y0, x1, y1 = box
        c0, c1 = int(round(x0 / self.res)), int(round(x1 / self.res))
        r0, r1 = int(round(y0 / self.res)), int(round(y1 / self.res))
        c1, r1 = max(c1, c0 + 1), max(r1, r0 + 1)
        c0, c1 = min(max(c0, 0), self.w), min(max(c1, 0), self.w)
        r0, r1 = min(max(r0, 0), self.h), min(max(r1, 0), self.h)
        return slice(r0, r1), slice(c0, c1)

    def fill(self, box: Box, code: int) -> None:
        self.grid[self.sl(box)] = code

    def walls(self, box: Box, t: float) -> None:
        """Free interior with walls of thickness ``t`` inside the border of ``box``."""
        x0, y0, x1, y1 = box
        self.fill(box, OCCUPIED)
        self.fill((x0 + t, y0 + t, x1 - t, y1 - t), FREE)

    def door(self, box: Box, keep: float = 0.9) -> None:
        """Cut a doorway (FREE) and keep furniture ``keep`` metres away from it."""
        self.fill(box, FREE)
        x0, y0, x1, y1 = box
        self.doorways[self.sl((x0 - 0.2, y0 - 0.2, x1 + 0.2, y1 + 0.2))] = True
        self.keepclear[self.sl((x0 - keep, y0 - keep, x1 + keep, y1 + keep))] = True

    def fits(self, box: Box, clearance: float) -> bool:
        """Whether ``box`` grown by ``clearance`` is all FREE, unprotected, clear of doorways and on the grid."""
        x0, y0, x1, y1 = box
        if x0 - clearance < 0 or y0 - clearance < 0:
            return False
        if x1 + clearance > self.w * self.res or y1 + clearance > self.h * self.res:
            return False
        s = self.sl((x0 - clearance, y0 - clearance, x1 + clearance, y1 + clearance))
        return bool((self.grid[s] == FREE).all() and not self.protected[s].any() and not self.keepclear[s].any())

    def place(self, size: tuple[float, float], region: Box, clearance: float, tries: int = 30) -> Box | None:
        """Drop an obstacle of ``size`` (w, h) at a random spot of ``region`` where it fits; None if none found."""
        w, h = size
        rx0, ry0, rx1, ry1 = region
        if rx1 - rx0 < w or ry1 - ry0 < h:
            return None
        for _ in range(tries):
            x = float(self.rng.uniform(rx0, rx1 - w))
            y = float(self.rng.uniform(ry0, ry1 - h))
            box = (x, y, x + w, y + h)
            if self.fits(box, clearance):
                self.fill(box, OCCUPIED)
                return box
        return None

    def protect(self, box: Box) -> None:
        self.protected[self.sl(box)] = True

    def leak(self, box: Box) -> None:
        """Free space seen through an open outer door; its far edge is made ragged by ``_slamify``."""
        x0, y0, x1, y1 = box
        edge = 0.25  # the yard fades into unknown before the image border
        box = (max(x0, edge), max(y0, edge), min(x1, self.w * self.res - edge), min(y1, self.h * self.res - edge))
        region = self.sl(box)
        self.grid[region] = np.where(self.grid[region] == UNKNOWN, FREE, self.grid[region])
        self.leaks.append(box)


# ------------------------------------------------------------------------------------------- SLAM look
def _slamify(plan: _Plan) -> None:
    rng, res, g = plan.rng, plan.res, plan.grid
    quiet = plan.protected | plan.doorways  # no noise in open zones and doorways
    px = lambda metres: max(1, int(round(metres / res)))  # noqa: E731

    # Ragged ends of the free space seen through open doors: erode it from the unknown side, randomly.
    leak_mask = np.zeros_like(plan.protected)
    for box in plan.leaks:
        leak_mask[plan.sl(box)] = True
    for p in (0.6, 0.5, 0.45, 0.4, 0.35, 0.3):
        edge = leak_mask & (g == FREE) & ndimage.binary_dilation(g == UNKNOWN, _FOUR)
        g[edge & (rng.random(g.shape) < p)] = UNKNOWN

    # A lidar sees only the outline of a solid obstacle: its core is unknown.
    occ = g == OCCUPIED
    core = ndimage.binary_erosion(occ, _FOUR, iterations=px(0.1), border_value=1)
    g[core] = UNKNOWN

    # Ragged, noisy edges: free cells next to obstacles turn occupied, more where a smooth noise field is high.
    smooth = ndimage.gaussian_filter(rng.standard_normal(g.shape), sigma=px(0.25))
    smooth /= smooth.std() + 1e-12
    for p_base in (0.3, 0.12):
        edge = (g == FREE) & ndimage.binary_dilation(g == OCCUPIED, _FOUR) & ~quiet
        prob = np.clip(p_base + 0.25 * smooth, 0.0, 0.9)
        g[edge & (rng.random(g.shape) < prob)] = OCCUPIED

    free = g == FREE
    area_m2 = free.sum() * res * res
    # Unknown shadows beside obstacles (cells the robot never saw behind a corner or a pallet).
    next_to_obstacle = free & ndimage.binary_dilation(g == OCCUPIED, _FOUR) & ~quiet
    candidates = np.flatnonzero(next_to_obstacle)
    n_shadows = min(len(candidates), int(area_m2 / 20.0))
    if n_shadows:
        for idx in rng.choice(candidates, size=n_shadows, replace=False):
            r, c = divmod(int(idx), plan.w)
            rr, cc = disk((r, c), float(rng.uniform(1.0, px(0.15) + 1.5)), shape=g.shape)
            keep = (g[rr, cc] == FREE) & ~quiet[rr, cc]
            g[rr[keep], cc[keep]] = UNKNOWN

    # Speckles: missed cells and isolated returns (chair legs, dust) on the open floor.
    free = (g == FREE) & ~quiet
    u = rng.random(g.shape)
    g[free & (u < 0.0015)] = UNKNOWN
    g[free & (u > 1.0 - 0.0002 * (res / 0.05) ** 2)] = OCCUPIED


# ------------------------------------------------------------------------------------------- framework
def _check_params(kind: str, seed: int, width_m: float, height_m: float, resolution: float) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"{kind}: seed must be a non-negative int, got {seed!r}")
    if not (isinstance(resolution, (int, float)) and math.isfinite(resolution) and 0.0 < resolution <= 0.2):
        raise ValueError(f"{kind}: resolution must be in (0, 0.2] metres per pixel, got {resolution!r}")
    for name, value in (("width_m", width_m), ("height_m", height_m)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and MIN_SIZE_M <= value <= 500.0):
            raise ValueError(
                f"{kind}: {name} must be between {MIN_SIZE_M} and 500 metres (the building must hold a "
                f"{OPEN_ZONE_M} m open zone), got {value!r}"
            )


def _building(
    plan: _Plan, width_m: float, height_m: float, margins: tuple[float, float, float, float], t: float
) -> Box:
    """Outer walls inside the given margins (left, top, right, bottom); returns the free interior box."""
    ml, mt, mr, mb = margins
    plan.walls((ml, mt, width_m - mr, height_m - mb), t)
    return (ml + t, mt + t, width_m - mr - t, height_m - mb - t)


def _finish(plan: _Plan, kind: str, seed: int, rotation: int) -> OccupancyMap:
    _slamify(plan)
    grid = np.ascontiguousarray(np.rot90(plan.grid, rotation))
    h, w = grid.shape
    origin = (-round(w * plan.res / 2.0, 6), -round(h * plan.res / 2.0, 6), 0.0)
    return OccupancyMap(grid, plan.res, origin, f"{kind}_{seed}")


def _canvas(
    kind: str, seed: int, width_m: float, height_m: float, resolution: float
) -> tuple[_Plan, int, float, float]:
    """A plan in canonical orientation; returns it, the final rot90 count and the canonical width/height."""
    _check_params(kind, seed, width_m, height_m, resolution)
    rng = np.random.default_rng(int(seed))
    rotation = int(rng.integers(4))
    cw, ch = (height_m, width_m) if rotation % 2 else (width_m, height_m)
    return _Plan(cw, ch, float(resolution), rng), rotation, cw, ch


# ------------------------------------------------------------------------------------------- warehouse
def warehouse(
    seed: int, width_m: float = 28.0, height_m: float = 24.0, resolution: float = DEFAULT_RESOLUTION
) -> OccupancyMap:
    """Warehouse: rack rows with aisles and cross-aisles, a staging area in front of loading docks.

    Canonical plan (before the random rotation): docks on the bottom wall, the staging area (the open zone) above
    them, rack rows filling the rest, running perpendicular or parallel to the dock wall.
    """
    plan, rotation, W, H = _canvas("warehouse", seed, width_m, height_m, resolution)
    rng = plan.rng
    bay_depth = float(rng.uniform(1.0, 1.6))
    side = lambda: float(rng.uniform(0.5, 1.2))  # noqa: E731
    bottom = bay_depth + 1.2  # room outside for the dock bays and the yard seen through open docks
    wall_t = float(rng.uniform(0.15, 0.25))
    bx0, by0, bx1, by1 = _building(plan, W, H, (side(), side(), side(), bottom), t=wall_t)

    # Loading docks along the bottom wall: a door, a leveller bay outside, open or shut.
    staging = min(float(rng.uniform(OPEN_ZONE_M + 0.3, OPEN_ZONE_M + 1.5)), by1 - by0 - 1.0)
    n_docks = int(rng.integers(2, max(3, int((bx1 - bx0) / 5.0)) + 1))
    slot = (bx1 - bx0) / n_docks
    for i in range(n_docks):
        dw = float(rng.uniform(2.6, 3.2))
        x = bx0 + i * slot + float(rng.uniform(0.3, max(0.31, slot - dw - 0.3)))
        y_wall = by1
        plan.door((x, y_wall - 0.05, x + dw, y_wall + wall_t + 0.05))
        bay = (x, y_wall + wall_t, x + dw, y_wall + wall_t + bay_depth)
        plan.fill((x - 0.15, bay[1], x, bay[3]), OCCUPIED)
        plan.fill((x + dw, bay[1], x + dw + 0.15, bay[3]), OCCUPIED)
        plan.fill(bay, FREE)
        if rng.random() < 0.6:
            plan.leak((x - 0.4, bay[3], x + dw + 0.4, H))
        else:
            plan.fill((x, bay[3] - 0.1, x + dw, bay[3]), OCCUPIED)
    plan.protect((bx0 + 0.2, by1 - staging, bx1 - 0.2, by1 - 0.2))

    # Rack rows in the remaining area.
    perim = float(rng.uniform(1.6, 2.4))
    area = (bx0 + perim, by0 + perim, bx1 - perim, by1 - staging - 0.2)
    vertical = rng.random() < 0.6
    across = (area[0], area[2]) if vertical else (area[1], area[3])  # rows are stacked along this axis
    along = (area[1], area[3]) if vertical else (area[0], area[2])  # each row runs along this axis
    pos = across[0]
    first = True
    while True:
        depth = float(rng.uniform(0.9, 1.2)) if first or rng.random() < 0.3 else float(rng.uniform(2.0, 2.4))
        if pos + depth > across[1]:
            break
        a = along[0]
        while a < along[1] - 1.0:
            length = min(float(rng.uniform(8.0, 14.0)), along[1] - a)
            if depth < 1.3 and rng.random() < 0.5:
                # Open pallet rack: the lidar sees the beams between the uprights as a dashed line.
                bar = float(rng.uniform(0.08, 0.15))
                mid = pos + depth / 2.0
                seg = a
                while seg < a + length:
                    seg_len = min(float(rng.uniform(1.6, 2.6)), a + length - seg)
                    end = seg + seg_len
                    box = (mid - bar, seg, mid + bar, end) if vertical else (seg, mid - bar, end, mid + bar)
                    plan.fill(box, OCCUPIED)
                    seg += seg_len + float(rng.uniform(0.25, 0.6))
            else:
                box = (pos, a, pos + depth, a + length) if vertical else (a, pos, a + length, pos + depth)
                plan.fill(box, OCCUPIED)
            a += length + float(rng.uniform(2.4, 3.2))
        pos += depth + float(rng.uniform(2.6, 3.4))
        first = False

    # A few pallets left on the floor, clear of aisles' centre lines and the staging area.
    for _ in range(int(rng.integers(2, 7))):
        size = (1.2, 0.8) if rng.random() < 0.5 else (0.8, 1.2)
        plan.place(size, (bx0, by0, bx1, by1), clearance=0.9)
    return _finish(plan, "warehouse", seed, rotation)


# ------------------------------------------------------------------------------------------- office
def _split_rooms(plan: _Plan, box: Box, t: float, rooms: list[Box], depth: int = 0) -> None:
    """Binary space partition into rooms; every split wall gets a door, so all rooms stay connected."""
    rng = plan.rng
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    max_side = float(rng.uniform(4.5, 6.5))
    if (w <= max_side and h <= max_side) or depth > 6 or (depth > 0 and rng.random() < 0.12 and w * h < 60.0):
        rooms.append(box)
        return
    door_w = float(rng.uniform(0.9, 1.1))
    for _ in range(10):  # a split wall must not run across an existing doorway
        if w >= h:
            x = x0 + w * float(rng.uniform(0.38, 0.62))
            if not plan.doorways[plan.sl((x, y0 - 0.1, x + t, y1 + 0.1))].any():
                break
        else:
            y = y0 + h * float(rng.uniform(0.38, 0.62))
            if not plan.doorways[plan.sl((x0 - 0.1, y, x1 + 0.1, y + t))].any():
                break
    else:
        rooms.append(box)
        return
    if w >= h:
        plan.fill((x, y0, x + t, y1), OCCUPIED)
        d = y0 + float(rng.uniform(0.25, max(0.26, h - door_w - 0.25)))
        plan.door((x - 0.05, d, x + t + 0.05, d + door_w))
        _split_rooms(plan, (x0, y0, x, y1), t, rooms, depth + 1)
        _split_rooms(plan, (x + t, y0, x1, y1), t, rooms, depth + 1)
    else:
        plan.fill((x0, y, x1, y + t), OCCUPIED)
        d = x0 + float(rng.uniform(0.25, max(0.26, w - door_w - 0.25)))
        plan.door((d, y - 0.05, d + door_w, y + t + 0.05))
        _split_rooms(plan, (x0, y0, x1, y), t, rooms, depth + 1)
        _split_rooms(plan, (x0, y + t, x1, y1), t, rooms, depth + 1)


def _furnish(plan: _Plan, room: Box) -> None:
    """Desks and cabinets against the walls, a table in the middle of larger rooms."""
    rng = plan.rng
    x0, y0, x1, y1 = room
    for _ in range(int(rng.integers(1, 4))):
        dw, dd = float(rng.uniform(1.2, 1.8)), float(rng.uniform(0.6, 0.8))
        wall = int(rng.integers(4))
        if wall == 0:
            region = (x0, y0, x1, y0 + dd)
        elif wall == 1:
            region = (x0, y1 - dd, x1, y1)
        elif wall == 2:
            region, dw, dd = (x0, y0, x0 + dd, y1), dd, dw
        else:
            region, dw, dd = (x1 - dd, y0, x1, y1), dd, dw
        plan.place((dw, dd), region, clearance=0.0, tries=10)
    if (x1 - x0) > 4.0 and (y1 - y0) > 4.0 and rng.random() < 0.6:
        tw, th = float(rng.uniform(1.2, 2.4)), float(rng.uniform(0.8, 1.2))
        plan.place((tw, th), (x0 + 1.0, y0 + 1.0, x1 - 1.0, y1 - 1.0), clearance=0.8, tries=10)


def office(
    seed: int, width_m: float = 26.0, height_m: float = 20.0, resolution: float = DEFAULT_RESOLUTION
) -> OccupancyMap:
    """Office floor: a lobby (the open zone), a corridor spine, rooms with doors, desks and tables.

    Canonical plan: the lobby spans the building's height at the left end; a corridor runs from it to the right
    end; the bands above and below the corridor are split into rooms (binary space partition, one door per
    split wall and one door from each corridor-side room into the corridor).
    """
    plan, rotation, W, H = _canvas("office", seed, width_m, height_m, resolution)
    rng = plan.rng
    side = lambda: float(rng.uniform(0.5, 1.5))  # noqa: E731
    bx0, by0, bx1, by1 = _building(plan, W, H, (side(), side(), side(), side()), t=float(rng.uniform(0.15, 0.25)))
    t = float(rng.uniform(0.1, 0.15))

    lobby_w = min(float(rng.uniform(OPEN_ZONE_M + 0.5, OPEN_ZONE_M + 2.0)), bx1 - bx0 - 3.0)
    lx1 = bx0 + lobby_w
    cw = float(rng.uniform(1.8, 2.4))
    cy = float(rng.uniform(by0 + (by1 - by0) * 0.35, by0 + (by1 - by0) * 0.65))
    c0, c1 = cy - cw / 2.0, cy + cw / 2.0
    if bx1 - lx1 > 2.0:
        # Wall between lobby and offices, open at the corridor; corridor walls with room doors.
        plan.fill((lx1, by0, lx1 + t, by1), OCCUPIED)
        plan.door((lx1 - 0.05, c0, lx1 + t + 0.05, c1), keep=0.3)
        plan.fill((lx1, c0 - t, bx1, c0), OCCUPIED)
        plan.fill((lx1, c1, bx1, c1 + t), OCCUPIED)
        plan.fill((lx1 + t, c0, bx1, c1), FREE)
        sides = (((lx1 + t, by0, bx1, c0 - t), (c0 - t, c0)), ((lx1 + t, c1 + t, bx1, by1), (c1, c1 + t)))
        for band, corridor_wall in sides:
            if band[3] - band[1] < 1.5:
                continue
            rooms: list[Box] = []
            _split_rooms(plan, band, t, rooms)
            for room in rooms:
                touches = abs(room[3] - corridor_wall[0]) < 1e-6 or abs(room[1] - corridor_wall[1]) < 1e-6
                rw = room[2] - room[0]
                if touches and rw >= 1.4:
                    dw = min(float(rng.uniform(0.9, 1.1)), rw - 0.3)
                    d = room[0] + float(rng.uniform(0.15, rw - dw - 0.15))
                    plan.door((d, corridor_wall[0] - 0.05, d + dw, corridor_wall[1] + 0.05))
            for room in rooms:
                _furnish(plan, room)

    # Lobby: the protected open zone in the middle, reception desk and plants around it.
    ly = float(rng.uniform(by0 + 0.3, max(by0 + 0.31, by1 - OPEN_ZONE_M - 0.3)))
    plan.protect((bx0 + 0.25, ly, lx1 - 0.25, ly + OPEN_ZONE_M))
    # Meeting rooms / storage closed off from the lobby where it extends beyond the open zone.
    top_wall, bottom_wall = ly - 0.2 - t, ly + OPEN_ZONE_M + 0.2
    for y_wall, band in ((top_wall, (bx0, by0, lx1, top_wall)), (bottom_wall, (bx0, bottom_wall + t, lx1, by1))):
        if band[3] - band[1] >= 2.5 and rng.random() < 0.8:
            plan.fill((bx0, y_wall, lx1, y_wall + t), OCCUPIED)
            rooms = []
            _split_rooms(plan, band, t, rooms)
            for room in rooms:
                rw = room[2] - room[0]
                touches = abs(room[3] - y_wall) < 1e-6 or abs(room[1] - (y_wall + t)) < 1e-6
                if touches and rw >= 1.4:
                    dw = min(float(rng.uniform(0.9, 1.1)), rw - 0.3)
                    d = room[0] + float(rng.uniform(0.15, rw - dw - 0.15))
                    plan.door((d, y_wall - 0.05, d + dw, y_wall + t + 0.05))
                _furnish(plan, room)
    plan.place((float(rng.uniform(1.8, 2.6)), 0.7), (bx0, by0, lx1, by1), clearance=0.6)
    for _ in range(int(rng.integers(3, 8))):
        s = float(rng.uniform(0.3, 0.6))
        plan.place((s, s), (bx0, by0, lx1, by1), clearance=0.3)
    return _finish(plan, "office", seed, rotation)


# ------------------------------------------------------------------------------------------- hall
def hall(
    seed: int, width_m: float = 30.0, height_m: float = 24.0, resolution: float = DEFAULT_RESOLUTION
) -> OccupancyMap:
    """Industrial hall: open floor on a pillar grid, pallet blocks, machines, an office box and big doors.

    The open zone is a random pillar-free bay; pallets and machines keep at least 1 m from each other and from
    walls, so the floor stays connected.
    """
    plan, rotation, W, H = _canvas("hall", seed, width_m, height_m, resolution)
    rng = plan.rng
    side = lambda: float(rng.uniform(0.8, 1.8))  # noqa: E731
    wall_t = float(rng.uniform(0.2, 0.3))
    bx0, by0, bx1, by1 = _building(plan, W, H, (side(), side(), side(), side()), t=wall_t)

    zx = float(rng.uniform(bx0 + 0.3, bx1 - OPEN_ZONE_M - 0.3))
    zy = float(rng.uniform(by0 + 0.3, by1 - OPEN_ZONE_M - 0.3))
    zone = (zx, zy, zx + OPEN_ZONE_M, zy + OPEN_ZONE_M)
    plan.protect(zone)

    # Sectional doors in the outer wall, open to the yard.
    for _ in range(int(rng.integers(1, 3))):
        dw = float(rng.uniform(3.0, 4.2))
        wall = int(rng.integers(4))
        if wall < 2:
            x = float(rng.uniform(bx0 + 1.0, bx1 - dw - 1.0))
            if wall == 0:
                plan.door((x, by0 - wall_t - 0.05, x + dw, by0 + 0.05), keep=1.5)
                plan.leak((x - 0.3, 0.0, x + dw + 0.3, by0 - wall_t))
            else:
                plan.door((x, by1 - 0.05, x + dw, by1 + wall_t + 0.05), keep=1.5)
                plan.leak((x - 0.3, by1 + wall_t, x + dw + 0.3, H))
        else:
            y = float(rng.uniform(by0 + 1.0, by1 - dw - 1.0))
            if wall == 2:
                plan.door((bx0 - wall_t - 0.05, y, bx0 + 0.05, y + dw), keep=1.5)
                plan.leak((0.0, y - 0.3, bx0 - wall_t, y + dw + 0.3))
            else:
                plan.door((bx1 - 0.05, y, bx1 + wall_t + 0.05, y + dw), keep=1.5)
                plan.leak((bx1 + wall_t, y - 0.3, W, y + dw + 0.3))

    # Office box in a corner, with a door towards the hall.
    if rng.random() < 0.7:
        ow, oh = float(rng.uniform(3.5, 5.5)), float(rng.uniform(3.0, 4.5))
        corner = int(rng.integers(4))
        ox = bx0 if corner in (0, 2) else bx1 - ow
        oy = by0 if corner in (0, 1) else by1 - oh
        box = (ox, oy, ox + ow, oy + oh)
        grown = plan.sl((box[0] - 1.0, box[1] - 1.0, box[2] + 1.0, box[3] + 1.0))
        if not plan.protected[grown].any() and not plan.keepclear[grown].any():
            plan.walls(box, 0.12)
            plan.fill((box[0] + 0.12, box[1] + 0.12, box[2] - 0.12, box[3] - 0.12), FREE)
            d = float(rng.uniform(0.4, ow - 1.4))
            y_door = (oy + oh - 0.12, oy + oh) if corner in (0, 1) else (oy, oy + 0.12)
            plan.door((ox + d, y_door[0] - 0.05, ox + d + 1.0, y_door[1] + 0.05))
            _furnish(plan, (box[0] + 0.12, box[1] + 0.12, box[2] - 0.12, box[3] - 0.12))
            plan.keepclear[plan.sl(box)] = True

    # Pillar grid, skipping pillars in the open zone.
    sx, sy = float(rng.uniform(7.6, 10.0)), float(rng.uniform(7.6, 10.0))
    ps = float(rng.uniform(0.35, 0.6))
    x = bx0 + float(rng.uniform(3.0, sx))
    y_first = by0 + float(rng.uniform(3.0, sy))
    while x < bx1 - 2.0:
        y = y_first
        while y < by1 - 2.0:
            pillar = (x - ps / 2, y - ps / 2, x + ps / 2, y + ps / 2)
            if not plan.protected[plan.sl(pillar)].any() and plan.fits(pillar, 0.0):
                plan.fill(pillar, OCCUPIED)
            y += sy
        x += sx

    # Machines and pallet blocks.
    floor = (bx0, by0, bx1, by1)
    for _ in range(int(rng.integers(1, 4))):
        plan.place((float(rng.uniform(1.5, 4.0)), float(rng.uniform(1.2, 3.0))), floor, clearance=1.2)
    area = (bx1 - bx0) * (by1 - by0)
    for _ in range(int(area / 45.0)):
        rows, cols = int(rng.integers(1, 3)), int(rng.integers(1, 5))
        pw, ph = (1.2, 0.8) if rng.random() < 0.5 else (0.8, 1.2)
        block = (cols * pw + (cols - 1) * 0.1, rows * ph + (rows - 1) * 0.1)
        placed = plan.place(block, floor, clearance=1.0, tries=15)
        if placed is not None:
            # Gaps between the pallets of a block (the lidar sees into some of them).
            for c in range(1, cols):
                gx = placed[0] + c * (pw + 0.1) - 0.1
                plan.fill((gx, placed[1], gx + 0.1, placed[3]), FREE if rng.random() < 0.5 else OCCUPIED)
    return _finish(plan, "hall", seed, rotation)


# ------------------------------------------------------------------------------------------- registry
GENERATORS: dict[str, Callable[..., OccupancyMap]] = {"warehouse": warehouse, "office": office, "hall": hall}


def generate_map(kind: str, seed: int, **params: float) -> OccupancyMap:
    """Generate a procedural map of ``kind`` ("warehouse", "office", "hall"), deterministic in ``seed``.

    ``params``: ``width_m``, ``height_m`` (>= 12 m each), ``resolution`` (m/px, default 0.05).
    """
    if kind not in GENERATORS:
        raise ValueError(f"unknown map kind {kind!r}; choose one of {sorted(GENERATORS)}")
    allowed = {"width_m", "height_m", "resolution"}
    unknown = set(params) - allowed
    if unknown:
        raise ValueError(f"generate_map({kind!r}) got unknown parameters {sorted(unknown)}; allowed: {sorted(allowed)}")
    return GENERATORS[kind](seed, **params)
