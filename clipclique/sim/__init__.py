"""The simulation room: everything synthetic, kept out of the real path.

- `demo`: the generated scenes (`DEMO_SCENES`), rendered into ordinary ScanNet and TUM RGB-D
  folders by `ensure_scene` (from `procedural` rooms, the real-data-shaped `scenes`, `render`);
  `scene_detector` says which simulated detector a generated scene is localized with.
- `detectors`: the simulated detectors; `encoder`: the simulated CLIP.
- `synthetic`: small random maps and queries with known ground truth, for tests and benchmarks;
  `poses`: a camera looking at a point (`look_at`), a uniformly random rotation.

The dataset readers (clipclique.datasets) never import this package; it writes their layouts.
"""

from clipclique.sim.demo import DEMO_SCENES, ensure_scene, first_use_notice, scene_detector

__all__ = ["DEMO_SCENES", "ensure_scene", "first_use_notice", "scene_detector"]
