"""The cell grid finds exactly the brute-force neighbours, for every boundary and awkward geometry."""

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH, PRECISION

from tflock import reference as ref
from tflock.config import load_config
from tflock.metrics import NeighbourGraph
from tflock.models.vicsek import Vicsek
from tflock.neighbors import LANES, CellGrid, DrawnEdges, run_at, window_run_wraps
from tflock.space import WINDOW


def model_at(engine, x, boundary, box, radius):
    cfg = load_config(overrides={"params.n": len(x), "params.box": box, "params.radius": radius,
                                 "params.boundary": boundary, "params.speed": 0.0,
                                 "engine.precision": engine.precision})
    model = Vicsek(cfg.params, 0, engine)
    model.set_state({"x": x, "theta": np.zeros(len(x))}, 0)
    return model


@pytest.mark.parametrize("boundary", ["periodic", "reflecting", "open"])
@pytest.mark.parametrize("box,radius", [(10.0, 1.0), (10.0, 4.0), (10.0, 6.0), (3.0, 1.0), (50.0, 0.7)])
def test_degrees_match_brute_force(engine, boundary, box, radius):
    rng = np.random.default_rng(int(box * 10 + radius))
    x = rng.random((300, 2)) * box
    model = model_at(engine, x, boundary, box, radius)
    metrics = model.metrics()  # on the CPU in a box, from the lane-wise pass; else from NeighbourGraph
    expected = ref.adjacency(x.astype(engine.real), radius, boundary, box).sum(axis=1)
    assert metrics["max_neighbors"] == expected.max()
    assert metrics["mean_neighbors"] == pytest.approx(expected.mean(), abs=1e-9)
    graph = NeighbourGraph(model.grid)
    graph.compute(radius, box)
    assert np.array_equal(graph.degree.to_numpy(), expected)


@pytest.mark.skipif(PRECISION == "f32", reason="f32 resolves positions 1e6 from the origin to 0.06-0.12 only: the "
                    "float64 brute force then sees other pairs")
def test_open_space_far_apart_groups(engine):
    """Open space assumes no box: groups 1e6 units apart are found, and never mixed by the hash."""
    rng = np.random.default_rng(0)
    centres = np.array([[0.0, 0.0], [1e6, 0.0], [-1e6, 5e5], [3e5, -2e6]])
    x = np.concatenate([c + rng.random((50, 2)) for c in centres])
    model = model_at(engine, x, "open", 1.0, 1.0)
    m = model.metrics()
    expected = ref.graph_metrics(x, 1.0, "open", 1.0)
    assert m["clusters"] == expected["clusters"]
    assert m["mean_neighbors"] == pytest.approx(expected["mean_neighbors"])


def test_open_space_shared_buckets(engine):
    """Agents spread over many more cells than the hash table has buckets: buckets shared by several cells are
    filtered agent by agent, buckets of one other cell are skipped whole, and the degrees and clusters are still
    exactly the brute-force ones."""
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.random((600, 2)) * 60.0, rng.random((200, 2)) * 4.0])  # sparse field + dense clump
    model = model_at(engine, x, "open", 1.0, 1.0)
    m = model.metrics()
    grid = model.grid
    mixed = grid.mixed.to_numpy()
    occupied = np.diff(grid.start.to_numpy()) > 0
    assert mixed.sum() >= 20 and (occupied & (mixed == 0)).sum() >= 100  # both kinds of bucket are exercised
    expected_degree = ref.adjacency(x.astype(engine.real), 1.0, "open", 1.0).sum(axis=1)
    assert np.array_equal(model.graph.degree.to_numpy(), expected_degree)
    expected = ref.graph_metrics(x, 1.0, "open", 1.0)
    assert m["clusters"] == expected["clusters"]
    assert m["largest_cluster"] == pytest.approx(expected["largest_cluster"])


def test_clusters_on_hand_built_configurations(engine):
    # three separate chains of 10, 5 and 1 agents, spacing 0.9 < R = 1
    chain = lambda start, k: np.array([[start + 0.9 * i, 2.0] for i in range(k)])  # noqa: E731
    x = np.concatenate([chain(0.5, 10), chain(15.0, 5), chain(25.0, 1)])
    m = model_at(engine, x, "reflecting", 30.0, 1.0).metrics()
    assert m["clusters"] == 3
    assert m["largest_cluster"] == pytest.approx(10 / 16)
    assert m["max_neighbors"] == 2
    # a ring of agents that closes only through the periodic boundary is one cluster, not two
    x = np.array([[0.2 + 0.9 * i, 1.0] for i in range(11)])  # last one at 9.2, first at 0.2: gap 1.0 via the wrap
    assert model_at(engine, x, "periodic", 10.0, 1.0).metrics()["clusters"] == 1
    assert model_at(engine, x, "reflecting", 10.0, 1.0).metrics()["clusters"] == 1
    x[5:, 0] += 0.15  # break the chain in the middle: periodic still one cluster? no: two breaks needed
    assert model_at(engine, x, "periodic", 10.0, 1.0).metrics()["clusters"] == 1
    assert model_at(engine, x, "reflecting", 10.0, 1.0).metrics()["clusters"] == 2


def induced_pairs(x: np.ndarray, radius: float, boundary: str, box: float) -> list[tuple[int, int]]:
    """Brute force: the pairs (r, q), q < r, of rows of x within radius, sorted."""
    a = ref.adjacency(x, radius, boundary, box)
    return [(r, q) for r in range(len(x)) for q in range(r) if a[r, q]]


def edge_rows(edges: np.ndarray, x: np.ndarray, box: float, periodic: bool) -> list[tuple[int, int]]:
    """The rows of x each edge joins (its start is a row's position, its end a row's position up to the box),
    sorted, after checking that the edges come row by row (a row's pairs in the grid's order)."""
    def row_of(p: np.ndarray) -> int:
        d = x - p
        if periodic:
            d -= box * np.round(d / box)
        k = int(np.argmin(np.linalg.norm(d, axis=1)))
        assert np.linalg.norm(d[k]) < 1e-4, "an edge end that is no drawn agent"
        return k
    pairs = [(row_of(e[0]), row_of(e[1])) for e in edges]
    assert all(a[0] <= b[0] for a, b in zip(pairs, pairs[1:], strict=False))
    return sorted(pairs)


def test_edges_join_drawn_agents_only(engine):
    """Edges are the pairs within R among the drawn agents (the R-graph induced on them), each once, from the later
    row to the earlier, the far end by the minimum image."""
    rng = np.random.default_rng(1)
    x = rng.random((400, 2)) * 8.0
    model = model_at(engine, x, "periodic", 8.0, 1.0)
    selected = np.arange(0, 400, 2)
    frame = model.frame(selected, max_edges=100000)
    drawn = x[selected].astype(engine.real)
    expected = induced_pairs(drawn, 1.0, "periodic", 8.0)
    assert len(expected) > 100
    assert edge_rows(frame.edges, drawn, 8.0, periodic=True) == expected
    lengths = np.linalg.norm(frame.edges[:, 1] - frame.edges[:, 0], axis=1)
    assert lengths.max() <= 1.0 + 1e-5  # minimum image: no edge spans the box


@pytest.mark.parametrize("max_edges", [1, 300, 2999, 7000, 10**6])
def test_edges_capped_are_the_graph_of_the_first_drawn_agents(engine, max_edges):
    """A cap keeps the graph induced on the first K drawn agents, K as large as the cap allows: the prefix of all
    edges that ends with a whole row; the same whatever the rows the last frame needed (its grid's size)."""
    rng = np.random.default_rng(2)
    x = rng.random((4000, 2)) * 40.0
    model = model_at(engine, x, "periodic", 40.0, 1.0)
    selected = np.sort(rng.choice(4000, 3000, replace=False))
    everything = model.frame(selected, max_edges=10**9).edges
    assert len(everything) > 7000
    rows = np.array([r for r, _ in edge_rows(everything, x[selected].astype(engine.real), 40.0, periodic=True)])
    assert np.all(np.diff(rows) >= 0)
    per_row = np.bincount(rows, minlength=len(selected)).cumsum()
    k = int(np.searchsorted(per_row, max_edges, side="right"))
    expected = everything[: per_row[k - 1] if k else 0]
    for _ in range(2):  # the second frame starts from the rows the first needed
        np.testing.assert_array_equal(model.frame(selected, max_edges=max_edges).edges, expected)
    model.frame(selected, max_edges=5)  # a small last frame: the next grows its grid again
    np.testing.assert_array_equal(model.frame(selected, max_edges=max_edges).edges, expected)


@pytest.mark.parametrize("dim,boundary", [(2, "periodic"), (2, "reflecting"), (2, "open"), (3, "periodic"),
                                          (3, "open")])
def test_drawn_edges_match_brute_force(engine, dim, boundary):
    rng = np.random.default_rng(dim)
    box, m = 12.0, 700
    x = (rng.random((m, dim)) * box).astype(engine.real)
    if boundary == "open":
        x -= np.asarray(box / 2, dtype=engine.real)
    edges = DrawnEdges(dim, boundary, box, 1.5, engine.real).edges(x, 10**6)
    expected = induced_pairs(x, 1.5, boundary, box)
    assert len(expected) > 300
    assert edge_rows(edges, x, box, periodic=boundary == "periodic") == expected
    assert DrawnEdges(dim, boundary, box, 1.5, engine.real).edges(x[:1], 10).shape == (0, 2, dim)


@pytest.mark.parametrize("dim,boundary", [(2, "periodic"), (2, "open"), (3, "periodic"), (3, "reflecting")])
def test_few_drawn_agents_edges_from_all_pairs_match_the_grid(engine, monkeypatch, dim, boundary):
    """A frame of at most ALL_PAIRS_ROWS drawn agents takes its edges from all pairs, on one thread: the brute-force
    pairs, row by row, each edge's far end by the minimum image, and under a cap the same whole rows as the grid's
    path."""
    import tflock.neighbors as neighbors

    rng = np.random.default_rng(dim + 10)
    box, m = 5.0, neighbors.ALL_PAIRS_ROWS
    x = (rng.random((m, dim)) * box).astype(engine.real)
    expected = induced_pairs(x, 1.5, boundary, box)
    assert len(expected) > 300
    small = DrawnEdges(dim, boundary, box, 1.5, engine.real).edges(x, 10**6)
    assert edge_rows(small, x, box, periodic=boundary == "periodic") == expected
    caps = (10**6, 200, 3)
    with monkeypatch.context() as patch:
        patch.setattr(neighbors, "ALL_PAIRS_ROWS", 0)
        grid_path = DrawnEdges(dim, boundary, box, 1.5, engine.real)
        by_grid = [grid_path.edges(x, cap) for cap in caps]
    for cap, grid_edges in zip(caps, by_grid, strict=True):
        by_pairs = DrawnEdges(dim, boundary, box, 1.5, engine.real).edges(x, cap)
        assert by_pairs.dtype == grid_edges.dtype and by_pairs.shape == grid_edges.shape, cap
        assert sorted(map(tuple, by_pairs.reshape(len(by_pairs), -1).tolist())) == sorted(
            map(tuple, grid_edges.reshape(len(grid_edges), -1).tolist())), cap


@pytest.mark.parametrize("boundary,replicas", [("periodic", 1), ("reflecting", 3), ("open", 1), ("open", 2)])
def test_rank_sort_builds_the_same_grid(engine, boundary, replicas):
    """The GPU's in-bucket ordering (each agent's rank among its bucket's ids) and the CPU's insertion sort give the
    same cell-sorted grid: slots in cell order, and agents of one cell in id order. Elements are stored shuffled
    and crowded (~40 per cell) so that the scatter leaves buckets far from id order."""
    rng = np.random.default_rng(3)
    n, box = 1200, 6.0
    x = rng.random((2, n)) * box - (box / 2 if boundary == "open" else 0.0)
    ids = rng.permutation(n).astype(np.int32)
    built = []
    for rank_sort in (False, True):
        grid = CellGrid(n, 2, boundary, box, 1.0, engine.real, replicas, rank_sort=rank_sort)
        pos = ti.ndarray(grid.pos_sorted.dtype, (2, n))
        pos.from_numpy(x.astype(engine.real))
        element_ids = ti.ndarray(ti.i32, n)
        element_ids.from_numpy(ids)
        grid.build(pos, element_ids)
        arrays = {k: getattr(grid, k).to_numpy() for k in ("start", "order", "id_sorted", "pos_sorted",
                                                             "coords_sorted", "mixed")}
        built.append({**arrays, "slot_of": grid.slots().to_numpy()})
    insertion, ranked = built
    for key, value in insertion.items():
        assert np.array_equal(value, ranked[key]), key
    assert np.array_equal(insertion["slot_of"][insertion["id_sorted"]], np.arange(n))
    start, id_sorted = insertion["start"], insertion["id_sorted"]
    assert np.diff(start).max() >= 20
    for b in np.flatnonzero(np.diff(start) > 1):
        assert np.all(np.diff(id_sorted[start[b]:start[b + 1]]) > 0)


@pytest.mark.skipif(ARCH != "cpu", reason="the lane-wise kernel is the CPU's")
@pytest.mark.parametrize("boundary", ["periodic", "reflecting"])
@pytest.mark.parametrize("box,radius", [(10.0, 1.0), (10.0, 4.0), (10.0, 6.0), (3.0, 1.0), (50.0, 0.7), (200.0, 1.0)])
def test_lane_wise_sums_match_brute_force(engine, boundary, box, radius):
    """The CPU's lane-wise Vicsek kernel (runs of cells, LANES agents at a time) counts and sums exactly the
    brute-force neighbours, itself included: sparse cells merged into runs, crowded cells of several lane blocks,
    periodic edges, boxes of fewer than 3 cells per side and rows of cells with no agent. The runs cover every
    occupied cell once."""
    from tflock.models.vicsek import RULES, _headings, _neighbour_sums
    from tflock.neighbors import LANES

    rng = np.random.default_rng(int(box * 10 + radius))
    x = np.concatenate([rng.random((300, 2)) * box, box / 3 + rng.random((60, 2)) * 0.4])  # a clump: crowded cells
    if box == 200.0:
        x[:, 1] *= 0.25  # a band: the rows of cells above it hold no agent
    theta = rng.random(len(x)) * 2 * np.pi
    model = model_at(engine, x, boundary, box, radius)
    model.set_state({"x": x, "theta": theta}, 0)
    assert model.lane_wise
    model._ensure_grid()
    grid, g = model.grid, model.grid.geometry
    nc = g.cells_per_side
    counts = np.diff(grid.start.to_numpy()).reshape(nc, nc)
    run_end = grid.runs().to_numpy().reshape(nc, nc)
    covered = np.zeros_like(counts)
    for y, x0 in zip(*np.nonzero(run_end >= 0), strict=True):
        x1 = run_end[y, x0]
        assert x0 < x1 <= nc and counts[y, x0] > 0
        assert counts[y, x0:x1].sum() <= LANES or x1 == x0 + 1
        covered[y, x0:x1] += 1
    assert np.array_equal(covered[counts > 0], np.ones((counts > 0).sum())) and covered.max() == 1
    assert box < 200.0 or (counts.sum(axis=1) == 0).sum() >= 20  # the runs' pass skips empty rows whole
    _headings(model.n_total, grid.order, model.theta, model.trig, model.payload)
    _neighbour_sums(g.total_buckets, nc, radius, box, RULES["average"], g.boundary, grid.start, grid.runs(),
                    grid.pos_sorted, model.payload, model.sums)
    ids = grid.id_sorted.to_numpy()
    sums = np.empty((3, len(x)))
    sums[:, ids] = model.sums.to_numpy()
    adjacency = ref.adjacency(x.astype(engine.real), radius, boundary, box)
    np.fill_diagonal(adjacency, True)
    assert np.array_equal(sums[2], adjacency.sum(axis=1))
    rtol = 1e-5 if engine.real == np.float32 else 1e-12
    assert np.allclose(sums[0], adjacency @ theta.astype(engine.real), rtol=rtol)


def built_grid(engine, x, boundary, box, radius, **options):
    """A CellGrid (`options`: replicas, bounded) built on positions x (n, dim), agent ids 0 .. n - 1."""
    n, dim = x.shape
    grid = CellGrid(n, dim, boundary, box, radius, engine.real, **options)
    pos = ti.ndarray(ti.f32 if engine.real == np.float32 else ti.f64, (dim, n))
    pos.from_numpy(np.ascontiguousarray(x.T, dtype=engine.real))
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(np.arange(n, dtype=np.int32))
    grid.build(pos, ids)
    return grid


def bounded_grid_degrees(engine, x, radius, boundary="open", box=1.0):
    """A bounded open-space (or periodic-box) grid on positions x (n, dim): its layout and each agent's
    brute-force-comparable degree (agent order) from the R-graph kernel."""
    grid = built_grid(engine, x, boundary, box, radius, bounded=True)
    graph = NeighbourGraph(grid)
    graph.compute(radius, box)
    return grid.geometry, graph.degree.to_numpy()


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("radius", [0.7, 2.0])
def test_bounded_layout_matches_brute_force(engine, dim, radius):
    """A compact open-space swarm's cells are stored row-major over their bounding box (a block like a box's); one
    far straggler makes that block too large, and the build falls back to the hash. Both find exactly the
    brute-force neighbours, agents on the box's faces included."""
    from tflock.neighbors import BOUNDED, OPEN

    rng = np.random.default_rng(dim * 10 + int(radius * 10))
    side = 9.0 if dim == 2 else 5.0  # the cube of cells fits in the table's 1024 buckets
    x = rng.random((400, dim)) * side - 20.0  # negative coordinates: the origin is the lower corner, not 0
    x[:10, 0] = x[:10, 0].min()  # agents on the lower and upper faces
    x[10:20, 1] = x[10:20, 1].max()
    geometry, degree = bounded_grid_degrees(engine, x, radius)
    cells = np.floor(x.astype(engine.real) / engine.real(radius))
    assert geometry.boundary == BOUNDED and geometry.cells_per_side == int((cells.max(0) - cells.min(0)).max()) + 1
    assert np.array_equal(degree, ref.adjacency(x.astype(engine.real), radius, "open", 1.0).sum(axis=1))
    for far in (1e5, 1e18):  # a straggler: the cube over the bounding box needs more cells than the table's buckets
        x[0] = far  # (1e18: its cell coordinate overflows an int32)
        geometry, degree = bounded_grid_degrees(engine, x, radius)
        assert geometry.boundary == OPEN
        assert np.array_equal(degree, ref.adjacency(x.astype(engine.real), radius, "open", 1.0).sum(axis=1))



@pytest.mark.parametrize("dim", [2, 3])
def test_window_layout_matches_brute_force(engine, dim):
    """A compact swarm in a large periodic box is stored over the window of side-R cells it occupies, also astride
    the box's edges (minimum-image distances); a swarm that leaves less than R of the torus outside its window
    keeps the box's tiling. Both find exactly the brute-force neighbours."""
    from tflock.space import PERIODIC, WINDOW

    box, radius = 200.0, 1.5
    rng = np.random.default_rng(dim)
    x = rng.random((500, dim)) * 12.0 - 6.0  # around the corner 0: agents on both sides of every face
    x %= box
    x[:5, 0] = box - 1e-3  # just inside the upper face
    geometry, degree = bounded_grid_degrees(engine, x, radius, "periodic", box)
    assert geometry.boundary == WINDOW and geometry.cell_size == radius and geometry.cells_per_side <= 10
    expected = ref.adjacency(x.astype(engine.real), radius, "periodic", box).sum(axis=1)
    assert expected.max() >= 5 and np.array_equal(degree, expected)
    for broken in ("chain", "nan anchor", "nan agent"):
        y = x.copy()
        if broken == "chain":  # a chain around the torus: no window fits
            y[5:60, 0] = np.linspace(0.0, box, 55, endpoint=False)
        else:  # a blown-up agent (the anchor is agent 0) has no neighbours, and no window
            y[0 if broken == "nan anchor" else 7] = np.nan
        geometry, degree = bounded_grid_degrees(engine, y, radius, "periodic", box)
        assert geometry.boundary == PERIODIC, broken
        assert np.array_equal(degree, ref.adjacency(y.astype(engine.real), radius, "periodic", box).sum(axis=1))


@ti.kernel
def _window_wraps(nc: ti.i32, cell_size: float, box: float, start: ti.types.ndarray(), run_end: ti.types.ndarray(),
                  bounds: ti.types.ndarray(), anchor: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[b] = window_run_wraps of the run starting at bucket b (1 or 0), -1 where none starts."""
    for b in range(nc * nc):
        row, x0, x1, a0, a1 = run_at(b, nc, start, run_end)
        out[b] = -1
        if a1 > a0:
            out[b] = ti.select(window_run_wraps(row, x0, x1, nc, cell_size, box, bounds, anchor), 1, 0)


def test_runs_are_the_same_however_the_rows_are_spread_over_the_threads(engine):
    """The runs' kernel takes a row a task at any stride (tflock.cpu_tasks.spread_shift): the same runs at every
    one, and the stride fills SPREAD_ITERATIONS iterations without passing TASK_STRIDE."""
    import taichi as ti

    from tflock.cpu_tasks import SPREAD_ITERATIONS, TASK_STRIDE, spread_shift
    from tflock.neighbors import _runs

    assert spread_shift(1 << 20) == 0 and spread_shift(1) == TASK_STRIDE.bit_length() - 1
    assert (707 << spread_shift(707)) >= SPREAD_ITERATIONS > (707 << (spread_shift(707) - 1))
    rng = np.random.default_rng(5)
    x = rng.random((3000, 2)) * 60.0
    x[:, 1] *= 0.5  # the upper rows hold no agent
    model = model_at(engine, x, "periodic", 60.0, 1.0)
    model.set_state({"x": x, "theta": rng.random(len(x)) * 2 * np.pi}, 0)
    model._ensure_grid()
    grid, g = model.grid, model.grid.geometry
    rows = g.total_buckets // g.cells_per_side
    expected = grid.runs().to_numpy()
    for shift in (0, 3, spread_shift(rows), 10):
        run_end = ti.ndarray(ti.i32, expected.shape)
        _runs(rows, g.cells_per_side, shift, grid.start, run_end)
        assert np.array_equal(run_end.to_numpy(), expected), shift


@pytest.mark.parametrize("where", ["middle", "below the upper edges", "astride the corner"])
def test_window_runs_skip_the_minimum_image_only_where_it_is_the_plain_difference(engine, where):
    """A run of a window grid that takes plain differences (window_run_wraps false) has every pair of its agents
    and its stencil's candidates less than box / 2 apart along each axis, where the minimum image is the plain
    difference; a swarm away from the torus's edges takes that path in most runs, one at its edges in few."""
    box, radius, n = 200.0, 1.5, 75 * LANES  # ~9 agents a cell whatever the lanes: runs of one or two cells
    rng = np.random.default_rng(len(where))
    offset = {"middle": 90.0, "below the upper edges": box - 12.0, "astride the corner": -6.0}
    x = (rng.random((n, 2)) * 12.0 + offset[where]) % box
    if where == "below the upper edges":
        x[:20] = box - 1e-3 * rng.random((20, 2))
    grid = CellGrid(n, 2, "periodic", box, radius, engine.real, bounded=True)
    pos = ti.ndarray(ti.f32 if engine.real == np.float32 else ti.f64, (2, n))
    pos.from_numpy(np.ascontiguousarray(x.T, dtype=engine.real))
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(np.arange(n, dtype=np.int32))
    grid.build(pos, ids)
    g = grid.geometry
    assert g.boundary == WINDOW
    nc = g.cells_per_side
    out = np.zeros(nc * nc, dtype=np.int32)
    _window_wraps(nc, g.cell_size, box, grid.start, grid.runs(), grid.bounds, grid.anchor, out)
    start, run_end, p = grid.start.to_numpy(), grid.runs().to_numpy(), grid.pos_sorted.to_numpy().T.astype(float)
    plain = 0
    for b in np.flatnonzero(out == 0):
        row, x0 = divmod(int(b), nc)
        run = p[start[b]:start[row * nc + run_end[b]]]
        for y in range(max(row - 1, 0), min(row + 2, nc)):
            stencil = p[start[y * nc + max(x0 - 1, 0)]:start[y * nc + min(run_end[b] + 1, nc)]]
            gap = np.abs(run[:, None, :] - stencil[None, :, :]).max(initial=0.0)
            assert gap < box / 2, (b, y)
        plain += 1
    runs = int((out >= 0).sum())
    low, high = {"middle": (0.99, 1.0), "below the upper edges": (0.3, 0.8), "astride the corner": (0.0, 0.5)}[where]
    assert runs >= 50 and low <= plain / runs <= high


@pytest.mark.parametrize("model", ["vicsek", "adaptive", "potential"])
def test_frame_rows_are_the_drawn_agents_state(make_sim, model):
    """A frame draws the selected agents' own positions and headings (its rows are gathered in the grid's order,
    which differs from the order the state is kept in once agents have changed cells)."""
    params = {"n": 3000, "box": 30.0} if model != "potential" else {"n": 3000, "box": 60.0, "dt": 0.05}
    sim = make_sim(model=model, params=params, steps=20)
    sim.step(6)
    selected = np.arange(1, 3000, 3)
    frame = sim.model.frame(selected, max_edges=500)
    state = sim.model.state()
    np.testing.assert_allclose(frame.positions, state["x"][selected], rtol=1e-6, atol=1e-5)
    if model == "vicsek":
        theta = state["theta"][selected]
        heading = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    else:
        heading = state["d" if model == "adaptive" else "v"][selected]
    unit = frame.directions / np.linalg.norm(frame.directions, axis=1, keepdims=True)
    np.testing.assert_allclose(unit, heading / np.linalg.norm(heading, axis=1, keepdims=True), atol=1e-5)
    assert 490 <= len(frame.edges) <= 500  # the pairs of whole drawn agents (rows), up to the cap


@pytest.mark.parametrize("model_name,params", [
    ("vicsek", {"n": 3000, "box": 30.0, "boundary": "periodic", "noise": 0.5}),
    ("vicsek", {"n": 3000, "box": 30.0, "boundary": "reflecting", "noise": 0.5}),
    ("potential", {"n": 3000, "box": 60.0, "dt": 0.05}),
    ("potential", {"n": 3000, "box": 20.0, "dt": 0.05, "dim": 3}),
])
def test_announced_frame_is_the_frame_drawn_by_its_own_pass(make_sim, model_name, params):
    """A lane-wise step told by draw_next that its state will be drawn writes the drawn agents' rows itself; the
    frame made from them equals, bit for bit, the frame its own pass over the grid draws from the same state. So
    does a run of steps told several steps ahead (the fused loops write the rows of the state they end at)."""
    sim = make_sim(model=model_name, params=params, steps=20)
    model = sim.model
    sim.step(4)
    selected = np.arange(2, 3000, 7)
    for ahead in (1, 5, 1, 3):
        model.draw_next(selected, model.step_index + ahead)
        model.advance(ahead)
        announced = model.frame(selected, max_edges=300)
        assert model._drawn is not None or not model.lane_wise  # the step wrote the rows (CPU lane-wise step)
        model.invalidate()  # forgets them: the frame is drawn again by its own pass (on the same grid, rebuilt)
        drawn = model.frame(selected, max_edges=300)
        for name in ("positions", "directions", "colors", "edges"):
            np.testing.assert_array_equal(getattr(announced, name), getattr(drawn, name), err_msg=name)


def swarm(kind, n, dim, box, radius, rng, boundary="periodic", spread=1.5):
    """Positions for the components' tests: one dense flock (astride the corner of a periodic box, where it wraps;
    in the middle of others; a normal spread of `spread` R), or many small clusters in a sparse field."""
    if kind == "one flock":
        x = rng.normal(size=(n, dim)) * radius * spread + (0.0 if boundary == "periodic" else box / 2)
    else:
        centres = rng.random((n // 8, dim)) * box
        x = centres[rng.integers(len(centres), size=n)] + rng.normal(size=(n, dim)) * radius * 0.3
    return np.mod(x, box)


#: tests of tflock.components' union-find passes, which Vulkan does not take: tflock.metrics.NeighbourGraph joins by
#: rounds of labels there (Taichi 1.7's SPIR-V backend miscompiles the lock-free union-find)
union_find_only = pytest.mark.skipif(ARCH == "vulkan", reason="Vulkan joins by rounds of labels, not by union-find")


def components_on_grid(engine, x, boundary, box, radius, strict, dense):
    """The components of x's R-graph by the pass `dense` picks (sub-cells or pairs), on a model grid of x."""
    from tflock.components import Components

    found = Components(built_grid(engine, x, boundary, box, radius), radius, strict)
    found.dense = dense
    return found.compute(), found


@union_find_only
@pytest.mark.parametrize("dense", [False, True], ids=["pairs", "sub-cells"])
@pytest.mark.parametrize("kind", ["one flock", "many clusters"])
@pytest.mark.parametrize("boundary,dim", [("periodic", 2), ("reflecting", 2), ("open", 2), ("periodic", 3),
                                          ("open", 3)])
def test_components_match_brute_force(engine, boundary, dim, kind, dense):
    """Both passes of tflock.components find the brute-force components: one dense flock (more than ten
    neighbours each on average; periodic: astride the corner, so it wraps), many small clusters, open space, 3D; the
    graph |r| < R (strict) too."""
    rng = np.random.default_rng(dim * 7 + len(boundary) + len(kind))
    box, radius = (12.0 if kind == "one flock" else 40.0), 1.0
    x = swarm(kind, 500, dim, box, radius, rng, boundary).astype(engine.real)
    for strict in (False, True):
        (clusters, largest), found = components_on_grid(engine, x, boundary, box, radius, strict, dense)
        a = ref.adjacency(x, radius, boundary, box)
        if strict:
            d = ref.displacements(x, boundary, box)
            a = (d * d).sum(axis=2) < engine.real(radius) ** 2
            np.fill_diagonal(a, False)
        _, sizes = np.unique(ref.components(a), return_counts=True)
        assert (clusters, largest) == (len(sizes), sizes.max())
        assert (found.slot_grid is not found.model_grid) == dense  # the pass asked for ran
    if kind == "one flock":
        assert a.sum(axis=1).mean() > 10 and sizes.max() > 250
    else:
        assert len(sizes) > 20


@union_find_only
@pytest.mark.parametrize("boundary,dim", [("periodic", 2), ("reflecting", 2), ("open", 2), ("periodic", 3)])
def test_degrees_counted_in_the_pairs_pass_are_the_degree_pass_counts(engine, monkeypatch, boundary, dim):
    """Once a call has seen a sparse swarm, the next one counts the degrees in the pairs pass's walk
    (Components.compute_with_degrees): the same degrees, clusters, roots and sizes as the degree pass and the
    pairs pass apart, and the brute-force graph's; a dense flock keeps the two passes."""
    from tflock.components import Components

    rng = np.random.default_rng(dim * 3 + len(boundary))
    combined = []
    original = Components.compute_with_degrees
    monkeypatch.setattr(Components, "compute_with_degrees",
                        lambda self, *a: combined.append(1) or original(self, *a))
    for kind, box in (("many clusters", 40.0), ("one flock", 12.0)):
        x = swarm(kind, 600, dim, box, 1.0, rng, boundary).astype(engine.real)
        if boundary == "open":
            x -= np.asarray(box / 2, dtype=engine.real)
        for strict in (False, True):
            graph = NeighbourGraph(built_grid(engine, x, boundary, box, 1.0), strict)
            first = graph.compute(1.0, box)
            degree, roots = graph.degree.to_numpy().copy(), [a.tolist() for a in graph._roots()]
            sparse = graph._components.takes_pairs()
            assert sparse == (kind == "many clusters" or dim == 3)  # a 2D flock is dense: sub-cells
            before = len(combined)
            again = graph.compute(1.0, box)
            assert len(combined) == before + sparse  # sparse: one walk; dense: two passes
            assert again == first
            assert np.array_equal(graph.degree.to_numpy(), degree)
            assert [a.tolist() for a in graph._roots()] == roots
            if not strict:
                want = ref.graph_metrics(x, 1.0, boundary, box)
                assert (again["clusters"], again["max_neighbors"]) == (want["clusters"], want["max_neighbors"])
                assert again["mean_neighbors"] == pytest.approx(want["mean_neighbors"])


@union_find_only
@pytest.mark.parametrize("arch", ["cpu", "cuda"])
def test_the_pass_follows_the_arch_thresholds(engine, monkeypatch, arch):
    """At Vicsek's default density (a mean degree of about 22) the CPU's thresholds take the sub-cell pass and
    CUDA's the pairs pass (faster there up to a mean degree of about 40); at about 80 both take the sub-cells. The
    pass runs on this test's engine whatever arch the thresholds are read for, and finds the brute-force
    components."""
    from dataclasses import replace

    from tflock import components

    info = replace(components.current_engine(), arch=arch)
    monkeypatch.setattr(components, "current_engine", lambda: info)
    rng = np.random.default_rng(11)
    n, radius = 2000, 1.0
    for degree, sub_cells in ((22.0, arch == "cpu"), (80.0, True)):
        box = float(np.sqrt(n * np.pi * radius**2 / degree))
        x = (rng.random((n, 2)) * box).astype(engine.real)
        a = ref.adjacency(x, radius, "periodic", box)
        _, sizes = np.unique(ref.components(a), return_counts=True)
        found = components.Components(built_grid(engine, x, "periodic", box, radius), radius)
        assert found.compute(a.sum(axis=1).mean()) == (len(sizes), sizes.max())
        assert (found.slot_grid is not found.model_grid) == sub_cells
        assert abs(a.sum(axis=1).mean() - degree) < 0.1 * degree


@union_find_only
def test_small_dense_swarms_take_the_pairs_pass(engine):
    """A flock dense enough for the sub-cell pass (on every arch: a mean degree above 38) but of at most
    SUBCELL_MIN_AGENTS agents is joined by the pairs pass (the sub-cell grid's launches cost more there), with the
    brute-force components and counts."""
    from tflock.components import SUBCELL_MIN_AGENTS

    rng = np.random.default_rng(5)
    box, radius = 12.0, 1.0
    x = swarm("one flock", SUBCELL_MIN_AGENTS, 2, box, radius, rng, spread=0.8).astype(engine.real)
    graph = NeighbourGraph(built_grid(engine, x, "periodic", box, radius))
    got = graph.compute(radius, box)
    assert graph._components.dense and graph._components.slot_grid is graph.grid  # dense, yet the pairs pass
    want = ref.graph_metrics(x, radius, "periodic", box)
    assert (got["clusters"], got["max_neighbors"]) == (want["clusters"], want["max_neighbors"])
    assert got["largest_cluster"] == pytest.approx(want["largest_cluster"])
    assert got["mean_neighbors"] == pytest.approx(want["mean_neighbors"]) and want["mean_neighbors"] > 40


@pytest.mark.parametrize("boundary,dim,bounded", [("periodic", 2, False), ("reflecting", 2, False),
                                                  ("open", 2, False), ("open", 2, True), ("periodic", 3, False)])
def test_small_swarms_graph_in_one_launch(engine, monkeypatch, boundary, dim, bounded):
    """At most SMALL_GRAPH_MAX agents: degrees and components from one launch on one thread, the brute-force
    graph's, and the same numbers and roots as the parallel passes (SMALL_GRAPH_MAX = 0), one flock and many
    clusters, the graph |r| < R (strict) too."""
    import tflock.metrics as metrics

    rng = np.random.default_rng(dim + len(boundary))
    for kind, box in (("one flock", 12.0), ("many clusters", 40.0)):
        x = swarm(kind, metrics.SMALL_GRAPH_MAX, dim, box, 1.0, rng, boundary).astype(engine.real)
        if boundary == "open":
            x -= np.asarray(box / 2, dtype=engine.real)
        for strict in (False, True):
            small = NeighbourGraph(built_grid(engine, x, boundary, box, 1.0, bounded=bounded), strict)
            parallel = NeighbourGraph(built_grid(engine, x, boundary, box, 1.0, bounded=bounded), strict)
            got = small.compute(1.0, box)
            with monkeypatch.context() as m:
                m.setattr(metrics, "SMALL_GRAPH_MAX", 0)
                assert parallel.compute(1.0, box) == got
            assert [a.tolist() for a in small._roots()] == [a.tolist() for a in parallel._roots()]
            if not strict:
                want = ref.graph_metrics(x, 1.0, boundary, box)
                assert (got["clusters"], got["max_neighbors"]) == (want["clusters"], want["max_neighbors"])
                assert got["largest_cluster"] == pytest.approx(want["largest_cluster"])
                assert got["mean_neighbors"] == pytest.approx(want["mean_neighbors"])
                if kind == "one flock":
                    assert want["largest_cluster"] > 0.5 and want["mean_neighbors"] > 3
                else:
                    assert want["clusters"] > 5


@pytest.mark.parametrize("boundary", ["periodic", "open"])
@pytest.mark.parametrize("density", ["sparse", "dense"])
def test_replica_components_match_brute_force(engine, boundary, density):
    """A batch of replicas (one grid, no edge across replicas): each replica's clusters and S are its own, by
    the pass its density picks (dense: a mean degree above 38, the sub-cells on every arch)."""
    rng = np.random.default_rng(11)
    kind = "one flock" if density == "dense" else "many clusters"
    box, radius, per = (10.0 if density == "dense" else 25.0), 1.0, 300
    xs = [swarm(kind, per, 2, box, radius, rng, boundary, spread=0.8).astype(engine.real) for _ in range(3)]
    grid = built_grid(engine, np.concatenate(xs), boundary, box, radius, replicas=3)
    graph = NeighbourGraph(grid)
    got = graph.compute_replicas(radius, box)
    assert graph.in_rounds or (graph._components.slot_grid is not grid) == (density == "dense")
    for r, x in enumerate(xs):
        want = ref.graph_metrics(x, radius, boundary, box)
        assert got["clusters"][r] == want["clusters"]
        assert got["largest_cluster"][r] == pytest.approx(want["largest_cluster"])
        assert got["mean_neighbors"][r] == pytest.approx(want["mean_neighbors"])
        assert got["max_neighbors"][r] == want["max_neighbors"]
        assert (want["mean_neighbors"] > 40) == (density == "dense")
