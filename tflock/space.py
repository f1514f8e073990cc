"""Boundaries of the simulated space: periodic box (minimum image), reflecting box (mirror), open plane/space;
and the wrapping of angles.

Boundary codes are compile-time constants of the kernels (``ti.template()`` arguments), so each kernel is
specialised to one boundary and carries no branch on it.
"""


import math

import taichi as ti

PERIODIC = 0
REFLECTING = 1
OPEN = 2
BOUNDARIES = {"periodic": PERIODIC, "reflecting": REFLECTING, "open": OPEN}
#: not a boundary: the layout code of a periodic box's cell grid stored over the window of cells its agents occupy
#: (tflock.neighbors.CellGrid, ``bounded``); distances in it are the periodic box's, by minimum image
WINDOW = 4


def boundary_code(name: str) -> int:
    """The kernel constant for a boundary name."""
    return BOUNDARIES[name]


@ti.func
def displacement(p, q, box, boundary: ti.template()):
    """q - p, by the minimum image convention when the box is periodic (a periodic box's ``WINDOW`` grid too)."""
    d = q - p
    if ti.static(boundary == PERIODIC or boundary == WINDOW):  # both points lie in [0, box): one image shift at most
        half = 0.5 * box
        d = ti.select(d > half, d - box, ti.select(d < -half, d + box, d))
    return d


@ti.func
def wrap_periodic(p, box):
    """Coordinates into [0, box) (x == box would put an agent outside the cell grid); element-wise, so it takes
    a position or a vector of one coordinate of several agents."""
    p -= box * ti.floor(p / box)
    return ti.select((p >= box) | (p < 0), 0.0, p)


@ti.func
def reflect(p, box):
    """Mirror coordinates at the walls 0 and box; returns the position and a per-axis 0/1 flip mask.

    A flipped axis means the velocity component along it changes sign (reflection like light on a mirror,
    Samiloglu et al. 2006 section 5.2). Valid for moves shorter than the box. Element-wise, like
    :func:`wrap_periodic`.
    """
    flips = ti.cast((p < 0) | (p > box), ti.i32)
    return ti.select(p < 0, -p, ti.select(p > box, 2 * box - p, p)), flips


TWO_PI = 2 * math.pi


@ti.func
def wrap_pi(a):
    """Angle into [-pi, pi) (element-wise on vectors)."""
    return a - TWO_PI * ti.floor((a + math.pi) / TWO_PI)


@ti.func
def wrap_two_pi(a):
    """Angle into [0, 2 pi) (headings, as 003 defines them); branch-free and element-wise on vectors."""
    a -= TWO_PI * ti.floor(a / TWO_PI)
    return ti.select((a >= TWO_PI) | (a < 0), 0.0, a)
