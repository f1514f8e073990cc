"""Lock-free union-find on a parent array of slots, for threads that join sets at the same time (DESIGN.md section
4: clusters). A set's root is its smallest slot whatever the thread timing: a hook puts the larger root under the
smaller with an atomic_min. :mod:`tflock.components` joins a whole swarm's pairs this way; :mod:`tflock.lane_graph`
the pairs across its stripes.
"""

import taichi as ti


@ti.func
def find_root(parent: ti.template(), x):
    """Root of x, halving the path on the way (x's parent becomes its grandparent).

    The halving write is an atomic_min to an ancestor in the same set, so it never loses a link: a concurrent
    hook that it overrides is merged again by the hooking thread (see :func:`union`).
    """
    while parent[x] != x:
        p = parent[x]
        gp = parent[p]
        if gp != p:
            ti.atomic_min(parent[x], gp)
        x = gp
    return x


@ti.func
def hook_union(parent: ti.template(), a, z):
    """Merge the sets of a and z: ``(hooked, root)``, the root this call hooked under another (-1 where the two
    were one set already) and the root the merged set had when the hook succeeded.

    Lock-free: the larger root is hooked under the smaller value with atomic_min; if another thread changed
    that parent meanwhile, the old parent is merged in its place, so no link is ever lost. A root stops being one
    by exactly one successful hook, so over all threads each former root is reported once.
    """
    hooked = -1
    done = False
    while not done:
        a = find_root(parent, a)
        z = find_root(parent, z)
        if a == z:
            done = True
        else:
            if a < z:
                a, z = z, a
            old = ti.atomic_min(parent[a], z)
            if old == a:
                hooked = a
                done = True
            else:
                a = old
    return hooked, z


@ti.func
def union(parent: ti.template(), a, z):
    """Merge the sets of a and z (:func:`hook_union`); returns the root the merged set had when the hook
    succeeded."""
    _, root = hook_union(parent, a, z)
    return root
