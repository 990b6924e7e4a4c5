"""The paper+general training pool keeps every test scene's recorded agents out of training."""

import json

import pytest

from sharedspace.paper.pools import main, paper_plus_general, record_ids, validation_pool
from sharedspace.pool import DEFAULT_POOL_PATH


def _paper():
    return json.loads(DEFAULT_POOL_PATH.read_text())


def _general_from(paper):
    """A stand-in general pool: each paper scene with one more pedestrian track, plus a scene
    made only of fresh tracks."""
    scenes = []
    for s in paper["scenarios"]:
        extra = dict(s["agents"][-1], record_id=900_000 + len(scenes))
        scenes.append({**s, "agents": [*s["agents"], extra]})
    fresh = dict(paper["scenarios"][0])
    fresh["name"] = "hbs-fresh"
    fresh["agents"] = [dict(a, record_id=800_000 + i) for i, a in enumerate(fresh["agents"])]
    scenes.append(fresh)
    return {"version": paper["version"], "name": "hbs-general", "scenarios": scenes}


def test_no_training_scene_shares_a_recorded_agent_with_a_test_scene():
    paper = _paper()
    pool = paper_plus_general(paper, _general_from(paper))
    test = [s for s in pool["scenarios"] if s["split"] == "test"]
    train = [s for s in pool["scenarios"] if s["split"] == "train"]
    held_out = set().union(*(record_ids(s) for s in test))
    added = [s for s in train if s["name"].startswith("general-")]
    assert added, "the general scenes that share nothing with the test split are added"
    assert all(not (record_ids(s) & held_out) for s in added)
    assert "general-hbs-fresh" in {s["name"] for s in added}


def test_the_test_split_is_exactly_the_papers():
    paper = _paper()
    pool = paper_plus_general(paper, _general_from(paper))
    assert [s for s in pool["scenarios"] if s["split"] == "test"] == [
        s for s in paper["scenarios"] if s["split"] == "test"
    ]
    assert pool["scenarios"][: len(paper["scenarios"])] == paper["scenarios"]
    assert len({s["name"] for s in pool["scenarios"]}) == len(pool["scenarios"])


def test_the_command_writes_a_pool_file(tmp_path):
    general = tmp_path / "general.json"
    general.write_text(json.dumps(_general_from(_paper())))
    out = tmp_path / "pool.json"
    main(["--general", str(general), "--out", str(out)])
    pool = json.loads(out.read_text())
    assert pool["name"] == "hbs-paper-plus-general"
    assert "share no recorded agent" in pool["provenance"]


def test_the_validation_pool_holds_out_train_scenes_and_never_the_test_split(tmp_path):
    paper = _paper()
    pool = validation_pool(paper, 12, seed=0)
    train = {s["name"] for s in paper["scenarios"] if s["split"] == "train"}
    val = [s["name"] for s in pool["scenarios"] if s["split"] == "test"]
    kept = [s["name"] for s in pool["scenarios"] if s["split"] == "train"]
    assert len(val) == 12 and len(kept) == len(train) - 12
    assert set(val) | set(kept) == train, "exactly the paper's train scenes, none of its test"
    assert validation_pool(paper, 12, seed=0) == pool, "a fixed seed, a fixed split"
    assert validation_pool(paper, 12, seed=1) != pool
    out = tmp_path / "val.json"
    main(["--validation", "12", "--out", str(out)])
    assert json.loads(out.read_text()) == pool
    with pytest.raises(ValueError, match="between 1 and"):
        validation_pool(paper, len(train))
    assert pool["name"] == f"{paper['name']}-validation"


def test_the_validation_pool_keeps_the_worlds_vehicle_model():
    paper = {**_paper(), "vehicle_model": "idm"}
    assert validation_pool(paper, 12)["vehicle_model"] == "idm", "its cars react as the test's do"


def test_one_pool_reader_lists_a_file_a_document_a_list_and_leaves_a_name_to_the_server():
    from sharedspace.pool import listed_scenarios

    paper = _paper()
    expected = [(s["name"], s["split"]) for s in paper["scenarios"]]
    assert listed_scenarios(DEFAULT_POOL_PATH) == ("hbs-paper", expected)
    assert listed_scenarios(str(DEFAULT_POOL_PATH)) == ("hbs-paper", expected)
    assert listed_scenarios(paper) == ("hbs-paper", expected)
    assert listed_scenarios(paper["scenarios"][:2]) == (None, expected[:2])
    assert listed_scenarios("hbs-general") == ("hbs-general", None)
    assert listed_scenarios(None) == (None, None)
