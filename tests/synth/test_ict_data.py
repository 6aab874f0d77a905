"""Labelled real-head datasets: specs, prompts from measured traits, the identity split, and
`geoface dataset ict` end to end."""
import json

import numpy as np
import pytest

from geoface.errors import GeofaceError
from geoface.synth.ict import load_ict_model
from geoface.synth.ict_data import PRESETS, describe_blendshapes, head_from_spec, ict_specs, measure_traits


@pytest.fixture(scope="module")
def model():
    return load_ict_model()


def test_specs_are_deterministic_labelled_and_split_by_identity(model):
    a = ict_specs(300, seed=4, model=model)
    assert a == ict_specs(300, seed=4, model=model)
    assert a != ict_specs(300, seed=5, model=model)
    names = [s["labels"]["expression_name"] for s in a]
    mix = sum(n == "mix" for n in names) / len(names)
    assert 0.2 < mix < 0.4  # mix_share 0.3
    assert set(names) - {"mix"} <= set(PRESETS) and len(set(names)) >= 10
    held = [s for s in a if s["labels"]["split"] == "heldout"]
    assert len(held) == 60  # 20 % of the identities, one head each
    ids = np.array([s["identity"] for s in a])
    assert ids.shape == (300, 100) and abs(ids.mean()) < 0.02 and abs(ids.std() - 1) < 0.02  # N(0, I)
    for s in a:
        lab = s["labels"]
        if lab["expression_name"] == "mix":
            assert 1 <= len(s["expression"]) <= 3 and "mouthClose" not in s["expression"]
            assert lab["prompt"].startswith(describe_blendshapes(s["expression"]))
        else:
            want = PRESETS[lab["expression_name"]]
            assert lab["prompt"].startswith(want[1]) and set(s["expression"]) == set(want[0])
            scale = {round(s["expression"][k] / w, 3) for k, w in want[0].items() if w * 1.0 <= 1.0 and s["expression"][k] < 1}
            assert all(0.59 <= x <= 1.001 for x in scale)  # one intensity in [0.6, 1] for the whole preset


def test_traits_are_measured_terciles(model):
    specs = ict_specs(150, seed=1, model=model)
    ids = np.array([s["identity"] for s in specs])
    vals = measure_traits(model, ids)
    # the measurement is the landmark distance on the neutral head of that identity
    h = model.head(ids[7])
    lm = h.V[h.landmarks]
    assert vals["face_width"][7] == pytest.approx(np.linalg.norm(lm[0] - lm[16]), rel=1e-5)
    assert vals["nose_length"][7] == pytest.approx(np.linalg.norm(lm[27] - lm[33]), rel=1e-5)
    for name, words in (("face_width", ("narrow", "wide")), ("nose_length", ("short nose", "long nose"))):
        t = [s["labels"]["traits"][name]["tercile"] for s in specs]
        assert 40 <= t.count("low") <= 60 and 40 <= t.count("high") <= 60
        cm = np.array([s["labels"]["traits"][name]["cm"] for s in specs])
        lows = cm[[x == "low" for x in t]]
        highs = cm[[x == "high" for x in t]]
        assert lows.max() < highs.min()
        said = 0
        for s in specs:  # a word is said only for its tercile, never guessed
            lab = s["labels"]
            traits = lab["prompt"][len(lab["expression_words"]) + 2:]
            tt = lab["traits"][name]["tercile"]
            said += bool(traits)
            if words[1] in traits:
                assert tt == "high"
            if words[0] in traits:
                assert tt == "low"
        assert 40 < said < 110  # about half the prompts (traits_share 0.5; middle terciles say nothing)


def test_describe_blendshapes_words():
    assert describe_blendshapes({}) == "a neutral expression"
    assert describe_blendshapes({"eyeBlink_L": 0.9}) == "left eye closed"
    assert describe_blendshapes({"jawOpen": 0.3}) == "mouth slightly open"
    assert describe_blendshapes({"eyeBlink_R": 0.8, "noseSneer_L": 0.6}) == "right eye closed and nose sneering on the left side"


def test_head_from_spec_is_the_model_head(model):
    s = ict_specs(2, seed=0, model=model)[1]
    h = head_from_spec(s, model)
    assert np.array_equal(h.V, model.head(np.asarray(s["identity"]), s["expression"]).V)
    with pytest.raises(GeofaceError):
        ict_specs(0, model=model)
    with pytest.raises(GeofaceError):
        ict_specs(3, model=model, presets=["laughing"])


def test_dataset_ict_builds_resumes_and_records_labels(tmp_path):
    from geoface.cli import main

    out = tmp_path / "ict"
    args = ["dataset", "ict", "-o", str(out), "--count", "2", "--res", "16", "--augment", "1", "--workers", "1", "-q"]
    assert main(args) == 0
    rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows)
    heads = [json.loads(x) for x in (out / "heads.jsonl").read_text().splitlines()]
    assert [h["name"] for h in heads] == ["ict_0000", "ict_0001"]
    for r in rows:
        lab = r["labels"]
        assert r["prompt"] == lab["prompt"] and lab["split"] in ("train", "heldout") and lab["expression_name"]
        assert len(r["bbox"]["min"]) == 3 and 20 < r["bbox"]["max"][1] - r["bbox"]["min"][1] < 50  # cm, a head
        meta = json.loads((out / r["item"] / "meta.json").read_text())
        assert meta["bbox_min"] == r["bbox"]["min"] and meta["channels"] == ["px", "py", "pz", "nx", "ny", "nz"]
        assert r["metrics"]["roi_vertices"] == 9409  # the model's face area is the ROI
    before = (out / "manifest.jsonl").read_text()
    assert main(args) == 0 and (out / "manifest.jsonl").read_text() == before  # resumed: nothing to do
    assert main([*args[:5], "1", *args[6:]]) == 2  # another source (count) is refused ...
    assert main([*args[:5], "1", *args[6:], "--force"]) == 0  # ... unless rebuilt
    rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert [r["item"] for r in rows] == [rows[0]["item"]]  # a fresh manifest: no row of the old build
