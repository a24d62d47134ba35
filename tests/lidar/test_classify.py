import numpy as np
import pytest

from rooftrace.lidar.classify import ClassifyOptions, cluster_means, kmeans_1d, separate_buildings


def test_cluster_means():
    assert cluster_means(np.array([0, 0, 1, -1]), np.array([1.0, 3.0, 5.0, 100.0])).tolist() == [2.0, 5.0]


def test_kmeans_is_deterministic_and_sorted(rng):
    v = np.concatenate([rng.normal(0.5, 0.05, 30), rng.normal(1.0, 0.03, 20)])
    c1, l1 = kmeans_1d(v)
    c2, l2 = kmeans_1d(v[::-1])
    assert c1 == pytest.approx(c2) and c1[0] < c1[1]
    assert np.array_equal(l1, l2[::-1]) and l1[:30].sum() == 0 and l1[30:].all()


def test_buildings_and_trees_are_split_by_kmeans():
    e = np.array([0.45, 0.5, 0.55, 0.7, 0.98, 1.0, 1.02])
    bld, params = separate_buildings(e, np.zeros(7))
    assert bld.tolist() == [True] * 4 + [False] * 3
    assert params["method"] == "kmeans" and 0.7 < params["entropy_threshold"] < 0.98


@pytest.mark.parametrize("e, expected", [
    (np.array([0.45, 0.5, 0.52, 0.6, 0.62]), True),  # only buildings: k-means would split them
    (np.array([0.97, 1.0, 1.02, 1.05, 1.07]), False),  # only trees
])
def test_one_population_uses_the_fallback_threshold(e, expected):
    bld, params = separate_buildings(e, np.zeros(len(e)))
    assert params["method"] == "fallback"
    assert bld.tolist() == [expected] * len(e)


def test_linear_clusters_are_never_buildings():
    bld, _ = separate_buildings(np.array([0.4, 0.45, 1.0, 1.05]), np.array([0.2, 0.9, 0.3, 0.3]))
    assert bld.tolist() == [True, False, False, False]


def test_options_are_checked():
    with pytest.raises(ValueError, match="entropy_floor"):
        ClassifyOptions(entropy_floor=0.9, fallback_entropy=0.8)
    with pytest.raises(ValueError, match="boundary"):
        ClassifyOptions(boundary="median")
    with pytest.raises(ValueError, match="neighbourhood"):
        ClassifyOptions(neighbourhood="optimal")
    with pytest.raises(ValueError, match="neighbour_step"):
        ClassifyOptions(neighbour_step=0)


def test_cluster_medians_are_the_lower_middle_value_of_each_cluster():
    from rooftrace.lidar.classify import cluster_medians

    rng = np.random.default_rng(13)
    labels = rng.integers(-1, 300, 5000)
    values = np.round(rng.random(5000), 2)  # ties
    got = cluster_medians(labels, values, 302)
    for k in range(302):
        v = np.sort(values[labels == k])
        assert (np.isnan(got[k]) if len(v) == 0 else got[k] == v[(len(v) - 1) // 2]), k
