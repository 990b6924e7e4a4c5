"""Cross-validation of Table I: folds partition the paper pool; the merged table scores every
scene once."""

import json
import sys

from conftest import REPO_ROOT

sys.path.insert(0, str(REPO_ROOT))

from calibration.crossval import MODELS, fold_pool, merge  # noqa: E402

POOL = json.loads((REPO_ROOT / "scenarios" / "data" / "hbs-paper.json").read_text())


def test_every_scene_is_held_out_in_exactly_one_fold():
    folds = 5
    held_out = []
    for f in range(folds):
        pool = fold_pool(POOL, folds, f)
        assert [s["name"] for s in pool["scenarios"]] == [s["name"] for s in POOL["scenarios"]]
        test = [s["name"] for s in pool["scenarios"] if s["split"] == "test"]
        assert 0 < len(test) < len(POOL["scenarios"])
        held_out += test
    assert sorted(held_out) == sorted(s["name"] for s in POOL["scenarios"])


def test_the_merged_table_averages_over_all_held_out_scenes():
    def table(scores):
        return {
            "models": {
                m: {"scenarios": [dict(name=n, ade=a, fde=2 * a, collided=c) for n, a, c in scores]}
                for m in MODELS
            }
        }

    merged = merge([table([("a", 1.0, True)]), table([("b", 3.0, False), ("c", 2.0, False)])])
    for m in MODELS:
        assert merged["models"][m]["episodes"] == 3
        assert merged["models"][m]["ade"] == 2.0
        assert merged["models"][m]["fde"] == 4.0
        assert abs(merged["models"][m]["collision_rate"] - 1 / 3) < 1e-12
