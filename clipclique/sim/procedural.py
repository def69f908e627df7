"""Procedural indoor rooms for the demo: furniture groups as coloured meshes, seeded.

A room is a mesh in the ScanNet sense: vertices with colours, each vertex in one segment
(here: one part of an object, e.g. a chair leg), each segment in one object. Objects carry a
raw ScanNet-style category and a description naming their colour ("a red office chair"), so
that text about colour means something in the images. Several objects share a class (chairs
around a table, cups, books, monitors), as in real rooms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clipclique.sim.poses import look_at
from clipclique.types import Pose

# Colour words and the RGB the renderer paints them with.
PALETTE: dict[str, tuple[int, int, int]] = {
    "red": (190, 40, 40),
    "green": (50, 150, 60),
    "blue": (40, 80, 190),
    "yellow": (225, 200, 50),
    "orange": (230, 130, 30),
    "purple": (120, 60, 160),
    "pink": (230, 130, 170),
    "white": (230, 230, 225),
    "black": (35, 35, 38),
    "grey": (130, 130, 135),
    "brown": (120, 75, 40),
    "teal": (40, 140, 140),
    "beige": (215, 195, 160),
}
STRUCTURE_COLORS = {"wall": (200, 196, 188), "floor": (150, 120, 90), "ceiling": (235, 235, 235)}

# How each category is described; {c} is the object's colour word.
PHRASES = {
    "chair": "a {c} wooden chair",
    "office chair": "a {c} office chair",
    "armchair": "a {c} armchair",
    "table": "a {c} dining table",
    "desk": "a {c} desk",
    "coffee table": "a {c} coffee table",
    "sofa": "a {c} sofa",
    "bed": "a bed with a {c} cover",
    "pillow": "a {c} pillow",
    "nightstand": "a {c} nightstand",
    "cabinet": "a {c} cabinet",
    "bookshelf": "a {c} bookshelf",
    "book": "a {c} book",
    "cup": "a {c} cup",
    "monitor": "a {c} computer monitor",
    "keyboard": "a {c} keyboard",
    "lamp": "a lamp with a {c} shade",
    "tv": "a {c} television",
    "tv stand": "a {c} tv stand",
    "plant": "a potted plant in a {c} pot",
    "trash can": "a {c} trash can",
    "door": "a {c} door",
    "picture": "a {c} picture on the wall",
    "box": "a {c} storage box",
}


@dataclass
class RoomObject:
    object_id: int  # ScanNet objectId: 0-based position in the aggregation file
    category: str
    description: str


@dataclass
class Room:
    """A room mesh with per-vertex segments and per-segment objects."""

    size: np.ndarray  # (3,) interior extent in metres (x, y, z up); the floor is z = 0
    objects: list[RoomObject]
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int32
    vertex_colors: np.ndarray  # (V, 3) uint8
    vertex_segments: np.ndarray  # (V,) int32 segment id
    segment_objects: np.ndarray  # (S,) int32 object id of each segment
    focus: np.ndarray  # (G, 3) centres of the furniture groups, what a visitor looks at

    def face_objects(self) -> np.ndarray:
        return self.segment_objects[self.vertex_segments[self.faces[:, 0]]]

    def face_colors(self) -> np.ndarray:
        return self.vertex_colors[self.faces[:, 0]]


def _grid_box(size: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """A box centred at the origin, each face a grid of cells no wider than `spacing`."""
    vertices, faces = [], []
    for axis in range(3):
        b, c = [a for a in range(3) if a != axis]
        nb, nc = (max(1, int(np.ceil(size[k] / spacing))) for k in (b, c))
        gb, gc = np.meshgrid(np.linspace(-0.5, 0.5, nb + 1) * size[b], np.linspace(-0.5, 0.5, nc + 1) * size[c],
                             indexing="ij")
        idx = np.arange((nb + 1) * (nc + 1)).reshape(nb + 1, nc + 1)
        quads = np.stack((idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]), axis=-1).reshape(-1, 4)
        tris = np.concatenate((quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]))
        for sign in (-0.5, 0.5):
            grid = np.zeros((gb.size, 3))
            grid[:, axis], grid[:, b], grid[:, c] = sign * size[axis], gb.ravel(), gc.ravel()
            faces.append(tris + sum(len(v) for v in vertices))
            vertices.append(grid)
    return np.concatenate(vertices), np.concatenate(faces)


def _legacy_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)


class RoomBuilder:
    """Collects parts (one segment each) of objects (one aggregation segGroup each)."""

    def __init__(self, rng: np.random.Generator, spacing: float):
        self.rng = rng
        self.spacing = spacing
        self.objects: list[RoomObject] = []
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []  # vertices, faces, colour, object

    def add_object(self, category: str, color: str | None) -> int:
        description = PHRASES.get(category, "a {c} " + category).format(c=color) if color else category
        self.objects.append(RoomObject(len(self.objects), category, description))
        return len(self.objects) - 1

    def _place(self, vertices: np.ndarray, faces: np.ndarray, rgb, obj: int, at, yaw: float) -> None:
        c, s = np.cos(yaw), np.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self.parts.append((vertices @ rotation.T + np.asarray(at, float), faces, np.asarray(rgb, float), obj))

    def box(self, obj: int, rgb, size, at, yaw: float = 0.0, spacing: float | None = None) -> None:
        """A box of `size` whose centre is `at` (world), turned by `yaw` about z."""
        size = np.asarray(size, float)
        step = spacing or float(np.clip(size.max() / 10, 0.012, self.spacing))
        self._place(*_grid_box(size, step), rgb, obj, at, yaw)

    def cylinder(self, obj: int, rgb, radius: float, height: float, base) -> None:
        import open3d as o3d

        resolution = int(np.clip(2 * np.pi * radius / 0.02, 12, 48))
        mesh = o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution, max(1, int(height / 0.03)))
        vertices, faces = _legacy_arrays(mesh)
        self._place(vertices + [0.0, 0.0, height / 2], faces, rgb, obj, base, 0.0)

    def sphere(self, obj: int, rgb, radius: float, center) -> None:
        import open3d as o3d

        vertices, faces = _legacy_arrays(o3d.geometry.TriangleMesh.create_sphere(radius, 16))
        self._place(vertices, faces, rgb, obj, center, 0.0)

    def build(self, size: np.ndarray, focus: list) -> Room:
        offsets = np.cumsum([0] + [len(p[0]) for p in self.parts])
        vertices = np.concatenate([p[0] for p in self.parts])
        faces = np.concatenate([p[1] + off for p, off in zip(self.parts, offsets)]).astype(np.int32)
        counts = [len(p[0]) for p in self.parts]
        segments = np.repeat(np.arange(len(self.parts), dtype=np.int32), counts)
        base = np.repeat(np.array([p[2] for p in self.parts]), counts, axis=0)
        shade = self.rng.normal(1.0, 0.04, size=(len(vertices), 1))  # surface texture
        colors = np.clip(base * shade, 0, 255).astype(np.uint8)
        objects = np.array([p[3] for p in self.parts], dtype=np.int32)
        return Room(size, self.objects, vertices, faces, colors, segments, objects, np.array(focus, float))


def yaw_offset(yaw: float, dx: float, dy: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * dx - s * dy, s * dx + c * dy, 0.0])


class Furniture:
    """Object makers: each adds one object (several parts) and returns its id."""

    def __init__(self, builder: RoomBuilder, rng: np.random.Generator):
        self.b, self.rng = builder, rng

    def colors(self, k: int) -> list[str]:
        """k distinct colour words (objects of one group never share a colour)."""
        names = list(PALETTE)
        return [names[i] for i in self.rng.choice(len(names), size=k, replace=False)]

    def _legs(self, obj, rgb, at, yaw, w, d, h, inset=0.06, leg=0.045):
        for sx in (-1, 1):
            for sy in (-1, 1):
                pos = at + yaw_offset(yaw, sx * (w / 2 - inset), sy * (d / 2 - inset)) + [0, 0, h / 2]
                self.b.box(obj, rgb, (leg, leg, h), pos, yaw)

    def table(self, at, yaw, color, category="table", w=1.4, d=0.8, h=0.75) -> float:
        """Adds a table; returns its top height for things standing on it."""
        obj, rgb = self.b.add_object(category, color), PALETTE[color]
        self.b.box(obj, rgb, (w, d, 0.04), at + [0, 0, h - 0.02], yaw)
        self._legs(obj, rgb, at, yaw, w, d, h - 0.04)
        return h

    def chair(self, at, yaw, color) -> None:
        """A chair facing direction `yaw` (its back on the opposite side)."""
        obj, rgb = self.b.add_object("chair", color), PALETTE[color]
        self.b.box(obj, rgb, (0.45, 0.45, 0.05), at + [0, 0, 0.455], yaw)
        self.b.box(obj, rgb, (0.05, 0.45, 0.45), at + yaw_offset(yaw, -0.2, 0) + [0, 0, 0.7], yaw)
        self._legs(obj, rgb, at, yaw, 0.45, 0.45, 0.43, inset=0.03, leg=0.04)

    def office_chair(self, at, yaw, color) -> None:
        obj, rgb = self.b.add_object("office chair", color), PALETTE[color]
        self.b.box(obj, rgb, (0.5, 0.5, 0.08), at + [0, 0, 0.5], yaw)
        self.b.box(obj, rgb, (0.06, 0.48, 0.5), at + yaw_offset(yaw, -0.24, 0) + [0, 0, 0.82], yaw)
        self.b.cylinder(obj, PALETTE["black"], 0.03, 0.42, at + [0, 0, 0.04])
        for angle in (0.0, np.pi / 2):
            self.b.box(obj, PALETTE["black"], (0.6, 0.06, 0.05), at + [0, 0, 0.05], yaw + angle)

    def sofa(self, at, yaw, color, category="sofa", w=2.0) -> None:
        """A sofa facing `yaw`: seat block, back rest behind, an arm at each end."""
        obj, rgb = self.b.add_object(category, color), PALETTE[color]
        self.b.box(obj, rgb, (0.9, w, 0.42), at + [0, 0, 0.21], yaw)
        self.b.box(obj, rgb, (0.2, w, 0.4), at + yaw_offset(yaw, -0.35, 0) + [0, 0, 0.62], yaw)
        for side in (-1, 1):
            self.b.box(obj, rgb, (0.9, 0.18, 0.2), at + yaw_offset(yaw, 0, side * (w / 2 - 0.09)) + [0, 0, 0.52], yaw)

    def bed(self, at, yaw, color) -> None:
        """A bed along `yaw` (head board at the far end)."""
        obj = self.b.add_object("bed", color)
        self.b.box(obj, PALETTE["brown"], (2.0, 1.5, 0.3), at + [0, 0, 0.15], yaw)
        self.b.box(obj, PALETTE[color], (1.95, 1.45, 0.2), at + [0, 0, 0.4], yaw)
        self.b.box(obj, PALETTE["brown"], (0.06, 1.5, 0.95), at + yaw_offset(yaw, 0.97, 0) + [0, 0, 0.475], yaw)

    def block(self, category, at, yaw, color, size) -> None:
        """A one-part object (cabinet, pillow, book, keyboard ...) standing on `at`."""
        obj = self.b.add_object(category, color)
        self.b.box(obj, PALETTE[color], size, at + [0, 0, size[2] / 2], yaw)

    def bookshelf(self, at, yaw, color, book_colors: list[str]) -> None:
        obj, rgb = self.b.add_object("bookshelf", color), PALETTE[color]
        for side in (-1, 1):
            self.b.box(obj, rgb, (0.35, 0.03, 1.8), at + yaw_offset(yaw, 0, side * 0.4) + [0, 0, 0.9], yaw)
        self.b.box(obj, rgb, (0.02, 0.8, 1.8), at + yaw_offset(yaw, -0.165, 0) + [0, 0, 0.9], yaw)
        for z in np.linspace(0.05, 1.75, 5):
            self.b.box(obj, rgb, (0.35, 0.8, 0.03), at + [0, 0, z], yaw)
        for k, book in enumerate(book_colors):  # standing on the shelves, spine out
            shelf_z = np.linspace(0.05, 1.75, 5)[1 + k % 3] + 0.015
            offset = yaw_offset(yaw, 0.0, -0.25 + 0.17 * (k // 3) + 0.05 * (k % 2))
            self.block("book", at + offset + [0, 0, shelf_z], yaw, book, (0.22, 0.05, 0.26))

    def monitor(self, at, yaw, color) -> None:
        obj, rgb = self.b.add_object("monitor", color), PALETTE[color]
        self.b.box(obj, rgb, (0.22, 0.16, 0.015), at + [0, 0, 0.0075], yaw)
        self.b.box(obj, rgb, (0.04, 0.04, 0.14), at + [0, 0, 0.085], yaw)
        self.b.box(obj, rgb, (0.035, 0.56, 0.34), at + yaw_offset(yaw, 0.03, 0) + [0, 0, 0.32], yaw)

    def lamp(self, at, color, height: float) -> None:
        obj = self.b.add_object("lamp", color)
        self.b.cylinder(obj, PALETTE["grey"], 0.1, 0.03, at)
        self.b.cylinder(obj, PALETTE["grey"], 0.015, height - 0.2, at + [0, 0, 0.03])
        self.b.cylinder(obj, PALETTE[color], 0.16, 0.24, at + [0, 0, height - 0.24])

    def cylinder_object(self, category, at, color, radius, height) -> None:
        obj = self.b.add_object(category, color)
        self.b.cylinder(obj, PALETTE[color], radius, height, at)

    def plant(self, at, color) -> None:
        obj = self.b.add_object("plant", color)
        self.b.cylinder(obj, PALETTE[color], 0.15, 0.32, at)
        self.b.sphere(obj, (60, 120, 50), 0.3, at + [0, 0, 0.6])

    def tabletop_items(self, top, yaw, n_cups, n_books, spread) -> None:
        """Cups and books scattered on a table top around `top` (world, z = top height)."""
        colors = self.colors(n_cups + n_books)
        slots = self.rng.permutation(8)[: n_cups + n_books]
        for k, (slot, color) in enumerate(zip(slots, colors)):
            angle = 2 * np.pi * slot / 8 + self.rng.uniform(-0.2, 0.2)
            pos = top + np.array([np.cos(angle) * spread[0], np.sin(angle) * spread[1], 0.0])
            if k < n_cups:
                self.cylinder_object("cup", pos, color, 0.04, 0.1)
            else:
                self.block("book", pos, yaw + self.rng.uniform(-0.5, 0.5), color, (0.23, 0.16, 0.035))


def add_shell(b: RoomBuilder, size: np.ndarray, walls: list[tuple[float, float, float, float]], spacing: float) -> None:
    """Floor, ceiling, the four outer walls, then inner wall segments (x0, y0, x1, y1), each along an axis."""
    W, D, H = size
    for name, dims, at in (
        ("floor", (W, D, 0.1), (W / 2, D / 2, -0.05)),
        ("ceiling", (W, D, 0.1), (W / 2, D / 2, H + 0.05)),
        ("wall", (W + 0.2, 0.1, H), (W / 2, -0.05, H / 2)),
        ("wall", (W + 0.2, 0.1, H), (W / 2, D + 0.05, H / 2)),
        ("wall", (0.1, D, H), (-0.05, D / 2, H / 2)),
        ("wall", (0.1, D, H), (W + 0.05, D / 2, H / 2)),
    ):
        b.box(b.add_object(name, None), STRUCTURE_COLORS[name], dims, at, spacing=spacing)
    for x0, y0, x1, y1 in walls:
        dims = (max(x1 - x0, 0.1), max(y1 - y0, 0.1), H)
        b.box(b.add_object("wall", None), STRUCTURE_COLORS["wall"], dims, ((x0 + x1) / 2, (y0 + y1) / 2, H / 2),
              spacing=spacing)


def make_room(seed: int, size=(8.0, 6.0, 2.7), wall_spacing: float = 0.12, spacing: float = 0.05,
              boxes: int = 0) -> Room:
    """A furnished room (about 40 objects plus walls, floor and ceiling), the same for the same seed.

    `spacing` bounds the mesh's vertex spacing on furniture; `boxes` (at most 8) adds storage
    boxes in a row along the wall y = D, for scenes with more objects.
    """
    rng = np.random.default_rng(seed)
    size = np.asarray(size, float)
    W, D, _ = size
    b = RoomBuilder(rng, spacing)
    f = Furniture(b, rng)

    def spot(x, y, rx=0.12, ry=0.12):
        """A floor point near (x, y), moved by up to (rx, ry) metres."""
        return np.array([x + rng.uniform(-rx, rx), y + rng.uniform(-ry, ry), 0.0])

    add_shell(b, size, [], wall_spacing)

    # Office corner: desk against the wall y = 0, two monitors, keyboard, lamp, chair.
    desk = spot(1.6, 0.4, 0.1, 0.0)
    top = f.table(desk, 0.0, *f.colors(1), category="desk", w=1.5, d=0.7)
    for dx, color in zip((-0.35, 0.35), f.colors(2)):
        f.monitor(desk + [dx, -0.15, top], np.pi / 2 + rng.uniform(-0.2, 0.2), color)
    f.block("keyboard", desk + [0, 0.12, top], 0.0, *f.colors(1), (0.44, 0.14, 0.025))
    f.lamp(desk + [0.62, -0.12, top], *f.colors(1), height=0.45)
    f.tabletop_items(desk + [-0.55, 0.15, top], 0.0, 1, int(rng.integers(0, 2)), (0.08, 0.05))
    f.office_chair(desk + [rng.uniform(-0.2, 0.2), 0.8, 0], -np.pi / 2 + rng.uniform(-0.5, 0.5), *f.colors(1))

    # Bookshelf against the wall x = 0, with books.
    shelf_color, *book_colors = f.colors(1 + int(rng.integers(3, 6)))
    f.bookshelf(spot(0.2, 2.3, 0.0, 0.1), 0.0, shelf_color, book_colors)

    # Dining group: table, four chairs around it, cups and books on it.
    dining = spot(2.6, 3.7)
    dining_yaw = rng.uniform(-0.15, 0.15)
    top = f.table(dining, dining_yaw, *f.colors(1))
    for (dx, dy, face), color in zip(((0.75, 0, np.pi), (-0.75, 0, 0.0), (0.3, 0.62, -np.pi / 2),
                                      (-0.3, -0.62, np.pi / 2)), f.colors(4)):
        f.chair(dining + yaw_offset(dining_yaw, dx, dy) + [*rng.uniform(-0.05, 0.05, 2), 0],
                dining_yaw + face + rng.uniform(-0.2, 0.2), color)
    f.tabletop_items(dining + [0, 0, top], dining_yaw, int(rng.integers(1, 4)), int(rng.integers(1, 3)), (0.45, 0.22))

    # Lounge: sofa against the wall y = D facing the room, coffee table, armchair, TV on a stand.
    sofa = spot(5.6, D - 0.5, 0.1, 0.0)
    f.sofa(sofa, -np.pi / 2, *f.colors(1))
    coffee = sofa + [rng.uniform(-0.1, 0.1), -1.05, 0]
    top = f.table(coffee, 0.0, *f.colors(1), category="coffee table", w=1.0, d=0.55, h=0.42)
    f.tabletop_items(coffee + [0, 0, top], 0.0, int(rng.integers(1, 3)), 1, (0.3, 0.12))
    f.sofa(spot(4.3, 4.4, 0.05, 0.1), rng.uniform(-0.3, 0.3), *f.colors(1), category="armchair", w=0.9)
    stand = spot(W - 0.25, 4.1, 0.0, 0.1)
    f.block("tv stand", stand, np.pi / 2, *f.colors(1), (1.2, 0.4, 0.5))
    f.block("tv", stand + [0.05, 0, 0.5], np.pi / 2, *f.colors(1), (1.0, 0.05, 0.6))

    # Bed corner: bed along the wall x = W, pillows, nightstand with a lamp and a book.
    bed = spot(W - 1.05, 0.8, 0.0, 0.0)
    f.bed(bed, 0.0, *f.colors(1))
    for dy, color in zip((-0.35, 0.35), f.colors(2)):
        f.block("pillow", bed + [0.7, dy, 0.5], 0.0, color, (0.3, 0.5, 0.12))
    night = bed + [0.75, 0.75 + 0.3, 0]
    f.block("nightstand", night, 0.0, *f.colors(1), (0.42, 0.4, 0.55))
    f.lamp(night + [0.05, 0.06, 0.55], *f.colors(1), height=0.4)

    # Along the walls.
    f.block("cabinet", spot(4.2, 0.25, 0.15, 0.0), 0.0, *f.colors(1), (0.9, 0.45, 0.9))
    f.cylinder_object("trash can", spot(3.2, 0.3, 0.1, 0.05), *f.colors(1), 0.15, 0.35)
    f.plant(spot(0.4, D - 0.4, 0.05, 0.05), *f.colors(1))
    f.lamp(spot(7.4, D - 0.35, 0.05, 0.05), *f.colors(1), height=1.55)
    f.block("door", np.array([0.03, 4.8, 0.0]), np.pi / 2, *f.colors(1), (0.9, 0.04, 2.05))
    f.block("picture", np.array([2.8, D - 0.006, 1.3]), 0.0, *f.colors(1), (0.6, 0.01, 0.45))  # too flat to map

    for k, color in enumerate(f.colors(min(boxes, 8))):
        f.block("box", np.array([0.9 + 0.42 * k, D - 0.25, 0.0]), rng.uniform(-0.2, 0.2), color, (0.35, 0.3, 0.3))

    focus = [desk + [0, 0, 0.9], (0.3, 2.3, 1.0), dining + [0, 0, 0.7], sofa + [0, -0.8, 0.5], stand + [0, 0, 0.7],
             bed + [0.2, 0, 0.6], (4.2, 0.3, 0.6)]
    return b.build(size, focus)


@dataclass
class Walk:
    """A hand-held walk through a room: smooth path, gaze moving between furniture groups, shake."""

    times: np.ndarray  # (T,) seconds of the rendered frames
    knots: np.ndarray  # (K,) seconds of the waypoints
    eyes: np.ndarray  # (K, 3)
    targets: np.ndarray  # (K, 3)
    shake: np.ndarray  # (18, 3) sinusoids (rad/s, phase, amplitude): 9 for position (m), 9 for rotation (rad)
    monotone: bool = False  # PCHIP between the waypoints: no overshoot where a quick turn meets a held view

    def poses(self, times: np.ndarray) -> list[Pose]:
        """Camera-to-world poses at `times` (seconds): spline path and gaze, then hand shake."""
        from scipy.interpolate import CubicSpline, PchipInterpolator
        from scipy.spatial.transform import Rotation

        times = np.asarray(times, float)
        spline = PchipInterpolator if self.monotone else CubicSpline
        eyes = spline(self.knots, self.eyes)(times)
        targets = spline(self.knots, self.targets)(times)
        waves = self.shake[:, 2] * np.sin(np.outer(times, self.shake[:, 0]) + self.shake[:, 1])
        wobble = waves.reshape(len(times), 2, -1, 3).sum(axis=2)  # (T, 2, 3): position, rotation vector
        shakes = Rotation.from_rotvec(wobble[:, 1]).as_matrix()
        poses = []
        for eye, target, shake in zip(eyes + wobble[:, 0], targets, shakes):
            base = look_at(eye, target)
            poses.append(Pose(base.rotation @ shake, base.translation))
        return poses


def make_walk(room: Room, seed: int, num_frames: int, duration: float) -> Walk:
    """A loop past every furniture group, standing 1.8-2.8 m away at eye height."""
    rng = np.random.default_rng(seed)
    center = np.array([room.size[0] / 2, room.size[1] / 2, 0.0])
    order = np.argsort(np.arctan2(room.focus[:, 1] - center[1], room.focus[:, 0] - center[0]))
    targets = room.focus[np.concatenate((order, order[:1]))]
    away = center - targets
    away[:, 2] = 0
    angles = rng.uniform(-0.5, 0.5, len(targets))
    c, s = np.cos(angles), np.sin(angles)
    away = np.column_stack((c * away[:, 0] - s * away[:, 1], s * away[:, 0] + c * away[:, 1], np.zeros(len(away))))
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    eyes = targets + away * rng.uniform(1.8, 2.8, (len(targets), 1))
    margin = 0.8
    eyes[:, 0] = np.clip(eyes[:, 0], margin, room.size[0] - margin)
    eyes[:, 1] = np.clip(eyes[:, 1], margin, room.size[1] - margin)
    eyes[:, 2] = rng.uniform(1.35, 1.65, len(eyes))
    knots = np.linspace(0.0, duration, len(eyes))
    return Walk(np.linspace(0.0, duration, num_frames, endpoint=False), knots, eyes, targets, hand_shake(rng))


def hand_shake(rng: np.random.Generator) -> np.ndarray:
    """`Walk.shake`: 18 seeded sinusoids, 8 mm of position and 6 mrad of rotation each."""
    return np.column_stack((
        rng.uniform(0.5, 3.0, 18),  # rad/s
        rng.uniform(0, 2 * np.pi, 18),
        np.concatenate((np.full(9, 0.008), np.full(9, 0.006))),  # metres; radians
    ))
