import argparse

import pytest

pytest.importorskip("torch")
pytest.importorskip("diffusers")


def _parser():
    from geoface.cli.ddpm import register
    p = argparse.ArgumentParser()
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS)
    sub = p.add_subparsers(dest="command")
    register(sub, common)
    return p


def test_cli_train_sample_end_to_end(gimage_dataset, tmp_path, capsys):
    p = _parser()
    run, out = tmp_path / "run", tmp_path / "samples"
    a = p.parse_args(["ddpm", "train", str(gimage_dataset), "-o", str(run), "--res", "8", "--steps", "2",
                      "--batch", "2", "--text-encoder", "hash:8", "--tiny", "-q", "--lr", "1e-3"])
    assert a.func(a) == 0
    assert (run / "checkpoint" / "model.safetensors").is_file()
    a = p.parse_args(["ddpm", "sample", str(run), "a smiling female", "-n", "2", "--steps", "2",
                      "--sampler", "ddim", "--seed", "1", "-o", str(out), "-q"])
    capsys.readouterr()
    assert a.func(a) == 0
    # two training steps: noise, and each sample says so (and the last line counts them)
    lines = capsys.readouterr().out.splitlines()
    assert all("NOT a valid surface (" in ln for ln in lines[:2]), lines
    assert lines[-1].startswith("0 of 2 samples are valid surfaces") and "trained 2 steps" in lines[-1]
    import json
    assert json.loads((out / "sample_000" / "meta.json").read_text())["validity"]["valid"] is False
    for k in range(2):
        assert (out / f"sample_{k:03d}" / "meta.json").is_file()
    from geoface.gimage import load_gimage
    gi = load_gimage(out / "sample_000")
    assert gi.image.shape == (9, 8, 8)


def test_cli_errors(tmp_path):
    from geoface import GeofaceError
    p = _parser()
    a = p.parse_args(["ddpm", "sample", str(tmp_path), "x", "-o", str(tmp_path / "o")])
    with pytest.raises(GeofaceError):
        a.func(a)
    a = p.parse_args(["ddpm", "train", str(tmp_path / "none"), "-o", str(tmp_path / "r"), "--text-encoder", "hash"])
    with pytest.raises(GeofaceError):
        a.func(a)
