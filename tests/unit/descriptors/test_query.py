"""The query side's descriptor and similarity stages (clipclique.descriptors.query) read the map's index through
`MapSide`: the pipeline's `MapIndex` holds every field it names."""

import dataclasses
import typing

import numpy as np

from clipclique.config import make_config
from clipclique.descriptors import query
from clipclique.pipeline import MapIndex, index_map
from clipclique.sim.synthetic import synthetic_map, synthetic_query


def test_the_map_index_is_a_map_side():
    fields = {field.name for field in dataclasses.fields(MapIndex)}
    assert set(typing.get_type_hints(query.MapSide)) <= fields


def test_fused_similarity_is_sh_alone_without_clip_embeddings():
    rng = np.random.default_rng(6)
    map = synthetic_map(rng, num_landmarks=20)
    observations, _ = synthetic_query(map, rng)
    config = make_config("clipclique")
    index = index_map(map, config)
    histograms, walks = query.descriptors(observations, index, config)
    fused, notes = query.scores(observations, index, histograms, walks, config)
    assert notes == [] and fused.shape == (len(observations), len(map))
    observations.image_embeddings = None
    sh, notes = query.scores(observations, index, histograms, walks, config)
    assert notes == ["no CLIP embeddings (the observations have no image embeddings): alpha = 0 (SH only)"]
    assert not np.allclose(sh, fused)
