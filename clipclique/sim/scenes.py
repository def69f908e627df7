"""Two procedural scenes shaped like real data (docs/REAL_SCENES.md), for the demo generator.

- `make_apartment`: a ScanNet-like apartment (7.5 x 8 m inside: open living room and kitchen,
  hall, bedroom, bathroom): 45 objects of 32 classes, most classes once, 6 cabinets, sparse
  furniture (44% of the objects have no neighbour within 0.8 m) and large objects (an L-shaped
  kitchen counter, couch, bed, curtains, bath towel) that a frame sees only in part.
- `make_desk`: a TUM fr2/desk-like office: two desks end to end crowded with 47 objects of 19
  COCO classes (8 cups, 7 books, 4 chairs, ...), so dense that most objects have more than
  a dozen neighbours within 0.8 m.

Each comes with a hand-held walk (`apartment_walk`, `desk_walk`; `clutter_walk` keeps to the desk
tops for demo_clutter, the desk seen closer and with a noisier detector): waypoints through the scene
with seeded jitter. `make_sparse_desk` is the office with three corner groups of 3-5 objects each, and
`sparse_walk` (demo_sparse) mostly looks at the desk tops but turns to a corner for stretches of 1-3 s:
where real runs of failures are (issue 37).
Layouts are fixed by hand where the statistics depend on them; the seed moves
objects by a few centimetres and picks colours.
"""

from __future__ import annotations

import numpy as np

from clipclique.sim.procedural import (
    PALETTE,
    Furniture,
    Room,
    RoomBuilder,
    Walk,
    add_shell,
    hand_shake,
    yaw_offset,
)

WALL_SPACING = 0.12


def _curtain(f: Furniture, at, yaw: float, color: str, width: float, height: float) -> None:
    """A curtain with folds: vertical strips at alternating depth, hanging from `height` to 10 cm above `at`."""
    obj, rgb = f.b.add_object("curtain", color), PALETTE[color]
    folds = max(2, int(round(width / 0.2)))
    for k in range(folds):
        offset = yaw_offset(yaw, 0.05 * (k % 2), -width / 2 + (k + 0.5) * width / folds)
        f.b.box(obj, rgb, (0.03, width / folds + 0.02, height - 0.1), at + offset + [0, 0, 0.1 + (height - 0.1) / 2],
                yaw)


def make_apartment(seed: int) -> Room:
    """The apartment: open living room and kitchen with dining table, hall, bedroom, bathroom."""
    rng = np.random.default_rng(seed)
    size = np.array([7.5, 8.0, 2.5])
    b = RoomBuilder(rng, 0.06)
    f = Furniture(b, rng)
    add_shell(b, size, [
        (3.95, 3.45, 4.05, 4.6), (3.95, 5.5, 4.05, 8.0),  # living room | hall, bedroom | hall
        (0.0, 4.55, 0.9, 4.65), (2.4, 4.55, 3.95, 4.65),  # living room | bedroom (a wide double door)
        (4.05, 3.35, 5.2, 3.45), (6.2, 3.35, 7.5, 3.45),  # kitchen | hall
        (4.9, 5.35, 6.0, 5.45), (6.9, 5.35, 7.5, 5.45), (4.85, 5.45, 4.95, 8.0),  # bathroom
    ], WALL_SPACING)

    def at(x, y, z=0.0, r=0.04):
        """A point near (x, y, z), moved by up to r metres in x and y."""
        return np.array([x + rng.uniform(-r, r), y + rng.uniform(-r, r), z])

    def color() -> str:
        return f.colors(1)[0]

    # Living room (x 0-4, y 0-4.6): couch and coffee table, tv on its stand, armchair; along the walls
    # a bookshelf, floor lamp, plant and the window's curtain.
    f.sofa(at(0.5, 2.4), 0.0, color(), category="couch", w=2.1)
    f.table(at(1.2, 2.4), np.pi / 2, color(), category="coffee table", w=1.0, d=0.55, h=0.42)
    f.sofa(at(1.25, 3.35), -np.pi / 2, color(), category="armchair", w=0.9)
    stand = at(3.7, 3.85)
    f.block("tv stand", stand, np.pi / 2, color(), (1.4, 0.42, 0.5))
    f.block("tv", stand + [0.02, 0, 0.5], np.pi / 2, color(), (1.1, 0.06, 0.65))
    _curtain(f, at(1.9, 0.1, r=0.0), np.pi / 2, color(), 1.8, 2.1)
    f.block("bookshelf", at(0.22, 0.75, r=0.0), 0.0, color(), (0.4, 0.9, 1.9))
    f.lamp(at(0.35, 4.2), color(), height=1.6)
    f.plant(at(3.6, 0.4), color())

    # Kitchen (x 4-7.5, y 0-3.4): L-shaped counter along the walls with sink, stove and microwave, wall cabinets
    # above, a tall pantry cabinet, fridge, dining table with four chairs.
    counter, rgb = b.add_object("kitchen counter", "white"), PALETTE["white"]  # an L along two walls
    b.box(counter, rgb, (2.8, 0.62, 0.9), (6.05, 0.32, 0.45))
    b.box(counter, rgb, (0.62, 1.3, 0.9), (7.14, 1.27, 0.45))
    f.block("sink", at(5.45, 0.32, 0.9, r=0.0), 0.0, "grey", (0.6, 0.45, 0.12))
    f.block("stove", at(6.1, 0.32, 0.9, r=0.0), 0.0, "black", (0.6, 0.55, 0.05))
    f.block("microwave", at(6.75, 0.3, 0.9, r=0.0), 0.0, color(), (0.5, 0.38, 0.3))
    for x in (5.0, 6.1):
        f.block("cabinet", at(x, 0.18, 1.45, r=0.0), 0.0, color(), (0.9, 0.35, 0.7))
    f.block("cabinet", at(4.4, 0.35, r=0.0), 0.0, color(), (0.6, 0.6, 2.0))
    f.block("refrigerator", at(7.12, 2.5, r=0.0), 0.0, color(), (0.7, 0.75, 1.8))
    f.cylinder_object("trash can", at(4.35, 2.55), color(), 0.16, 0.4)
    table = at(5.6, 2.15)
    top = f.table(table, 0.0, color(), w=1.0, d=0.8)
    for (dx, dy, face), c in zip(((0.32, 0.55, -np.pi / 2), (-0.32, 0.55, -np.pi / 2), (0.32, -0.55, np.pi / 2),
                                  (-0.32, -0.55, np.pi / 2)), f.colors(4)):
        f.chair(table + [dx, dy, 0] + [*rng.uniform(-0.04, 0.04, 2), 0], face + rng.uniform(-0.2, 0.2), c)
    f.cylinder_object("bowl", table + [0.3, 0.1, top], color(), 0.12, 0.09)

    # Hall (x 4-7.5, y 3.4-5.4, and the corridor x 4-4.9 to the back): front door, shoe rack, coat rack.
    f.block("door", np.array([7.47, 4.4, 0.0]), 0.0, color(), (0.05, 0.9, 2.05))
    f.cylinder_object("coat rack", at(4.4, 7.75), color(), 0.06, 1.75)
    f.block("shoe rack", at(4.45, 6.9, r=0.0), 0.0, color(), (0.32, 0.9, 0.5))

    # Bedroom (x 0-4, y 4.6-8): bed with two pillows, nightstand and lamp, dresser, wardrobe, desk
    # with office chair, laundry basket, the window's curtain.
    bed = at(1.3, 6.95, r=0.0)
    f.bed(bed, np.pi / 2, color())
    for dx, c in zip((-0.35, 0.35), f.colors(2)):
        f.block("pillow", bed + [dx, 0.55, 0.5], 0.0, c, (0.5, 0.3, 0.12))
    night = bed + [1.05, 0.72, 0]
    f.block("nightstand", night, 0.0, color(), (0.42, 0.4, 0.55))
    f.lamp(night + [0.0, 0.05, 0.55], color(), height=0.42)
    f.block("dresser", at(1.2, 4.92, r=0.0), 0.0, color(), (1.2, 0.5, 0.9))
    f.block("cabinet", at(0.35, 5.3, r=0.0), 0.0, color(), (0.6, 1.0, 2.0))
    _curtain(f, at(0.1, 6.6, r=0.0), 0.0, color(), 1.4, 2.1)
    desk = at(3.6, 6.7, r=0.0)
    f.table(desk, np.pi / 2, color(), category="desk", w=1.2, d=0.6)
    f.office_chair(desk + [-0.6, 0.0, 0.0], 0.0, color())
    f.cylinder_object("laundry basket", at(3.7, 5.8), color(), 0.22, 0.5)

    # Bathroom (x 4.9-7.5, y 5.4-8): bathtub with a bath towel on the wall, vanity cabinet with sink
    # and mirror cabinet, hand towel, toilet.
    f.block("bathtub", at(6.62, 7.6, r=0.0), 0.0, "white", (1.65, 0.75, 0.55))
    f.block("towel", at(7.46, 6.6, 0.4, r=0.0), 0.0, color(), (0.04, 1.2, 1.5))
    vanity = at(5.2, 6.0, r=0.0)
    f.block("cabinet", vanity, 0.0, color(), (0.55, 0.8, 0.8))
    f.block("sink", vanity + [0.0, 0, 0.8], 0.0, "white", (0.48, 0.6, 0.14))
    f.block("cabinet", vanity + [-0.22, 0, 1.2], 0.0, color(), (0.15, 0.6, 0.7))
    f.block("towel", at(4.93, 6.5, 0.75, r=0.0), 0.0, color(), (0.04, 0.4, 0.6))
    toilet = at(5.35, 7.45, r=0.0)
    obj = b.add_object("toilet", "white")
    b.cylinder(obj, PALETTE["white"], 0.19, 0.42, toilet + [0.0, -0.15, 0])
    b.box(obj, PALETTE["white"], (0.45, 0.2, 0.4), toilet + [0.0, 0.3, 0.6])

    return b.build(size, [])


def make_desk(seed: int, corners: bool = False) -> Room:
    """The office: two desks end to end (3.4 m) crowded with things, chairs, and a side shelf; with `corners`
    also `_corner_groups` (added after the rest, so that the desk's objects are the same)."""
    rng = np.random.default_rng(seed)
    size = np.array([7.0, 5.0, 2.6])
    b = RoomBuilder(rng, 0.04)
    f = Furniture(b, rng)
    add_shell(b, size, [], WALL_SPACING)
    y0 = 0.8  # desks' centre line; their backs face the wall y = 0.4
    for x, w in ((1.9, 1.8), (3.65, 1.7)):
        f.table(np.array([x, y0, 0.0]), 0.0, f.colors(1)[0], category="dining table", w=w, d=0.8, h=0.72)
    top = 0.72
    # Free places on the desk tops: a grid, less where keyboards and mice lie.
    cells = [(x, y) for x in np.linspace(1.35, 3.95, 13) for y in (y0 - 0.1, y0 + 0.1, y0 + 0.3)
             if not (y == y0 + 0.1 and min(abs(x - 1.7), abs(x - 3.7)) < 0.4)]
    free = iter(rng.permutation(len(cells)))

    def spot() -> np.ndarray:
        x, y = cells[next(free)]
        return np.array([x + rng.uniform(-0.04, 0.04), y + rng.uniform(-0.03, 0.03), top])

    colors = list(PALETTE)

    def color() -> str:
        return colors[int(rng.integers(len(colors)))]

    for x in (1.5, 2.4, 3.5):  # monitors along the back, keyboards and mice in front
        f.block("tv", np.array([x, y0 - 0.28, top + 0.06]), 0.0, color(), (0.5, 0.04, 0.32))
    for x in (1.5, 3.5):
        f.block("keyboard", np.array([x, y0 + 0.12, top]), 0.0, color(), (0.44, 0.14, 0.025))
    for x in (1.85, 3.85, 2.75):
        f.block("mouse", np.array([x, y0 + 0.15, top]), rng.uniform(-0.5, 0.5), color(), (0.11, 0.065, 0.04))
    for _ in range(8):
        f.cylinder_object("cup", spot(), color(), 0.04, 0.1)
    for _ in range(7):
        f.block("book", spot(), rng.uniform(-0.6, 0.6), color(), (0.24, 0.17, 0.04))
    for _ in range(2):
        f.cylinder_object("bowl", spot(), color(), 0.08, 0.06)
    for _ in range(2):
        f.cylinder_object("bottle", spot(), color(), 0.035, 0.24)
    for _ in range(2):
        f.block("cell phone", spot(), rng.uniform(-0.8, 0.8), color(), (0.15, 0.075, 0.025))
    for category, dims in (("fork", (0.19, 0.035, 0.025)), ("knife", (0.21, 0.03, 0.025)),
                           ("spoon", (0.17, 0.045, 0.025)),
                           ("scissors", (0.2, 0.08, 0.025)), ("remote", (0.19, 0.05, 0.025))):
        f.block(category, spot(), rng.uniform(-0.8, 0.8), color(), dims)
    f.block("laptop", spot(), 0.0, color(), (0.34, 0.24, 0.025))
    bear = spot()
    obj = b.add_object("teddy bear", "brown")
    b.sphere(obj, PALETTE["brown"], 0.09, bear + [0, 0, 0.09])
    b.sphere(obj, PALETTE["brown"], 0.06, bear + [0, 0, 0.23])
    for _ in range(2):
        f.cylinder_object("vase", spot(), color(), 0.05, 0.22)
    _potted_plant(b, spot(), color(), 0.07)

    for x, yaw in ((1.55, -np.pi / 2), (3.5, -np.pi / 2), (2.6, -np.pi / 2 + 0.6)):  # office chairs at the desks
        f.chair(np.array([x + rng.uniform(-0.1, 0.1), y0 + 0.75 + rng.uniform(-0.1, 0.1), 0.0]), yaw, color())
    # A side shelf far from the desks with a vase and a plant, and a spare chair: sparse corners.
    f.chair(np.array([5.75, 3.45, 0.0]), np.pi, color())
    f.cylinder_object("vase", np.array([0.55, 3.4, 0.0]), color(), 0.08, 0.4)
    _potted_plant(b, np.array([5.8, 1.2, 0.0]), color(), 0.15)
    if corners:
        _corner_groups(f, color)
    return b.build(size, [])


def make_sparse_desk(seed: int) -> Room:
    """The office with three corner groups of a handful of confusable objects (`_corner_groups`)."""
    return make_desk(seed, corners=True)


def _corner_groups(f: Furniture, color) -> None:
    """Three groups of 3-5 objects, each seen from where no desk is in view: a side table right of the desks
    (with the floor plant beside it), a low table by the left wall, and the spare chair's table at the back.
    Every class here has look-alikes (detector_lookalikes.csv), as the confused real corners' have."""
    top = f.table(np.array([6.35, 0.85, 0.0]), 0.0, color(), category="dining table", w=0.7, d=0.5, h=0.7)
    f.cylinder_object("cup", np.array([6.2, 0.75, top]), color(), 0.045, 0.11)
    f.block("book", np.array([6.5, 0.95, top]), 0.3, color(), (0.24, 0.17, 0.04))
    f.cylinder_object("bottle", np.array([6.45, 0.7, top]), color(), 0.04, 0.26)
    top = f.table(np.array([0.45, 2.0, 0.0]), np.pi / 2, color(), category="dining table", w=0.8, d=0.5, h=0.55)
    f.cylinder_object("vase", np.array([0.4, 1.75, top]), color(), 0.06, 0.26)
    f.cylinder_object("bowl", np.array([0.5, 2.2, top]), color(), 0.09, 0.07)
    f.block("remote", np.array([0.45, 2.0, top]), 0.5, color(), (0.19, 0.05, 0.025))
    top = f.table(np.array([6.3, 4.35, 0.0]), 0.0, color(), category="dining table", w=0.8, d=0.5, h=0.7)
    f.block("laptop", np.array([6.2, 4.35, top]), 0.2, color(), (0.34, 0.24, 0.025))
    f.cylinder_object("cup", np.array([6.55, 4.25, top]), color(), 0.045, 0.11)


def _potted_plant(b: RoomBuilder, at: np.ndarray, color: str, radius: float) -> None:
    """A pot of `radius` with a ball of leaves (COCO's "potted plant")."""
    obj = b.add_object("potted plant", color)
    b.cylinder(obj, PALETTE[color], radius, 2 * radius, at)
    b.sphere(obj, (60, 120, 50), 1.8 * radius, at + [0, 0, 3.6 * radius])


def _walk(rng: np.random.Generator, eyes: np.ndarray, targets: np.ndarray, num_frames: int, duration: float,
          jitter: float) -> Walk:
    """Waypoints (eye, target) moved by up to `jitter` metres, spread evenly over `duration`, with hand shake."""
    eyes = eyes + rng.uniform(-jitter, jitter, eyes.shape) * [1, 1, 0.5]
    targets = targets + rng.uniform(-jitter, jitter, targets.shape)
    knots = np.linspace(0.0, duration, len(eyes))
    return Walk(np.linspace(0.0, duration, num_frames, endpoint=False), knots, eyes, targets, hand_shake(rng))


def apartment_walk(room: Room, seed: int, num_frames: int, duration: float) -> Walk:
    """Through living room, kitchen, hall, bedroom and bathroom, often close to large furniture."""
    del room
    route = np.array([
        # eye (x, y, z)          target
        [3.5, 0.6, 1.7, 0.8, 3.2, 0.5],    # living room: couch, armchair, lamp, tv
        [3.3, 2.8, 1.7, 0.5, 1.0, 0.5],    # bookshelf, curtain, couch, coffee table
        [2.6, 1.6, 1.6, 1.2, 0.0, 0.8],    # near the curtain
        [0.9, 0.9, 1.75, 5.5, 2.2, 0.5],   # across to the kitchen
        [1.9, 3.9, 1.75, 6.0, 1.0, 0.5],   # across to the kitchen from the armchair
        [4.5, 3.0, 1.7, 6.5, 0.6, 0.6],    # kitchen: counter, cabinets, table, chairs
        [5.6, 1.15, 1.5, 6.3, 0.2, 0.7],   # close to the counter
        [6.5, 1.5, 1.7, 4.0, 2.6, 0.5],    # table, pantry, the living room
        [6.5, 2.0, 1.75, 2.0, 3.0, 0.5],   # across everything
        [6.4, 1.1, 1.75, 1.0, 2.0, 0.5],   # the living room from the kitchen
        [4.6, 2.9, 1.7, 1.0, 1.5, 0.5],    # the living room from the kitchen door
        [5.7, 3.0, 1.6, 7.4, 4.5, 0.9],    # through to the hall: front door
        [4.45, 5.0, 1.6, 1.5, 6.6, 0.5],   # bedroom door
        [3.1, 5.4, 1.7, 0.5, 7.3, 0.5],    # bedroom: bed, pillows, curtain
        [1.1, 5.5, 1.7, 3.4, 7.3, 0.5],    # nightstand, lamp, desk, chair
        [1.6, 5.4, 1.5, 1.6, 7.5, 0.4],    # close to the bed
        [2.9, 5.6, 1.7, 0.6, 4.2, 0.6],    # dresser, wardrobe, the living room through the double door
        [2.0, 5.2, 1.75, 2.0, 2.0, 0.5],   # into the living room
        [5.2, 4.6, 1.7, 6.3, 7.0, 0.5],    # back to the hall, into the bathroom
        [6.45, 5.2, 1.7, 5.6, 7.2, 0.5],   # bathroom door: toilet, bathtub
        [7.2, 5.7, 1.75, 5.1, 6.9, 0.5],   # vanity, mirror cabinet, hand towel, toilet, bathtub
        [6.4, 6.8, 1.5, 7.5, 6.4, 0.9],    # close to the bath towel
    ])
    return _walk(np.random.default_rng(seed), route[:, :3], route[:, 3:], num_frames, duration, 0.05)


def desk_walk(room: Room, seed: int, num_frames: int, duration: float) -> Walk:
    """Around the desks at 1-2.5 m, looking at their tops, as in TUM fr2/desk."""
    del room
    route = np.array([
        # eye (x, y, z)          target
        [1.2, 2.05, 1.45, 2.0, 0.8, 0.75],
        [2.0, 2.15, 1.5, 2.3, 0.8, 0.75],
        [3.0, 2.05, 1.5, 2.9, 0.8, 0.75],
        [4.1, 1.95, 1.45, 3.5, 0.8, 0.75],
        [4.8, 1.65, 1.4, 3.4, 0.8, 0.75],
        [4.0, 2.6, 1.55, 5.8, 3.4, 0.4],   # a look at the spare chair and the plant
        [3.2, 2.15, 1.55, 2.7, 0.8, 0.7],
        [2.2, 2.4, 1.5, 0.5, 3.4, 0.3],    # a look at the floor vase
        [0.6, 1.75, 1.45, 2.0, 0.8, 0.75],
        [0.9, 2.35, 1.55, 2.5, 0.8, 0.75],
        [1.9, 1.95, 1.4, 1.9, 0.8, 0.75],
        [3.4, 2.05, 1.45, 3.0, 0.8, 0.75],
        [1.2, 2.05, 1.45, 2.0, 0.8, 0.75],
    ])
    return _walk(np.random.default_rng(seed), route[:, :3], route[:, 3:], num_frames, duration, 0.08)


def clutter_walk(room: Room, seed: int, num_frames: int, duration: float) -> Walk:
    """Along the desks at 0.9-1.6 m, always looking at their tops (no look at the sparse corners): as
    in TUM fr2/desk, almost every frame sees three or more mapped objects, most of them small."""
    del room
    route = np.array([
        # eye (x, y, z)          target
        [1.3, 1.75, 1.35, 1.9, 0.75, 0.74],
        [2.1, 1.85, 1.4, 2.4, 0.75, 0.74],
        [2.9, 1.7, 1.35, 3.0, 0.75, 0.74],
        [3.9, 1.8, 1.4, 3.5, 0.75, 0.74],
        [4.5, 1.5, 1.35, 3.4, 0.8, 0.74],
        [3.6, 2.1, 1.5, 2.8, 0.8, 0.72],
        [2.4, 2.0, 1.45, 1.8, 0.8, 0.72],
        [1.0, 1.55, 1.35, 1.9, 0.8, 0.74],
        [1.5, 2.0, 1.5, 2.6, 0.75, 0.72],
        [3.0, 1.9, 1.4, 3.6, 0.75, 0.74],
        [4.2, 1.7, 1.4, 3.0, 0.8, 0.74],
        [2.6, 1.6, 1.3, 2.2, 0.75, 0.74],
    ])
    return _walk(np.random.default_rng(seed), route[:, :3], route[:, 3:], num_frames, duration, 0.06)


# demo_sparse's walk: (seconds, eye, target) waypoints. Busy: along the desk tops at 1-1.6 m, as clutter_walk.
# Sparse: held on a corner group (make_sparse_desk) for 1, 1.5 and 3 s, reached and left in 0.3 s turns.
DESK_VIEWS = np.array([
    [1.3, 1.75, 1.35, 1.9, 0.75, 0.74], [2.1, 1.85, 1.4, 2.4, 0.75, 0.74], [2.9, 1.7, 1.35, 3.0, 0.75, 0.74],
    [3.9, 1.8, 1.4, 3.5, 0.75, 0.74], [3.6, 2.1, 1.5, 2.8, 0.8, 0.72], [2.4, 2.0, 1.45, 1.8, 0.8, 0.72],
    [1.5, 2.0, 1.5, 2.6, 0.75, 0.72], [3.0, 1.9, 1.4, 3.6, 0.75, 0.74],
])
CORNER_VIEWS = {  # eye, target: one corner group in view, no desk
    "right": [5.4, 1.45, 1.25, 6.4, 0.85, 0.8],
    "left": [1.2, 2.4, 1.2, 0.45, 2.0, 0.6],
    "back": [5.3, 3.3, 1.3, 6.1, 4.05, 0.6],
}
SPARSE_SCHEDULE = (  # (busy seconds before, corner, seconds held): 5.5 s of 30 held, 7.3 s with the turns
    (3.0, "right", 1.0), (5.5, "left", 1.5), (6.5, "back", 3.0),
)
TURN_S = 0.3


def sparse_walk(room: Room, seed: int, num_frames: int, duration: float) -> Walk:
    """The desk tops (DESK_VIEWS, cycled) with a stretch at a corner group after each busy spell of
    SPARSE_SCHEDULE, then the desk until `duration`; waypoints every 1.5 s on the desk, two per corner stretch.
    PCHIP between them: a quick turn does not overshoot into the held view."""
    del room
    rng = np.random.default_rng(seed)
    times, views, desk = [], [], 0
    t = 0.0

    def busy(until: float) -> None:  # a desk view every 1.5 s from t, and one at `until`
        nonlocal t, desk
        while True:
            times.append(t)
            views.append(DESK_VIEWS[desk % len(DESK_VIEWS)])
            desk += 1
            if t >= until - 1e-9:
                return
            t = min(t + 1.5, until)

    for before, corner, held in SPARSE_SCHEDULE:
        busy(t + before)
        view = np.array(CORNER_VIEWS[corner])
        t += TURN_S
        times += [t, t + held]
        views += [view, view + [0.08, -0.05, 0.02, 0.1, 0.05, 0.0]]  # a slow drift while held
        t += held + TURN_S
    busy(max(duration, t) + 1.5)  # the spline's last knot beyond the last frame
    route = np.array(views)
    eyes = route[:, :3] + rng.uniform(-0.04, 0.04, (len(route), 3)) * [1, 1, 0.5]
    targets = route[:, 3:] + rng.uniform(-0.04, 0.04, (len(route), 3))
    return Walk(np.linspace(0.0, duration, num_frames, endpoint=False), np.array(times), eyes, targets, hand_shake(rng),
                monotone=True)


# Scene name -> (room maker, walk maker), as `clipclique.sim.demo.SceneSpec.scene` names them.
SCENES = {"apartment": (make_apartment, apartment_walk), "desk": (make_desk, desk_walk),
          "clutter": (make_desk, clutter_walk), "sparse": (make_sparse_desk, sparse_walk)}
