import json

import numpy as np
import pytest

pytest.importorskip("torch")

from geoface.cli import main  # noqa: E402


def test_synth_train_reconstruct_end_to_end(tmp_path, capsys):
    data, model, out = tmp_path / "data", tmp_path / "model", tmp_path / "out"
    assert main(["texture", "synth", "-o", str(data), "--count", "2", "--res", "64", "--map-res", "128",
                 "--vertices", "3000", "-q"]) == 0
    assert main(["texture", "train", str(data), "-o", str(model), "--gde-res", "32", "--k", "2",
                 "--epochs", "2,2,2", "--batch", "2", "-q"]) == 0
    assert (model / "model.safetensors").is_file() and json.loads((model / "config.json").read_text())["k"] == 2
    import cv2

    from geoface.texture.model import load_sample
    photo = load_sample(data / "sample_0000.npz")["photo"]
    cv2.imwrite(str(tmp_path / "photo.png"), (photo[:, :, ::-1] * 255).astype(np.uint8))
    # with a mesh + camera: the maps also land in the mesh's UV space
    from geoface.mesh.io import save_mesh
    from geoface.synth.surfaces import square_grid
    V, F = square_grid(8, 1.0)
    V = np.asarray(V, float)
    UV = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], axis=0)
    save_mesh(tmp_path / "plane.obj", V=V, F=F, UV=UV)
    cam = {"K": [[60, 0, 32], [0, 60, 32], [0, 0, 1]], "R": np.diag([1.0, -1.0, -1.0]).tolist(), "t": [0, 0, 2]}
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    assert main(["texture", "reconstruct", str(tmp_path / "photo.png"), "--model", str(model),
                 "--mesh", str(tmp_path / "plane.obj"), "--camera", str(tmp_path / "cam.json"),
                 "--uv-size", "64", "-o", str(out), "-q"]) == 0
    for name in ("albedo", "micronormal", "specular", "uv", "normal", "uv_albedo", "uv_specular"):
        img = cv2.imread(str(out / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert img is not None and img.dtype == np.uint16, name
    assert cv2.imread(str(out / "albedo.png"), cv2.IMREAD_UNCHANGED).shape == (64, 64, 3)
    assert cv2.imread(str(out / "uv_albedo.png"), cv2.IMREAD_UNCHANGED).shape == (64, 64, 3)
    assert "UV maps 64²" in capsys.readouterr().out
    # a camera that sees nothing: one-line error, no output folder
    cam["t"] = [0, 0, -2]
    (tmp_path / "away.json").write_text(json.dumps(cam))
    assert main(["texture", "reconstruct", str(tmp_path / "photo.png"), "--model", str(model),
                 "--mesh", str(tmp_path / "plane.obj"), "--camera", str(tmp_path / "away.json"),
                 "--uv-size", "64", "-o", str(tmp_path / "out2"), "-q"]) == 2
    assert "sees none" in capsys.readouterr().err and not (tmp_path / "out2").exists()
    # no mesh, no camera: 68 landmarks of the photo; the ICT head is fitted and takes the maps
    from geoface.synth.ict import load_ict_model
    from geoface.synth.ict_fit import project
    ict = load_ict_model()
    R, f = np.diag([1.0, -1.0, -1.0]), 150.0
    L = project(ict.neutral[ict.landmarks], R, [0, 0, 60.0], f, (32, 32))  # the mean face, 64 px photo
    (tmp_path / "lm.json").write_text(json.dumps({"image_size": [64, 64], "landmarks": L.tolist()}))
    out3 = tmp_path / "out3"
    assert main(["texture", "reconstruct", str(tmp_path / "photo.png"), "--model", str(model), "--landmarks",
                 str(tmp_path / "lm.json"), "--focal", "150", "--uv-size", "64", "-o", str(out3), "-q"]) == 0
    assert "ICT head fitted to the landmarks" in capsys.readouterr().out
    uv = cv2.imread(str(out3 / "uv_albedo.png"), cv2.IMREAD_UNCHANGED)
    assert uv.shape == (64, 64, 3) and uv.std() > 0
    assert main(["texture", "reconstruct", str(tmp_path / "photo.png"), "--model", str(model), "--landmarks",
                 str(tmp_path / "lm.json"), "--mesh", str(tmp_path / "plane.obj"), "--camera", str(tmp_path / "cam.json"),
                 "-o", str(tmp_path / "out4"), "-q"]) == 2
    (tmp_path / "lm2.json").write_text(json.dumps({"image_size": [128, 64], "landmarks": L.tolist()}))
    assert main(["texture", "reconstruct", str(tmp_path / "photo.png"), "--model", str(model), "--landmarks",
                 str(tmp_path / "lm2.json"), "-o", str(tmp_path / "out5"), "-q"]) == 2
    assert "written for a 128x64 image" in capsys.readouterr().err
    # the same as one library call: what the command wrote is what reconstruct_textures returns
    from geoface.camera import Camera
    from geoface.images import read_image
    from geoface.texture import TextureModel, reconstruct_textures
    from geoface.mesh.io import load_mesh

    cam = {"K": [[60, 0, 32], [0, 60, 32], [0, 0, 1]], "R": np.diag([1.0, -1.0, -1.0]), "t": [0, 0, 2]}
    rec = reconstruct_textures(TextureModel.load(model), read_image(tmp_path / "photo.png"), mesh=load_mesh(tmp_path / "plane.obj"),
                               camera=Camera.from_K(cam["K"], cam["R"], cam["t"]), uv_size=64)
    assert 0 < rec.coverage <= 1 and rec.fit is None and set(rec.uv_maps) == {"albedo", "micronormal", "specular"}
    assert np.abs(rec.uv_maps["albedo"] - read_image(out / "uv_albedo.png")).max() < 1e-3
    # a real photo alone (skimage's astronaut): MediaPipe finds the 68 landmarks, the ICT head is fitted
    pytest.importorskip("mediapipe")
    from skimage import data

    save_image = __import__("geoface.images", fromlist=["save_image"]).save_image
    save_image(tmp_path / "astronaut.png", cv2.resize(data.astronaut(), (256, 256), interpolation=cv2.INTER_AREA))
    out6 = tmp_path / "out6"
    assert main(["texture", "reconstruct", str(tmp_path / "astronaut.png"), "--model", str(model), "--track",
                 "--uv-size", "64", "-o", str(out6), "-q"]) == 0
    msg = capsys.readouterr().out
    assert "ICT head fitted to the landmarks" in msg and float(msg.split("RMS ")[1].split(" px")[0]) < 3.0
    assert read_image(out6 / "uv_albedo.png").shape == (64, 64, 3)
    assert main(["texture", "reconstruct", str(tmp_path / "astronaut.png"), "--model", str(model), "--track",
                 "--landmarks", str(tmp_path / "lm.json"), "-o", str(tmp_path / "out7"), "-q"]) == 2


@pytest.mark.parametrize("argv,msg", [
    (["texture", "reconstruct", "{tmp}/in/missing.png", "--model", "{tmp}/in", "-o", "{tmp}/o"], "no such file"),
    (["texture", "train", "{tmp}/in", "-o", "{tmp}/m", "--epochs", "3,3"], "--epochs"),
    (["texture", "train", "{tmp}/in", "-o", "{tmp}/m"], "no *.npz"),
    (["texture", "train", "{tmp}/in", "-o", "{tmp}/in/m"], "inside the input folder"),
    (["texture", "train", "{tmp}/in", "-o", "{tmp}/m", "--map-weights", "1,4"], "--map-weights"),
    (["texture", "train", "{tmp}/in", "-o", "{tmp}/m", "--init", "{tmp}/in"], "config.json is missing"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, msg):
    (tmp_path / "in").mkdir()
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_corrupt_model_is_one_line_exit_2(tmp_path, capsys):
    import cv2
    cv2.imwrite(str(tmp_path / "p.png"), np.zeros((64, 64, 3), np.uint8))
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "config.json").write_text("{not json")
    assert main(["texture", "reconstruct", str(tmp_path / "p.png"), "--model", str(tmp_path / "m"),
                 "-o", str(tmp_path / "o")]) == 2
    assert "corrupt" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_model_saved_over_a_link_replaces_the_link_and_leaves_no_temporary(tmp_path):
    """``texture train -o LINK --force`` trained, then failed on "Cannot call rmtree on a symbolic
    link" and left ``.LINK.tmp/``: the link itself is replaced (its target untouched), nothing left."""
    from geoface.texture.model import TextureModel, TextureTrainConfig

    target = tmp_path / "theirs"
    target.mkdir()
    (target / "keep.txt").write_text("mine")
    link = tmp_path / "m2"
    link.symlink_to(target)
    TextureModel(TextureTrainConfig()).save(link)
    assert not link.is_symlink() and (link / "model.safetensors").is_file()
    assert (target / "keep.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["m2", "theirs"]


def test_an_unknown_key_in_a_texture_models_config_is_refused(tmp_path):
    """A key the config does not have (a typo, another model's file) once loaded silently."""
    from geoface.errors import CheckpointError
    from geoface.texture.model import TextureModel, TextureTrainConfig

    d = tmp_path / "m"
    TextureModel(TextureTrainConfig()).save(d)
    assert TextureModel.load(d) is not None
    cfg = json.loads((d / "config.json").read_text())
    for bad in (dict(cfg, lerning_rate=0.1), dict(cfg, nets=dict(cfg["nets"], widths=[1]))):
        (d / "config.json").write_text(json.dumps(bad))
        with pytest.raises(CheckpointError, match="unknown fields"):
            TextureModel.load(d)
