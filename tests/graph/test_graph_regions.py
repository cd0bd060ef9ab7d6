"""Region clustering: the paper's weight, average linkage and cuts against a naive reference, the
micro-cluster form above the dense size limit, spectral splits and their stopping rules."""

from __future__ import annotations

import numpy as np
import pytest

from terra.graph.agglomerative import (
    agglomerative_assignments,
    condensed_sqeuclidean,
    gap_cuts,
    weighted_average_linkage,
)
from terra.graph.regions import build_levels, paper_weight
from terra.graph.spectral import SpectralStop, semantic_difference, should_stop, spectral_assignments


def partition(labels) -> set[frozenset[int]]:
    groups: dict[int, set[int]] = {}
    for i, label in enumerate(np.asarray(labels).tolist()):
        groups.setdefault(label, set()).add(i)
    return {frozenset(g) for g in groups.values()}


def naive_average_linkage_cut(W: np.ndarray, height: float) -> set[frozenset[int]]:
    """Textbook UPGMA on a full matrix: merge the two clusters with the smallest mean pairwise
    weight while it is <= height."""
    clusters = [[i] for i in range(len(W))]
    while len(clusters) > 1:
        best, pair = np.inf, None
        for a in range(len(clusters)):
            for b in range(a + 1, len(clusters)):
                d = W[np.ix_(clusters[a], clusters[b])].mean()
                if d < best:
                    best, pair = d, (a, b)
        if best > height:
            break
        assert pair is not None
        a, b = pair
        clusters[a] = clusters[a] + clusters[b]
        del clusters[b]
    return {frozenset(c) for c in clusters}


def unit(rng, n, d=8):
    v = rng.normal(size=(n, d))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_paper_weight_by_hand():
    p_i, p_j = np.array([[0.0, 0.0, 0.0]]), np.array([[3.0, 4.0, 0.0]])
    e_i, e_j = np.array([[1.0, 0.0]]), np.array([[2.0, 2.0]])  # any norm: cos = 1 / sqrt(2)
    assert np.isclose(paper_weight(p_i, p_j, e_i, e_j, 100.0)[0], 5.0 + 100.0 * (1 - 1 / np.sqrt(2)))
    assert np.isclose(paper_weight(p_i, p_j, e_i, e_i, 100.0)[0], 5.0)


def test_dense_average_linkage_cuts_match_a_naive_reference():
    rng = np.random.default_rng(1)
    # Three spatial blobs 120 m apart, two embedding families mixed inside them.
    centres = np.array([[0.0, 0.0], [120.0, 0.0], [0.0, 130.0]])
    pos = np.column_stack(
        [np.repeat(centres, 8, axis=0) + rng.normal(scale=12.0, size=(24, 2)), rng.normal(scale=0.5, size=24)]
    )
    base = unit(rng, 2)
    emb = base[rng.integers(0, 2, 24)] + 0.2 * unit(rng, 24)
    cuts = (20.0, 50.0, 100.0, 200.0)
    out = agglomerative_assignments(pos, emb, np.zeros(24, int), gamma=100.0, cuts=cuts)
    W = np.array(
        [[paper_weight(pos[[i]], pos[[j]], emb[[i]], emb[[j]], 100.0)[0] for j in range(24)] for i in range(24)]
    )
    for labels, cut in zip(out, cuts):
        assert partition(labels) == naive_average_linkage_cut(W, cut)
    sizes = [len(partition(labels)) for labels in out]
    assert sizes == sorted(sizes, reverse=True) and sizes[0] > sizes[-1]


def test_condensed_squared_distances_from_products_equal_pdists():
    """Across row blocks, with a zero row (an unembedded place) and twin rows: scipy's values."""
    from scipy.spatial.distance import pdist

    rng = np.random.default_rng(4)
    x = rng.normal(size=(600, 24))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    x[7] = 0.0
    x[300] = x[299]
    for block in (1, 256, 1000):
        np.testing.assert_allclose(condensed_sqeuclidean(x, block), pdist(x, "sqeuclidean"), rtol=0, atol=1e-12)
    assert condensed_sqeuclidean(x[:1]).shape == (0,)


def test_the_semantic_term_separates_co_located_places():
    rng = np.random.default_rng(2)
    pos = np.column_stack([rng.uniform(0, 20, size=(30, 2)), np.zeros(30)])
    family = np.arange(30) % 2
    emb = np.eye(4)[family]  # orthogonal: 1 - cos = 1, weight >= gamma = 100 between families
    labels = agglomerative_assignments(pos, emb, np.zeros(30, int), gamma=100.0, cuts=(50.0, 400.0))
    assert partition(labels[0]) == partition(family)
    assert len(partition(labels[1])) == 1
    # gamma = 0: geometry only, and 20 m of spread is one region at a 50 m cut.
    assert len(partition(agglomerative_assignments(pos, emb, np.zeros(30, int), gamma=0.0, cuts=(50.0,))[0])) == 1


def test_gap_levels_cut_below_the_largest_merge_height_gaps():
    assert gap_cuts(np.array([11.0, 1.0, 30.0, 2.0, 10.0]), 2) == (2.0, 11.0)  # gaps 19 and 8
    # Places on a line in groups: {0, 1}, {10, 11} 10 m apart, and {60} far away (gamma 0).
    x = np.array([0.0, 1.0, 10.0, 11.0, 60.0])
    pos = np.column_stack([x, np.zeros(5), np.zeros(5)])
    out = agglomerative_assignments(pos, np.ones((5, 2)), np.zeros(5, int), gamma=0.0, gap_levels=2)
    # Merge heights 1, 1, 10, 54.5: the largest gaps are above 10 and above 1.
    assert [partition(o) for o in out] == [partition([0, 0, 1, 1, 2]), partition([0, 0, 0, 0, 1])]


def test_weighted_average_linkage_equals_scipy_on_singletons():
    from scipy.cluster.hierarchy import linkage
    from scipy.spatial.distance import pdist, squareform

    rng = np.random.default_rng(3)
    x = rng.normal(size=(40, 2)) * 30
    d = pdist(x)
    ours = weighted_average_linkage(squareform(d), np.ones(40))
    assert np.allclose(np.sort(ours[:, 2]), np.sort(linkage(d, "average")[:, 2]))


def test_micro_cluster_form_agrees_with_the_dense_form_where_both_apply():
    """Above dense_max the places are grouped per (terrain, cuts[0] / 10 m cell). With one place
    per cell the micro-cluster linkage is exact, so the two forms give the same regions."""
    rng = np.random.default_rng(4)
    grid = np.stack(np.meshgrid(np.arange(18), np.arange(14)), -1).reshape(-1, 2) * 10.0
    pos = np.column_stack([grid + rng.uniform(0.5, 4.5, size=grid.shape), np.zeros(len(grid))])  # one per 5 m cell
    emb = unit(rng, 3)[(grid[:, 0] > 90).astype(int) + (grid[:, 1] > 70)] + 0.1 * unit(rng, len(grid), 8)[:, :8]
    terrain = (grid[:, 0] > 60).astype(int)
    dense = agglomerative_assignments(pos, emb, terrain, dense_max=10_000)
    micro = agglomerative_assignments(pos, emb, terrain, dense_max=10, micro_max=10_000)
    for a, b in zip(dense, micro):
        assert partition(a) == partition(b)
    assert len(partition(dense[0])) > 1


def test_micro_clusters_bound_the_matrix_and_keep_a_hierarchy():
    rng = np.random.default_rng(5)
    pos = np.column_stack([rng.uniform(0, 600, size=(3000, 2)), np.zeros(3000)])
    emb = unit(rng, 3000)
    out = agglomerative_assignments(pos, emb, rng.integers(0, 3, 3000), dense_max=100, micro_max=400)
    for fine, coarse in zip(out, out[1:]):  # nested: each fine region inside one coarse region
        pairs = np.unique(np.column_stack([fine, coarse]), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(pairs)
    # Places of one (terrain, cell) group share a region; at most micro_max groups.
    assert len(np.unique(out[0])) <= 400


def test_build_levels_centroids_and_normalised_mean_embeddings():
    pos = np.array([[0.0, 0, 0], [2, 0, 0], [10, 0, 0], [12, 0, 1]])
    emb = np.array([[1.0, 0], [0, 1], [1, 0], [1, 0]], dtype=np.float32)
    levels = build_levels([np.array([5, 5, 7, 7]), np.array([1, 1, 1, 1])], pos, emb)
    assert np.array_equal(levels[0].parent_of_child, [0, 0, 1, 1])
    assert np.allclose(levels[0].position, [[1, 0, 0], [11, 0, 0.5]])
    assert np.allclose(levels[0].embedding[0], np.array([1, 1]) / np.sqrt(2))
    assert np.array_equal(levels[1].parent_of_child, [0, 0])
    assert np.allclose(levels[1].position, [[6, 0, 0.25]])


# ------------------------------------------------------------------------------------ spectral


def test_semantic_difference_is_most_minus_least_similar_to_the_mean():
    emb = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    mean = np.array([1.0, 1.0]) / np.sqrt(2)
    sims = (emb / np.linalg.norm(emb, axis=1, keepdims=True)) @ mean
    assert np.isclose(semantic_difference(emb), sims.max() - sims.min())
    assert np.isclose(semantic_difference(emb), 1 - 1 / np.sqrt(2))


def test_stop_rule_either_is_the_papers_and_both_is_the_references():
    pos = np.array([[0.0, 0, 0], [200, 200, 0]])  # 40,000 m^2: too large to stop on area
    same = np.array([[1.0, 0], [1.0, 0.01]])  # semantic difference ~0: small
    assert should_stop(pos, same, 0.45, 10_000, "either")
    assert not should_stop(pos, same, 0.45, 10_000, "both")
    small = np.array([[0.0, 0, 0], [20, 20, 0]] * 3)  # 400 m^2
    different = np.array([[1.0, 0]] * 5 + [[0.0, 1]])  # mean ~ (5, 1): 0.98 - 0.20 = 0.78
    assert np.isclose(semantic_difference(different), (5 - 1) / np.sqrt(26))
    assert should_stop(small, different, 0.45, 10_000, "either")
    assert not should_stop(small, different, 0.45, 10_000, "both")
    same = np.array([[1.0, 0]] * 6)
    assert should_stop(small, same, 0.45, 10_000, "both")


def chain_world(rng, n=30, m=12):
    """Two chains 300 m long, side by side 150 m apart, of n and m places, each with its own
    embedding, joined by one edge; each spans more than 10,000 m^2 with a ripple. (Unbalanced on
    purpose: with two orthogonal families of equal size every member is equally similar to the
    mean, so the paper's semantic difference of the whole would be 0.)"""

    def chain(k, y):
        x = np.linspace(0, 300, k)
        return np.column_stack([x, y + 40 * np.sin(x / 40), np.zeros(k)])

    pos = np.vstack([chain(n, 0.0), chain(m, 150.0)])
    family = np.repeat([0, 1], [n, m])
    emb = np.eye(6)[family] + 0.05 * unit(rng, n + m, 6)
    edges = np.array(
        [(i, i + 1) for i in range(n - 1)] + [(n + i, n + i + 1) for i in range(m - 1)] + [(n // 2, n + m // 2)]
    )
    return pos, emb, edges, family


def test_spectral_splits_along_semantics_and_geometry_and_is_deterministic():
    pos, emb, edges, family = chain_world(np.random.default_rng(6))
    out = spectral_assignments(pos, emb, edges, levels=3, stop=SpectralStop(0.45, 10_000.0), seed=0)
    # The root's semantic difference (0.59) is large, so it splits, at the weak link between the
    # families; each chain is semantically uniform, so it stops there (the paper's 'either' rule).
    assert semantic_difference(emb) > 0.45
    assert partition(out[0]) == partition(family)
    assert len(partition(out[-1])) == 1  # one split deep: the upper levels are the root
    again = spectral_assignments(pos, emb, edges, levels=3, seed=0)
    assert all(np.array_equal(a, b) for a, b in zip(out, again))
    for fine, coarse in zip(out, out[1:]):
        pairs = np.unique(np.column_stack([fine, coarse]), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(pairs)


def test_spectral_stop_rules_differ_on_a_large_uniform_scene():
    pos, emb, edges, _ = chain_world(np.random.default_rng(7))
    emb = np.tile(np.eye(6)[0], (len(pos), 1)) + 0.01 * unit(np.random.default_rng(8), len(pos), 6)
    either = spectral_assignments(pos, emb, edges, levels=2, stop=SpectralStop(0.45, 10_000.0, "either"))
    both = spectral_assignments(pos, emb, edges, levels=2, stop=SpectralStop(0.45, 10_000.0, "both"))
    assert len(partition(either[0])) == 1  # semantic difference below 0.45: the paper stops at once
    # The reference's rule also needs the area below 10,000 m^2: it splits until every leaf is small.
    leaves = partition(both[0])
    assert len(leaves) > 2
    for leaf in leaves:
        idx = np.array(sorted(leaf))
        span = np.ptp(pos[idx, :2], axis=0)
        assert span[0] * span[1] < 10_000 or len(idx) < 4


@pytest.mark.parametrize("seed", [0, 3])
def test_spectral_is_a_partition_for_any_seed(seed):
    pos, emb, edges, _ = chain_world(np.random.default_rng(9))
    for labels in spectral_assignments(pos, emb, edges, levels=4, seed=seed):
        assert labels.shape == (len(pos),)


# ------------------------------------------------------------------------- adaptive levels


def test_level_counts_fall_geometrically_and_strictly():
    from terra.graph.agglomerative import level_counts

    assert level_counts(600, 4, 12.0, 3) == [50, 20, 8, 3]  # 50 * (3 / 50) ** (k / 3), rounded
    assert level_counts(50, 4, 12.0, 3) == [4, 3, 2, 1]  # a tiny map: strictly decreasing down to one
    assert level_counts(3000, 1, 12.0, 3) == [250]
    assert level_counts(600, 4, 12.0, 3, max_count=20) == [20, 11, 6, 3]


def test_count_cuts_give_the_counts_and_snap_to_the_largest_gap_nearby():
    from terra.graph.agglomerative import count_cuts

    # 8 leaves, merge heights 1..7 (each merge removes one cluster): c clusters need 8 - c merges.
    heights = np.arange(1.0, 8.0)
    assert count_cuts(heights, 8, [6, 4, 2]) == (2.0, 4.0, 6.0)
    # A big gap between merges 3 (height 3) and 4 (height 10): with snap 1.5, 4 clusters (cut after
    # 4 merges) move to 5 clusters (cut after 3 merges, just below the gap).
    heights = np.array([1.0, 2.0, 3.0, 10.0, 11.0, 12.0, 13.0])
    assert count_cuts(heights, 8, [4], snap=1.5) == (3.0,)
    assert count_cuts(heights, 8, [4], snap=1.0) == (10.0,)


def test_adaptive_levels_carry_information_where_the_papers_cuts_do_not():
    """A 120 m x 80 m map: the paper's 50/100/200/400 cuts leave its upper levels one region each;
    the adaptive levels strictly coarsen upward and nest; cuts=(50, 100, 200, 400) reproduces
    scipy's average linkage cut at those heights exactly."""
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import pdist

    rng = np.random.default_rng(10)
    pos = np.column_stack([rng.uniform(0, 120, 400), rng.uniform(0, 80, 400), np.zeros(400)])
    emb = unit(rng, 3)[(pos[:, 0] > 60).astype(int) + (pos[:, 1] > 40)] + 0.3 * unit(rng, 400, 8)[:, :8]
    paper = agglomerative_assignments(pos, emb, np.zeros(400, int), cuts=(50.0, 100.0, 200.0, 400.0))
    assert [len(np.unique(p)) for p in paper][2:] == [1, 1]
    w = pdist(pos) + 100.0 * (
        1 - (1 - 0.5 * pdist(np.asarray(emb / np.linalg.norm(emb, axis=1, keepdims=True)), "sqeuclidean"))
    )
    Z = linkage(w, "average")
    for labels, cut in zip(paper, (50.0, 100.0, 200.0, 400.0)):
        assert partition(labels) == partition(fcluster(Z, cut, "distance"))
    adaptive = agglomerative_assignments(pos, emb, np.zeros(400, int), cuts=None)
    counts = [len(np.unique(a)) for a in adaptive]
    assert len(counts) == 4 and all(a > b for a, b in zip(counts, counts[1:])) and counts[-1] >= 2
    for fine, coarse in zip(adaptive, adaptive[1:]):  # nested
        pairs = np.unique(np.column_stack([fine, coarse]), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(pairs)


def three_areas(rng, base: float):
    """90 places in three 30 m areas along a line, each area one semantic family (45, 30 and 15
    places: with equal families every place would be equally similar to the mean, a semantic
    difference of 0); embeddings are `base` times a common direction plus the family's, so a larger
    base compresses their cosines into a narrower, higher range. Places are chained along the line."""
    pos = np.column_stack(
        [np.repeat([0.0, 40.0, 80.0], 30) + np.tile(np.linspace(0, 30, 30), 3), np.zeros(90), np.zeros(90)]
    )
    family = np.repeat([0, 1, 2], [45, 30, 15])
    emb = base * np.eye(8)[7] + np.eye(8)[family] + 0.02 * unit(rng, 90, 8)
    edges = np.array([(i, i + 1) for i in range(89)])
    return pos, emb, edges, family


@pytest.mark.parametrize("base, root_range", [(0.3, (0.45, 0.5)), (1.0, (0.15, 0.25))])
def test_relative_spectral_thresholds_split_whatever_the_similarity_range(base, root_range):
    """The same three areas embedded in a wide similarity range (the whole map's semantic difference
    0.48, like CLIP images) and in a compressed one (0.2, like the text embedder): the relative
    thresholds split both into the three areas, while the paper's absolute 0.45 splits the first
    and never the second."""
    pos, emb, edges, family = three_areas(np.random.default_rng(11), base)
    assert root_range[0] < semantic_difference(emb) < root_range[1]
    relative = spectral_assignments(pos, emb, edges, levels=2, stop=SpectralStop(0.3, 0.001, relative=True), top=1)
    assert partition(relative[0]) == partition(family)
    assert len(partition(relative[1])) == 1
    absolute = spectral_assignments(pos, emb, edges, levels=2, stop=SpectralStop(0.45, 0.0))
    assert len(partition(absolute[0])) == (1 if base == 1.0 else 2)
