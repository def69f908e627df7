import numpy as np

from clipclique.sim.synthetic import duplicate_rooms, synthetic_map, synthetic_query


def test_query_is_the_map_seen_from_the_returned_pose():
    map = synthetic_map(np.random.default_rng(0), num_landmarks=30)
    observations, pose = synthetic_query(map, np.random.default_rng(1), num_visible=8, num_outliers=2, center_noise=0.0)
    true = observations.instance_ids >= 0
    landmarks = np.searchsorted(map.instance_ids, observations.instance_ids[true])
    np.testing.assert_allclose(pose.apply(observations.ellipsoids.centers[true]), map.ellipsoids.centers[landmarks])
    assert (observations.class_ids[true] == map.class_ids[landmarks]).all()
    assert (observations.ellipsoids.axes[true] <= map.ellipsoids.axes[landmarks]).all()
    assert np.count_nonzero(~true) == 2
    np.testing.assert_allclose(np.linalg.norm(observations.image_embeddings, axis=1), 1.0, rtol=1e-6)


def test_duplicated_rooms_are_shifted_copies_with_new_instance_ids():
    map = synthetic_map(np.random.default_rng(0), num_landmarks=10)
    rooms = duplicate_rooms(map, 3, gap=2.0)
    assert len(rooms) == 30 and len(np.unique(rooms.instance_ids)) == 30
    shift = rooms.ellipsoids.centers[10:20] - map.ellipsoids.centers
    np.testing.assert_allclose(shift, np.tile([np.ptp(map.ellipsoids.centers[:, 0]) + 2.0, 0, 0], (10, 1)))
    np.testing.assert_array_equal(rooms.class_ids[20:], map.class_ids)
    np.testing.assert_array_equal(rooms.text_embeddings[20:], map.text_embeddings)


def test_a_map_smaller_than_the_view_is_seen_whole():
    map = synthetic_map(np.random.default_rng(0), num_landmarks=5)
    observations, _ = synthetic_query(map, np.random.default_rng(1), num_visible=10, num_outliers=2)
    assert len(observations) == 7 and observations.image_embeddings.shape == (7, 32)
    assert sorted(observations.instance_ids[:5]) == sorted(map.instance_ids)
    np.testing.assert_array_equal(observations.detection_index, np.arange(7))
