"""The SASA shared-inference benchmark (benchmarks/sasa_shared_inference.py): two tiny trained models
on two dev scenes, one process per model against one process for both; the detections must be the
same both ways, and the test split is refused."""

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))
sys.path.insert(0, str(REPO / "tests"))

from sasa_shared_inference import main  # noqa: E402
from test_sasa_model import TINY, make_scene  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_one_process_per_model_and_one_for_all_give_the_same_detections(tmp_path, capsys):
    from sonardet.detect.sasa import train

    results = tmp_path / "results"
    (results / "scenes").mkdir(parents=True)
    paths = [make_scene(results / "scenes", f"s010{i}", 20 + i, ["reef_ring", "tetrapod_s"]) for i in range(2)]
    (results / "splits").mkdir()
    (results / "splits" / "dev.txt").write_text("s0100\ns0101\n")
    models = []
    for seed in (1, 2):
        train(paths, [], {**TINY, "epochs": 1, "batch_size": 1, "seed": seed, "score_thresh": 0.0},
              tmp_path / f"m{seed}", resume=False)
        models.append(str(tmp_path / f"m{seed}" / "model.pt"))
    assert main(["--results", str(results), "--models", *models, "--repeat", "1", "--scenes", "2"]) == 0
    out = capsys.readouterr().out
    assert "detections: the same both ways" in out and "2 models, 2 dev scenes" in out
    with pytest.raises(SystemExit):  # the test split is not a choice
        main(["--results", str(results), "--models", *models, "--dataset", "test"])
