"""The paper's published figures (CLIP-Clique, Matsuzaki et al., IEEE RA-L 2024), as printed.

Transcribed from docs/PAPER_TABLES.md so every report stands them beside ours. Sequences:
ScanNet scene0002_00 ("0002"), scene0017_00 ("0017") with ground-truth 2D instances; TUM fr2/desk
("fr2"), fr3/long_office_household ("fr3") with YOLOv8-x detections; CLIP ViT-L/14. Rotation
errors are in RADIANS as the paper prints them; precision/recall only on ScanNet (None: not given).
"""

from __future__ import annotations

SEQUENCES = ("0002", "0017", "fr2", "fr3")
NOTE = ("ScanNet 0002/0017 with ground-truth instances, TUM fr2/fr3 with YOLOv8-x detections, real CLIP "
        "ViT-L/14; TE in m, RE in radians as printed; RANSAC/PROSAC best of 3 trials")

# Table I: (P %, R %, TE m, RE rad, SR@1, SR@3, SR@5 %, time s) per sequence and method.
TABLE_ONE: dict[str, dict[str, tuple]] = {
    "0002": {"X-View": (67.1, 30.2, 1.877, 1.413, 36.7, 37.5, 38.7, 1.815),
             "SH": (70.1, 33.7, 1.709, 1.294, 39.8, 40.4, 41.3, 1.743),
             "CLIP-Loc": (37.5, 11.8, 2.379, 1.820, 19.6, 30.0, 36.5, 1.888),
             "CLIP-Clique": (75.9, 36.9, 0.772, 0.806, 72.9, 81.5, 84.1, 0.043)},
    "0017": {"X-View": (65.1, 17.6, 2.244, 1.197, 24.8, 24.8, 25.6, 1.090),
             "SH": (66.9, 18.0, 2.514, 1.317, 22.5, 22.5, 22.5, 1.011),
             "CLIP-Loc": (41.9, 11.6, 2.314, 1.544, 24.8, 38.8, 48.8, 1.125),
             "CLIP-Clique": (62.9, 28.8, 1.270, 1.125, 54.2, 67.1, 71.4, 0.041)},
    "fr2": {"X-View": (None, None, 1.019, 0.800, 50.7, 50.7, 50.7, 0.405),
            "SH": (None, None, 0.888, 0.661, 62.6, 62.6, 62.6, 0.400),
            "CLIP-Loc": (None, None, 0.701, 0.485, 83.2, 92.3, 94.8, 0.631),
            "CLIP-Clique": (None, None, 0.529, 0.320, 91.1, 95.4, 96.5, 0.013)},
    "fr3": {"X-View": (None, None, 1.249, 0.945, 44.9, 44.9, 44.9, 0.714),
            "SH": (None, None, 1.340, 1.013, 43.7, 43.7, 43.7, 0.682),
            "CLIP-Loc": (None, None, 0.882, 0.650, 71.9, 81.0, 84.5, 0.921),
            "CLIP-Clique": (None, None, 0.638, 0.482, 81.0, 86.3, 88.9, 0.042)},
}
TABLE_ONE_COLUMNS = ("P [%]", "R [%]", "TE [m]", "RE [rad]", "Top-1 [%]", "Top-3 [%]", "Top-5 [%]", "Time [s]")

# Ablations: (P %, R %, TE m, RE rad, SR@1 %) per group, sequence and setting (our report's setting labels).
ABLATIONS: dict[str, dict[str, dict[str, tuple]]] = {
    "descriptors": {
        "0002": {"SH": (70.2, 33.6, 0.889, 0.921, 65.3), "CLIP": (37.9, 11.8, 1.433, 1.424, 38.5),
                 "SH + CLIP": (75.9, 36.9, 0.772, 0.806, 72.9)},
        "0017": {"SH": (56.9, 24.5, 1.297, 1.176, 44.9), "CLIP": (41.4, 16.7, 1.745, 1.529, 37.2),
                 "SH + CLIP": (62.9, 28.8, 1.270, 1.125, 54.2)},
        "fr2": {"SH": (None, None, 0.909, 0.654, 68.8), "CLIP": (None, None, 0.628, 0.410, 84.7),
                "SH + CLIP": (None, None, 0.529, 0.320, 91.1)},
        "fr3": {"SH": (None, None, 0.831, 0.662, 73.2), "CLIP": (None, None, 0.870, 0.660, 74.5),
                "SH + CLIP": (None, None, 0.638, 0.482, 81.0)},
    },
    "inliers": {
        "0002": {"RANSAC": (67.6, 18.2, 1.920, 1.454, 37.3), "PROSAC": (74.9, 19.6, 1.865, 1.411, 39.6),
                 "Maximal cliques": (75.9, 36.9, 0.772, 0.806, 72.9)},
        "0017": {"RANSAC": (55.3, 15.4, 1.809, 1.146, 41.1), "PROSAC": (58.5, 16.2, 1.772, 1.102, 44.0),
                 "Maximal cliques": (62.9, 28.8, 1.270, 1.125, 54.2)},
        "fr2": {"RANSAC": (None, None, 0.573, 0.381, 88.9), "PROSAC": (None, None, 0.578, 0.389, 89.3),
                "Maximal cliques": (None, None, 0.529, 0.320, 91.1)},
        "fr3": {"RANSAC": (None, None, 0.758, 0.570, 76.1), "PROSAC": (None, None, 0.776, 0.591, 75.4),
                "Maximal cliques": (None, None, 0.638, 0.482, 81.0)},
    },
    "weights": {
        "0002": {"none": (None, None, 0.802, 0.837, 72.1), "w_sim": (None, None, 0.799, 0.832, 72.2),
                 "w_com": (None, None, 0.778, 0.814, 72.6), "w_sim * w_com": (None, None, 0.772, 0.806, 72.9)},
        "0017": {"none": (None, None, 1.287, 1.131, 54.5), "w_sim": (None, None, 1.283, 1.124, 55.0),
                 "w_com": (None, None, 1.274, 1.131, 54.0), "w_sim * w_com": (None, None, 1.270, 1.125, 54.2)},
        "fr2": {"none": (None, None, 0.545, 0.334, 90.6), "w_sim": (None, None, 0.542, 0.331, 90.9),
                "w_com": (None, None, 0.531, 0.322, 90.9), "w_sim * w_com": (None, None, 0.529, 0.320, 91.1)},
        "fr3": {"none": (None, None, 0.656, 0.485, 79.7), "w_sim": (None, None, 0.649, 0.481, 80.2),
                "w_com": (None, None, 0.644, 0.485, 80.9), "w_sim * w_com": (None, None, 0.638, 0.482, 81.0)},
    },
    "matching": {
        "0002": {"1-to-1": (68.4, 25.0, 0.666, 0.661, 61.5), "kNN (k = 3)": (73.4, 35.7, 0.813, 0.868, 71.3),
                 "Adaptive": (75.9, 36.9, 0.772, 0.806, 72.9)},
        "0017": {"1-to-1": (60.6, 18.7, 1.529, 1.323, 35.2), "kNN (k = 3)": (61.3, 28.3, 1.272, 1.109, 55.2),
                 "Adaptive": (62.9, 28.8, 1.270, 1.125, 54.2)},
        "fr2": {"1-to-1": (None, None, 0.577, 0.364, 86.9), "kNN (k = 3)": (None, None, 0.560, 0.350, 89.5),
                "Adaptive": (None, None, 0.529, 0.320, 91.1)},
        "fr3": {"1-to-1": (None, None, 0.727, 0.560, 76.7), "kNN (k = 3)": (None, None, 0.709, 0.535, 78.3),
                "Adaptive": (None, None, 0.638, 0.482, 81.0)},
    },
}
ABLATION_COLUMNS = ("P [%]", "R [%]", "TE [m]", "RE [rad]", "Top-1 [%]")
