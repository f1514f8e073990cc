"""Clusters of the R-graph found during a lane-wise neighbour pass (DESIGN.md section 4).

A model's lane-wise CPU kernel already compares every candidate with ``LANES`` agents at once to sum over its
neighbours. :class:`LaneComponents` lets that same pass find the connected components of the graph
|x_i - x_j| <= R, so a metrics pass costs little more than the neighbour sums the next step needs anyway.

The grid's layers (the last cell coordinate, and the replica) are cut into stripes of consecutive layers (one stripe
for a small swarm); each stripe is one task, its runs of cells taken in slot order by one thread. Every agent of a
stripe is settled when its block of lanes closes: it joins the sets of its neighbours at smaller slots in the same
stripe (all settled before it), so in the vector loop a block only keeps, per lane, the set label
(:func:`candidate_label`) its near candidates before it in the stripe share, or MIXED (:func:`fold_label`), and a
bit mask of the near agents of its own block. A span of candidates that carries one label (nearly every span inside
a flock) folds it once, into the lanes that found one of them near (:func:`span_labels`), instead of once per
candidate. After the loop the block's lanes find their roots: from the shared label (almost always) with one scalar
step, or when MIXED by re-reading the lane's candidates and joining each one's set (:func:`block_roots`,
:func:`join_candidate`); then the lanes within R of each other join those roots into one set (:func:`settle_block`).
This phase writes only parents of its own stripe's slots, so it needs no atomics; a parent always points to a
smaller slot, so each set's root is its smallest slot.

Pairs whose agents lie in two stripes (neighbouring layers at a stripe's edge, and a periodic grid's wrap) are
joined afterwards by :meth:`LaneComponents.finish`, a pass over the stripes' edge layers (a few per cent of the
agents) with the lock-free unions of :mod:`tflock.union_find`, the stripes in parallel; it then brings each merged
set's size to its root, counts the roots and takes the largest set's size.
The partition, and hence the cluster count and the largest cluster, do not depend on the thread count or the
stripes.
"""

import numpy as np
import taichi as ti

from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.neighbors import LANES, CellGrid, load_cell, load_vec, span_agents, span_count, stencil_span
from tflock.space import displacement
from tflock.taichi_host import SMALL_SWARM_MAX, host_view, small_host_view
from tflock.union_find import find_root, hook_union

#: no candidate seen: the initial smallest label of a lane
NO_LABEL = 2**31 - 1
#: a lane's near candidates carried two set labels (see fold_label)
MIXED = -1
#: stripes per CPU thread: enough tasks to even out dense and empty parts of the grid, few enough edge layers for
#: the joins across stripes (LaneComponents.finish: about a millisecond per 4 stripes at 1e6 in a developed flock)
STRIPES_PER_THREAD = 4
#: layers a stripe holds at least (its edge layers are joined in a second pass, see LaneComponents.finish)
MIN_STRIPE_LAYERS = 4
#: agents (replicas counted together) up to which the grid is one stripe: for a small swarm the join across
#: stripes, one more launch, costs more than a second thread gains
ONE_STRIPE_MAX = SMALL_SWARM_MAX
LANE_BITS = LANES.bit_length() - 1  # log2(LANES)


@ti.func
def local_root(parent: ti.template(), x):
    """Root of x among slots one thread owns (a stripe in phase 1: plain writes), halving the path."""
    while parent[x] != x:
        gp = parent[parent[x]]
        parent[x] = gp
        x = gp
    return x


@ti.func
def _join(parent: ti.template(), size: ti.template(), a, b):
    """Merge the sets of roots a and b (plain writes: one thread owns both); the smaller root stays the root
    (returned) and takes the other's size."""
    lo = ti.min(a, b)
    hi = ti.max(a, b)
    parent[hi] = lo
    size[lo] += size[hi]
    return lo


@ti.func
def stripe_range(j, n_stripes, layers, layer_buckets, start: ti.template()):
    """Buckets [b_lo, b_hi) and slots [s_lo, s_hi) of stripe j."""
    b_lo = (j * layers // n_stripes) * layer_buckets
    b_hi = ((j + 1) * layers // n_stripes) * layer_buckets
    return b_lo, b_hi, start[b_lo], start[b_hi]


@ti.func
def candidate_label(parent: ti.template(), k):
    """The set label a candidate k before the block carries: its grandparent, a slot of its set that is the set's
    root unless the set was merged twice since k settled (so the labels of one set seldom differ)."""
    return parent[parent[k]]


@ti.func
def span_labels(parent: ti.template(), begin, end):
    """The smallest and largest :func:`candidate_label` of the candidates [begin, end) (scalar; NO_LABEL and -1
    when empty). Where they are equal the whole span carries one label: it is folded once, into the lanes that
    found a candidate of the span near, instead of once per candidate (:func:`fold_label`)."""
    lo = NO_LABEL
    hi = -1
    for k in range(begin, end):
        label = candidate_label(parent, k)
        lo = ti.min(lo, label)
        hi = ti.max(hi, label)
    return lo, hi


@ti.func
def fold_label(label, other, near, candidate):
    """Per lane, the set labels of its near candidates so far: `label` the first (NO_LABEL: none yet), `other` a
    second one (NO_LABEL: none), or MIXED once a third differs from both; `candidate` is one more candidate's label,
    folded into the lanes it is `near` (vector loop). Two labels are often one set (one of them an earlier root)."""
    first = near & (label == NO_LABEL)
    second = near & ~first & (label != candidate)
    other = ti.select(second, ti.select((other == candidate) | (other == NO_LABEL), candidate, MIXED), other)
    return ti.select(first, candidate, label), other


@ti.func
def block_roots(width, label, other, parent: ti.template(), size: ti.template()):
    """Per lane of a block of `width` lanes, the root of the set of its near candidates before the block in the
    stripe (-1: none near), from :func:`fold_label`'s labels, and the bit mask of the lanes whose candidates carried
    two labels: the caller re-reads their candidates, joins each one's set with :func:`join_candidate` and puts the
    root in their place."""
    roots = ti.Vector([-1] * LANES)
    recheck = 0
    for q in ti.static(range(LANES)):
        if q < width:
            if label[q] != NO_LABEL:
                r = local_root(parent, label[q])
                if other[q] == MIXED:
                    recheck |= 1 << q
                elif other[q] != NO_LABEL:
                    r2 = local_root(parent, other[q])
                    if r2 != r:
                        r = _join(parent, size, r, r2)
                roots[q] = r
    return roots, recheck


@ti.func
def _bits(mask):
    """The lanes where the vector `mask` is nonzero, as a bit mask."""
    bits = 0
    for q in ti.static(range(LANES)):
        bits |= ti.select(mask[q] != 0, 1 << q, 0)
    return bits


@ti.func
def lowest_lane(bits):
    """Index of the lowest set bit of `bits` (nonzero; element-wise on a vector of masks)."""
    return ti.cast(ti.math.popcnt((bits & -bits) - 1), ti.i32)


@ti.func
def _roots_of(slots, has, parent: ti.template()):
    """Per lane where `has`, the root of the set of slot `slots[q]` (settled, in this thread's stripe), else -1.
    Two parent reads per lane in vector form, no branch per lane: trees stay shallow, so a slot is almost always a
    root or a root's child; the few lanes deeper (a bit mask) walk on with :func:`local_root`."""
    at = ti.select(has, slots, 0)  # (slot 0: a valid read for the lanes without one, never used)
    up = ti.Vector([parent[at[q]] for q in ti.static(range(LANES))])
    top = ti.Vector([parent[up[q]] for q in ti.static(range(LANES))])
    roots = ti.select(has, up, -1)
    deep = _bits(has & (top != up))
    while deep != 0:
        q = lowest_lane(deep)
        roots[q] = local_root(parent, top[q])
        deep &= deep - 1
    return roots


@ti.func
def block_roots_vectorised(width, label, other, parent: ti.template(), size: ti.template()):
    """Per lane of a block of `width` lanes, the root of the set of its near candidates before the block in the
    stripe (-1: none near), from :func:`fold_label`'s labels, and the bit mask of the lanes whose candidates carried
    two labels: the caller re-reads their candidates, joins each one's set with :func:`join_candidate` and puts the
    root in their place. As :func:`block_roots`, with the lanes taken as vectors and bit masks instead of a branch
    and a root walk per lane: the faster form in the Vicsek model's pass, whose labels (grandparents) are nearly
    always roots; `potential`'s pass (labels: parents) timed slower with it and keeps :func:`block_roots`
    (docs/performance-history.md)."""
    lane = ti.Vector([q for q in ti.static(range(LANES))])
    has = (lane < width) & (label != NO_LABEL)
    roots = _roots_of(label, has, parent)
    second = has & (other != NO_LABEL) & (other != MIXED)
    joins = 0
    others = roots
    if second.any():  # (few lanes see two labels)
        others = _roots_of(other, second, parent)
        joins = _bits(second & (others != roots))
    while joins != 0:  # two sets near one lane: one set now
        q = lowest_lane(joins)
        a = local_root(parent, roots[q])  # (an earlier join of this block may have moved it)
        b = local_root(parent, others[q])
        if a != b:
            a = _join(parent, size, a, b)
        roots[q] = a
        joins &= joins - 1
    recheck = 0  # (a branch per lane here: from bit operations on the vectors, LLVM compiled Vicsek's pass slower)
    for q in ti.static(range(LANES)):
        if q < width:
            if label[q] != NO_LABEL:
                if other[q] == MIXED:
                    recheck |= 1 << q
    return roots, recheck


@ti.func
def settle_block(i0, width, roots, inmask, parent: ti.template(), size: ti.template(), vectorised: ti.template()):
    """Settle the block's lanes (slots i0 .. i0 + width - 1): the lanes within R of each other (bits of `inmask`,
    itself included) form the block's own components, found by doubling bit masks; each such component joins the
    roots its lanes found (`roots`, -1 for none) into one set, or starts a set rooted at its first lane. Where they
    found different sets, or none, by :func:`_settle_components` or, where `vectorised`,
    :func:`_settle_components_vectorised`: `potential`'s pass is the faster with the second, Vicsek's with the
    first (docs/performance-history.md)."""
    same = True  # every lane found the same set: it is theirs (the common case inside a flock)
    for q in ti.static(range(1, LANES)):
        if q < width:
            same = same and roots[q] == roots[0]
    if same and roots[0] >= 0:
        for q in ti.static(range(LANES)):
            if q < width:
                parent[i0 + q] = roots[0]
        size[roots[0]] += width
    elif ti.static(vectorised):
        _settle_components_vectorised(i0, width, roots, inmask, parent, size)
    else:
        _settle_components(i0, width, roots, inmask, parent, size)


@ti.func
def _block_components(width, inmask, until_stable: ti.template()):
    """Per lane of a block of `width` lanes, the bit mask of its component among them (`inmask`: each lane's lanes
    within R, itself included), by doubling: after round k, every lane within 2^k hops. Where `until_stable`, the
    rounds stop at the first that adds nothing (most blocks: one, when each component's lanes are all within R of
    each other), else all LANE_BITS of them run: the per-lane settle is the faster with the first, the vector
    settle with the second (docs/performance-history.md)."""
    comp = inmask & ((1 << width) - 1)
    if ti.static(until_stable):
        growing = True
        while growing:
            grown = _grown(comp)
            growing = (grown != comp).any()
            comp = grown
    else:
        for _ in ti.static(range(LANE_BITS)):
            comp = _grown(comp)
    return comp


@ti.func
def _grown(comp):
    """One doubling round of :func:`_block_components`: each lane's mask joined with those of the lanes in it."""
    grown = comp
    for q in ti.static(range(LANES)):
        grown |= ti.select(((comp >> q) & 1) == 1, comp[q], 0)
    return grown


@ti.func
def _settle_components(i0, width, roots, inmask, parent: ti.template(), size: ti.template()):
    """:func:`settle_block` where the lanes found different sets, or none."""
    comp = _block_components(width, inmask, True)
    joined = ti.Vector([-1] * LANES)  # the set of each component, at its first lane
    for q in ti.static(range(LANES)):
        if q < width and (comp[q] & ((1 << q) - 1)) == 0:
            r = -1
            m = comp[q]
            while m != 0:
                other = roots[lowest_lane(m)]
                if other >= 0:
                    other = local_root(parent, other)
                    if r < 0:
                        r = other
                    elif other != r:
                        r = _join(parent, size, r, other)
                m &= m - 1
            lanes_in = ti.cast(ti.math.popcnt(comp[q]), ti.i32)
            if r < 0:
                r = i0 + q
                size[r] = lanes_in
            else:
                size[r] += lanes_in
            joined[q] = r
    for q in ti.static(range(LANES)):
        if q < width:
            parent[i0 + q] = joined[lowest_lane(comp[q])]


@ti.func
def _settle_components_vectorised(i0, width, roots, inmask, parent: ti.template(), size: ti.template()):
    """:func:`_settle_components` with the lanes taken as vectors: each block component's set is the smallest root
    its lanes found (the others, few, are joined to it), or a new one at its first lane; the stores go to a selected
    slot (a lane past `width` stores to lane 0's slot what lane 0 stores) instead of a branch per lane."""
    valid = ti.Vector([q for q in ti.static(range(LANES))]) < width
    comp = _block_components(width, inmask, False)
    has = valid & (roots >= 0)
    up = ti.Vector([parent[ti.select(has[q], roots[q], 0)] for q in ti.static(range(LANES))])
    stale = has & (up != roots)
    if stale.any():  # a join since block_roots (a recheck, a second label) moved a root
        for q in ti.static(range(LANES)):
            if stale[q]:
                roots[q] = local_root(parent, roots[q])
    found = ti.select(has, roots, NO_LABEL)
    best = ti.Vector([NO_LABEL] * LANES)  # per lane, the smallest root its component's lanes found
    for q in ti.static(range(LANES)):
        best = ti.min(best, ti.select(((comp >> q) & 1) == 1, found[q], NO_LABEL))
    joins = (found != NO_LABEL) & (found != best)
    if joins.any():  # a component near two sets: one set now
        for q in ti.static(range(LANES)):
            if joins[q]:
                a = local_root(parent, best[q])
                b = local_root(parent, found[q])
                if a != b:
                    _join(parent, size, a, b)
        for q in ti.static(range(LANES)):
            if best[q] != NO_LABEL:
                best[q] = local_root(parent, best[q])
    # new sets: their first lane (lowest_lane's form, its cast on a vector, timed 0.5 ms slower in potential's pass)
    top = ti.select(best != NO_LABEL, best, i0 + ti.math.popcnt((comp & -comp) - 1))
    for q in ti.static(range(LANES)):
        size[i0 + ti.select(valid[q], q, 0)] = 0  # (a new set's size starts here; the block's other slots are no roots)
    for q in ti.static(range(LANES)):
        parent[i0 + ti.select(valid[q], q, 0)] = ti.select(valid[q], top[q], top[0])
        size[ti.select(valid[q], top[q], top[0])] += ti.select(valid[q], 1, 0)


@ti.func
def join_candidate(r, k, parent: ti.template(), size: ti.template()):
    """The merged root of root r (-1: none yet) and candidate k's set (a recheck, inside a stripe)."""
    other = local_root(parent, k)
    if r < 0:
        r = other
    elif other != r:
        r = _join(parent, size, r, other)
    return r


@ti.kernel
def _cross_stripes(n_stripes: ti.i32, layers: ti.i32, layer_buckets: ti.i32, r2: float, box: float, nc: ti.i32,
                   n_buckets: ti.i32, layout: ti.template(), metric: ti.template(), strict: ti.template(),
                   dim: ti.template(), start: ti.types.ndarray(), mixed: ti.types.ndarray(),
                   pos_sorted: ti.types.ndarray(), coords_sorted: ti.types.ndarray(), parent: ti.types.ndarray(),
                   size: ti.types.ndarray(), hooked: ti.types.ndarray(), hooks: ti.types.ndarray()):
    """Join the pairs within R (|r|^2 <= r2, or < r2 where `strict`) whose agents lie in two stripes. Cells are at
    least R wide, so such a pair joins the first layer of a stripe to the layer before it (the previous stripe's
    last, or across a periodic wrap): the agents of each stripe's first layer are tested against the stencil spans
    one layer back (the first third of :func:`stencil_span`'s spans, where the slowest axis steps back).

    A stripe a task, all in parallel: two tasks may join the same sets, so the joins are the lock-free unions of
    :mod:`tflock.union_find`, which list each root they hook under another in `hooked` (hooks[0] of them; the
    caller sizes `hooked` for the stripes' edge layers, see :func:`edge_agents`). Then each listed root's set size
    (from the stripes' own pass) is added to its final root's, so each set's size is at its root again."""
    hooks[0] = 0
    for t in range(n_stripes * TASK_STRIDE):  # a stripe a task (tflock.cpu_tasks)
        j = task_at(t)
        if j >= 0:
            b_lo, b_hi, s_lo, s_hi = stripe_range(j, n_stripes, layers, layer_buckets, start)
            for s in range(s_lo, start[ti.min(b_lo + layer_buckets, b_hi)]):
                p = load_vec(pos_sorted, s, dim)
                c = load_cell(coords_sorted, s, dim)
                root = s  # a recent root of s's set: a candidate already under it needs no union
                for o in range(ti.static(span_count(layout, dim) // 3)):
                    lo, hi, cell = stencil_span(c, o, nc, n_buckets, layout, dim)
                    begin, end, _ = span_agents(lo, hi, cell, start, mixed, coords_sorted, layout, dim)
                    for k in range(begin, end):
                        if k < s_lo or k >= s_hi:
                            d2 = displacement(p, load_vec(pos_sorted, k, dim), box, metric).norm_sqr()
                            near = d2 <= r2
                            if ti.static(strict):
                                near = d2 < r2
                            if near and parent[k] != root:
                                former, root = hook_union(parent, root, k)  # the root it hooked, if any
                                if former >= 0:
                                    hooked[ti.atomic_add(hooks[0], 1)] = former
    for e in range(hooks[0]):  # after every join: the listed roots' sizes to the roots of their merged sets
        root = hooked[e]
        ti.atomic_add(size[find_root(parent, root)], size[root])


def edge_agents(start: np.ndarray, n_stripes: int, layers: int, layer_buckets: int) -> int:
    """Agents in the stripes' edge layers (each stripe's first layer and the layer before it), from the grid's
    bucket starts: at least the number of roots :func:`_cross_stripes` can hook, since each hook joins two sets of
    such agents into one."""
    firsts = (np.arange(n_stripes) * layers // n_stripes) * layer_buckets
    befores = np.where(firsts > 0, firsts, layers * layer_buckets) - layer_buckets  # the wrap's: the last layer
    return int((start[firsts + layer_buckets] - start[firsts]).sum() + (start[befores + layer_buckets]
                                                                        - start[befores]).sum())


@ti.func
def count_roots(n, parent: ti.template(), size: ti.template(), result: ti.template()):
    """result[0]: the number of roots (slots that are their own parent); result[1]: the largest root's size."""
    result[0] = 0
    result[1] = 0
    for s in range(n):
        if parent[s] == s:
            ti.atomic_add(result[0], 1)
            ti.atomic_max(result[1], size[s])


@ti.kernel
def _count_components(n: ti.i32, parent: ti.types.ndarray(), size: ti.types.ndarray(), result: ti.types.ndarray()):
    """result = (components, agents in the largest): the roots and their sizes."""
    count_roots(n, parent, size, result)


class LaneComponents:
    """Scratch and results of the components a lane-wise pass finds on one grid (box, window or bounded layouts).

    A model's kernel takes :meth:`stripes` and ``parent``, loops over stripes as this module describes, and then
    :meth:`finish` gives the component count and the largest component.
    """

    def __init__(self, grid: CellGrid, threads: int) -> None:
        self.grid = grid
        self.threads = max(1, threads)
        self.parent = ti.ndarray(ti.i32, grid.n)
        self.size = ti.ndarray(ti.i32, grid.n)
        self.result = np.zeros(2, dtype=np.int32)
        self.hooked: ti.Ndarray | None = None  # the roots the cross-stripe joins hooked (see _cross_stripes)
        self.hooks = ti.ndarray(ti.i32, 1)

    def stripes(self) -> tuple[int, int, int]:
        """``(n_stripes, layers, layer_buckets)`` for the grid's current layout (one stripe up to ONE_STRIPE_MAX
        agents)."""
        g = self.grid.geometry
        layer_buckets = g.cells_per_side ** (g.dim - 1)
        layers = g.total_buckets // layer_buckets
        n_stripes = max(1, min(STRIPES_PER_THREAD * self.threads, layers // MIN_STRIPE_LAYERS))
        if self.grid.n <= ONE_STRIPE_MAX:
            n_stripes = 1
        return n_stripes, layers, layer_buckets

    def finish(self, r2: float, box: float, metric: int, strict: bool = False) -> tuple[int, int]:
        """Join the pairs across stripes and count: ``(components, agents in the largest)``. Pairs are joined where
        |r|^2 <= r2 (< r2 where `strict`), r2 as the model's own pass has it (the squared radius in the run's
        precision); `metric` is the boundary code whose displacement measures distances (the periodic box's for a
        window grid)."""
        grid = self.grid
        g = grid.geometry
        n_stripes, layers, layer_buckets = self.stripes()
        if n_stripes > 1:
            edges = edge_agents(host_view(grid.start), n_stripes, layers, layer_buckets)
            held = 0 if self.hooked is None else self.hooked.shape[0]
            if held < edges:  # grown by doubling: a flock's edge layers fill and empty as it moves
                self.hooked = ti.ndarray(ti.i32, max(edges, 2 * held))
            _cross_stripes(n_stripes, layers, layer_buckets, r2, box, g.cells_per_side, g.n_buckets, g.boundary,
                           metric, strict, g.dim, grid.start, grid.mixed, grid.pos_sorted, grid.coords_sorted,
                           self.parent, self.size, self.hooked, self.hooks)
        parent = small_host_view(self.parent, grid.n)
        if parent is not None:  # a small swarm's roots counted in NumPy: a launch costs more than the count
            roots = parent == np.arange(grid.n, dtype=parent.dtype)
            sizes = host_view(self.size)[roots]
            return int(roots.sum()), int(sizes.max(initial=0))
        _count_components(grid.n, self.parent, self.size, self.result)
        return int(self.result[0]), int(self.result[1])

