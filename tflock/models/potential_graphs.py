"""Fixed interconnection graphs of the potential-field model (Tanner-Jadbabaie-Pappas section 4), in NumPy.

Taichi-free: the params validator reads edge-list files with it, the model and the NumPy reference build their
graphs with it. A graph is undirected and is handed around as CSR adjacency: ``offsets`` (n + 1,) and
``neighbours`` (2 |E|,), each agent's neighbours sorted by id (a deterministic summation order in the kernel).

Families (``params.graph``):

- ``complete``: every pair (Corollary 3: no collisions);
- ``path`` (0 - 1 - ... - n-1) and ``ring`` (the path closed; a path for n < 3);
- ``tree``: a random recursive tree, agent i > 0 attached to a uniform j < i (Corollary 1: distances along edges
  converge to d);
- ``random``: the paper's "randomly generated 0 - 1 adjacency matrix [that] defined a connected neighboring
  graph" (section 6): G(n, p), each pair an edge with probability ``graph_p``, redrawn (attempt 0, 1, ...) until
  connected;
- ``file``: an edge list, one ``i j`` pair of 0-based agent ids a line (``#`` comments and blank lines ignored).

Random draws come from :mod:`tflock.rng` keyed by (seed, attempt, agent[, other agent], stream).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: stream ids of this model's random draws (tflock.rng.Stream holds 0-11; models define theirs from 200)
STREAM_GRAPH = 201
STREAM_TREE = 202

#: the dense families (complete, random) are built only up to this many agents
DENSE_GRAPH_MAX = 5000
#: attempts at drawing a connected G(n, p) before giving up
RANDOM_GRAPH_ATTEMPTS = 100


class GraphError(RuntimeError):
    """A fixed graph that cannot be used (not connected, bad edge file); the message is one line."""


def path_edges(n: int, ring: bool = False) -> np.ndarray:
    """Edges (i, i + 1), closed into a ring when asked and n >= 3."""
    i = np.arange(n - 1)
    edges = np.stack([i, i + 1], axis=1)
    if ring and n >= 3:
        edges = np.vstack([edges, [[n - 1, 0]]])
    return edges


def complete_edges(n: int) -> np.ndarray:
    """Every pair i < j."""
    i, j = np.triu_indices(n, k=1)
    return np.stack([i, j], axis=1)


def tree_edges(n: int, seed: int) -> np.ndarray:
    """Random recursive tree: agent i > 0 is attached to j uniform in {0, ..., i - 1}."""
    from tflock.rng import hash_np, randint_np  # lazily: params validation stays Taichi-free
    child = np.arange(1, n)
    parent = randint_np(hash_np(seed, 0, child, STREAM_TREE), child)
    return np.stack([parent, child], axis=1)


def random_edges(n: int, p: float, seed: int, attempt: int) -> np.ndarray:
    """G(n, p): pair (i, j), i < j, is an edge when its uniform draw is < p (24-bit draws, as everywhere)."""
    from tflock.rng import pair_hash_np  # lazily: params validation stays Taichi-free
    i, j = np.triu_indices(n, k=1)
    u = (pair_hash_np(seed, attempt, i, j, STREAM_GRAPH) >> np.uint32(8)).astype(np.float64) / (1 << 24)
    keep = u < p
    return np.stack([i[keep], j[keep]], axis=1)


def read_edge_file(path: str | Path, n: int) -> np.ndarray:
    """Edges from a text file, one ``i j`` pair a line; raises GraphError with a one-line message."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise GraphError(f"graph file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise GraphError(f"{path}: cannot read: {getattr(error, 'strerror', None) or error}") from None
    edges = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 2 or not all(f.lstrip("-").isdecimal() for f in fields):
            raise GraphError(f"{path}:{number}: expected two agent ids 'i j', got {line!r}")
        i, j = int(fields[0]), int(fields[1])
        if not (0 <= i < n and 0 <= j < n):
            raise GraphError(f"{path}:{number}: agent ids must be in [0, {n - 1}] (n = {n}), got {i} {j}")
        if i == j:
            raise GraphError(f"{path}:{number}: an edge needs two different agents, got {i} {j}")
        edges.append((i, j))
    if not edges and n > 1:
        raise GraphError(f"{path}: no edges")
    return np.asarray(edges, dtype=np.int64).reshape(-1, 2)


def to_csr(n: int, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric CSR (offsets, neighbours) of undirected edges; duplicates merged, neighbours sorted by id."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    both = np.vstack([edges, edges[:, ::-1]])
    key = np.unique(both[:, 0] * n + both[:, 1])
    rows, cols = key // n, key % n
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=offsets[1:])
    return offsets.astype(np.int32), cols.astype(np.int32)


def component_labels(n: int, edges: np.ndarray) -> np.ndarray:
    """Connected-component label (the smallest agent id in it) of every agent: hooking and pointer jumping."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    u, v = edges[:, 0], edges[:, 1]
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        if np.array_equal(pu, pv):
            return parent
        np.minimum.at(parent, np.maximum(pu, pv), np.minimum(pu, pv))  # hook the larger root under the smaller
        while True:
            grand = parent[parent]
            if np.array_equal(grand, parent):
                break
            parent = grand


def describe_components(labels: np.ndarray, limit: int = 4, members: int = 6) -> str:
    """One line naming the components, e.g. ``2 components: {0, 1, 2}, {3, 4}``."""
    roots, sizes = np.unique(labels, return_counts=True)
    parts = []
    for root in roots[:limit]:
        ids = np.flatnonzero(labels == root)
        shown = ", ".join(str(i) for i in ids[:members])
        parts.append("{" + shown + (f", ... ({len(ids)} agents)" if len(ids) > members else "") + "}")
    more = f", ... ({len(roots) - limit} more)" if len(roots) > limit else ""
    return f"{len(roots)} components: " + ", ".join(parts) + more


def check_connected(n: int, edges: np.ndarray, what: str) -> None:
    """Raise GraphError naming the components when the graph is not connected."""
    labels = component_labels(n, edges)
    if n > 1 and labels.max() != 0:
        raise GraphError(f"{what} is not connected (Theorem 1 needs a connected graph): {describe_components(labels)}")


def fixed_graph_edges(n: int, graph: str, seed: int, graph_p: float = 0.3, graph_file: str = "") -> np.ndarray:
    """Edges (E, 2) of the fixed graph of family `graph`; raises GraphError when it is not connected."""
    if graph == "complete":
        edges = complete_edges(n)
    elif graph in ("path", "ring"):
        edges = path_edges(n, ring=graph == "ring")
    elif graph == "tree":
        edges = tree_edges(n, seed)
    elif graph == "file":
        edges = read_edge_file(graph_file, n)
        check_connected(n, edges, f"the graph in {graph_file}")
    elif graph == "random":
        for attempt in range(RANDOM_GRAPH_ATTEMPTS):
            edges = random_edges(n, graph_p, seed, attempt)
            labels = component_labels(n, edges)
            if labels.max() == 0:
                break
        else:
            raise GraphError(f"no connected G(n = {n}, p = {graph_p}) in {RANDOM_GRAPH_ATTEMPTS} draws "
                             f"(raise params.graph_p); the last had {describe_components(labels)}")
    else:
        raise ValueError(f"unknown graph family {graph!r}")
    return edges


# ----------------------------------------------------------------------------------------------------------
# Initial state (section 6), shared by the model and the NumPy reference.

#: stream id of the initial speeds
STREAM_SPEED = 200
#: rounds of redrawing too-close agents before giving up
PLACEMENT_ROUNDS = 500
#: cells per axis at most in the placement grid: (2**20 + 3)**3 keys fit in an int64
GRID_CELLS = 2**20


def _too_close(x: np.ndarray, candidates: np.ndarray, placed: np.ndarray, separation: float) -> np.ndarray:
    """Which of `candidates` lie closer than `separation` to a placed agent or to a candidate with a smaller id.

    A hashed grid of cells of side `separation` over all positions; each candidate looks at the 3^dim cells
    around its own (vectorised over candidates, looping over the few agents a cell holds). Cells are widened where
    the box spans more than :data:`GRID_CELLS` of them per axis, so that the cell keys fit in 64 bits (a wider cell
    still holds every agent within `separation` of its neighbours).
    """
    n, dim = x.shape
    width = max(separation, float((x.max(axis=0) - x.min(axis=0)).max()) / GRID_CELLS)
    cell = np.floor(x / width).astype(np.int64)
    cell -= cell.min(axis=0) - 1
    side = cell.max(axis=0) + 2
    strides = np.cumprod(np.concatenate(([1], side[:-1])))
    key = cell @ strides
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    occupancy = int(np.bincount(np.unique(sorted_key, return_inverse=True)[1]).max())
    by_cell = np.argsort(key[candidates], kind="stable")  # sorted queries: searchsorted stays in cache
    candidates = candidates[by_cell]
    conflict = np.zeros(len(candidates), dtype=bool)
    for offset in np.ndindex(*(3,) * dim):
        k = key[candidates] + (np.asarray(offset) - 1) @ strides
        lo = np.searchsorted(sorted_key, k, side="left")
        count = np.searchsorted(sorted_key, k, side="right") - lo
        for r in range(occupancy):
            m = np.flatnonzero(count > r)  # candidates whose visited cell holds an (r+1)-th agent: few
            if m.size == 0:
                break
            i, j = candidates[m], order[lo[m] + r]
            d2 = ((x[j] - x[i]) ** 2).sum(axis=1)
            conflict[m] |= (j != i) & (placed[j] | (j < i)) & (d2 < separation * separation)
    result = np.empty_like(conflict)
    result[by_cell] = conflict
    return result


def initial_state(n: int, dim: int, box: float, speed: float, min_separation: float, seed: int) -> dict:
    """Section 6: positions uniform in (-box/2, box/2)^dim with pairwise distances >= min_separation, speeds
    uniform in (0, speed) with uniformly random directions (on the circle, or the sphere in 3D); float64.

    Positions are drawn by rounds: in round a, every agent not yet placed draws ``uniform(seed, a, i, INIT_X/Y/Z)``
    and is placed unless closer than `min_separation` to a placed agent or to an unplaced one with a smaller id
    (so the result is a pure function of the seed). Speed: ``STREAM_SPEED``; direction: INIT_HEADING (2D angle;
    3D cos polar angle) and INIT_HEADING_2 (3D azimuth).
    """
    from tflock.rng import Stream, uniform_np

    ids = np.arange(n)
    axes = (Stream.INIT_X, Stream.INIT_Y, Stream.INIT_Z)[:dim]
    x = np.stack([box * (uniform_np(seed, 0, ids, s) - 0.5) for s in axes], axis=1)
    placed = np.zeros(n, dtype=bool)
    pending = ids
    for attempt in range(1, PLACEMENT_ROUNDS + 1):
        if min_separation <= 0 or n < 2:
            break
        conflict = _too_close(x, pending, placed, min_separation)
        placed[pending[~conflict]] = True
        pending = pending[conflict]
        if pending.size == 0:
            break
        x[pending] = np.stack([box * (uniform_np(seed, attempt, pending, s) - 0.5) for s in axes], axis=1)
    else:
        raise GraphError(f"could not place {n} agents {min_separation:g} apart in a box of side {box:g}")
    s = speed * uniform_np(seed, 0, ids, STREAM_SPEED)
    a = uniform_np(seed, 0, ids, Stream.INIT_HEADING)
    if dim == 2:
        direction = np.stack([np.cos(2 * np.pi * a), np.sin(2 * np.pi * a)], axis=1)
    else:
        cos_polar = 1.0 - 2.0 * a
        sin_polar = np.sqrt(np.maximum(0.0, 1.0 - cos_polar**2))
        azimuth = 2 * np.pi * uniform_np(seed, 0, ids, Stream.INIT_HEADING_2)
        direction = np.stack([sin_polar * np.cos(azimuth), sin_polar * np.sin(azimuth), cos_polar], axis=1)
    return {"x": x, "v": s[:, None] * direction}
