"""The source study's published figures, in one place (every report table that sets our numbers
beside the study's reads them from here).

Synthetic test scenes (the study's results section): mAP@0.5 m of SASA trained on 100 / 50 / 25 %
of its 80 training scenes and of its model-based pipeline, their per-class APs (ring, cone,
tetrapod_b, tetrapod_s: SASA 0.98 / 0.99 / 0.98 / 0.96, model-based 0.98 / 0.98 / 0.97 / 0.97) and
numbers of predictions; its dataset (100 scenes, 80 train / 20 test, 5491 objects: 4518 in training,
973 in test scenes). Real Baltic Sea sonar (Nienhagen reef): the model-based pipeline 0.83 mAP,
SASA 0.40 (domain shift).
"""

from __future__ import annotations

#: Synthetic test scenes. Values the study does not report stay out.
STUDY = {
    "comparison": {
        "SASA (study)": {"mAP": 0.98, "predictions": 991,
                         "AP": {"reef_ring": 0.98, "reef_cone": 0.99, "tetrapod_b": 0.98, "tetrapod_s": 0.96}},
        "model-based (study)": {"mAP": 0.97, "predictions": 957,
                                "AP": {"reef_ring": 0.98, "reef_cone": 0.98, "tetrapod_b": 0.97, "tetrapod_s": 0.97}},
    },
    "sasa_fraction_mAP": {25: 0.96, 50: 0.97, 100: 0.98},
    "model_based_mAP": 0.97,
    "dataset": {"scenes": {"train": 80, "test": 20, "all": 100}, "objects": {"train": 4518, "test": 973, "all": 5491}},
}

def study_map(family: str, fraction: int | None):
    """The study's synthetic-test mAP@0.5 m of a method family at a training fraction (%), or NaN
    when the study reports none (families: 'model_based', 'sasa')."""
    if family == "model_based":
        return STUDY["model_based_mAP"]
    if family == "sasa" and fraction is not None:
        return STUDY["sasa_fraction_mAP"].get(int(fraction), float("nan"))
    return float("nan")


#: Real Baltic Sea sonar (not our test sets: shown for reference beside the realism and hybrid sets).
STUDY_REAL_SONAR = {
    "model-based (study, real sonar)": 0.83,
    "SASA (study, real sonar)": 0.40,
}

STUDY_SOURCE = "source study"
