"""Write the consumer notebooks (03 DDPM, 04 splats and a talking avatar, 05 skin textures).

The notebooks are generated from the cells below so that their text and code stay reviewable
in one place; ``make notebooks`` then executes every notebook and stores its outputs.

    python data_tools/make_notebooks.py            # (re)write notebooks/03..05 without outputs
"""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"

SHOW = '''

def show(img, width=None):
    """Show an (H, W, 3) picture: uint8, or float in [0, 1]."""
    import cv2
    if img.dtype != np.uint8:
        img = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
    ok, png = cv2.imencode(".png", np.ascontiguousarray(img[:, :, ::-1]))
    display(Image(data=png.tobytes(), width=width))'''

DDPM = [
    new_markdown_cell("""# Heads from text: the DDPM on real heads, at toy size

geoface's diffusion model generates heads as **geometry images**: a UNet denoises the stacked
position and normal images, conditioned on a sentence. This notebook runs the whole loop at a size
that finishes in a minute on a laptop CPU:

1. **data** — real heads from the ICT-FaceKit morphable model, with expressions and prompts measured
   from the geometry, converted to geometry images (`geoface.dataset.build_ict_dataset`)
2. **train** — a `tiny` UNet for a few dozen steps (`geoface.ddpm.model.train`)
3. **sample** — draw heads for a prompt, decode them to geometry images and meshes, judge them

A model this small, trained this briefly, draws noise: the point here is the API. The measured
results of the real run (1,000 identities, 64², the `small` model) are in `docs/ddpm.md`; the same
steps from the command line are `geoface dataset ict`, `geoface ddpm train` and `geoface ddpm sample`."""),
    new_code_cell("""# parameters
HEADS = 6            # ICT heads in the dataset (the real run uses 1,250)
RES = 16             # geometry-image resolution (the real runs: 32 and 64)
STEPS = 60           # training steps (the real runs: thousands)
SAMPLES = 4          # samples drawn for the prompt
TEXT = "hash:32"     # text encoder: "minilm" (the default, offline) or a hashing encoder for speed"""),
    new_code_cell("""import tempfile
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from IPython.display import Image, display

warnings.filterwarnings("ignore", message="IProgress not found")  # tqdm inside a notebook without ipywidgets
WORK = Path(tempfile.mkdtemp(prefix="geoface_ddpm_nb_"))""" + SHOW),
    new_markdown_cell("""## 1. A labelled dataset of real heads

Identities are drawn from N(0, I) over the model's 100 modes; expressions come from named presets
(smiling, mouth open, an eye closed, pouting, …) and random sparse ARKit mixes. Each head goes
through the converter (repair → Ricci flow → optimal transport with the face magnified) and gets a
prompt; the manifest keeps the labels and an identity-level train/held-out split."""),
    new_code_cell("""from geoface.dataset import DatasetOptions, build_ict_dataset, read_manifest

data = WORK / "ict"
build_ict_dataset(data, HEADS, DatasetOptions(res=RES, augment=1), workers=1, quiet=True)
rows = list(read_manifest(data).values())
for r in rows:
    print(f"{r['item']:<16} {r['labels']['split']:<8} {r['prompt']}")"""),
    new_code_cell("""from geoface.gimage import load_gimage

fig, ax = plt.subplots(2, len(rows), figsize=(2 * len(rows), 4.4))
for k, r in enumerate(rows):
    gi = load_gimage(data / r["item"])
    ax[0, k].imshow(np.moveaxis(gi.image[:3], 0, -1)); ax[0, k].set_title(r["labels"]["expression_name"], fontsize=8)
    ax[1, k].imshow(np.moveaxis(gi.image[3:6], 0, -1))
for a in ax.ravel():
    a.axis("off")
fig.suptitle("position (top) and normal (bottom) images"); plt.show()"""),
    new_markdown_cell("""## 2. Train

`DDPMConfig.preset` names the model sizes (`tiny` here; `small`, 5.9 M parameters, is the command
line's default). Items are read lazily; positions are normalised once for the whole dataset and the
frame is stored with the checkpoint, so samples decode to centimetres."""),
    new_code_cell("""from geoface.ddpm.model import DDPMConfig, train

cfg = DDPMConfig.preset("tiny", res=RES, text_encoder=TEXT, batch_size=4, steps=STEPS, checkpoint_every=STEPS)
last = train(data, WORK / "run", cfg, quiet=True)
print(f"{last['step']} steps, loss {last['loss']:.3f} ({last['steps_per_second']:.1f} steps/s)")"""),
    new_markdown_cell("""## 3. Sample, decode, judge

`sample` runs DDIM with classifier-free guidance; `to_geometry_images` decodes the samples in the
dataset's frame; `mesh_validity` rebuilds each one as a mesh and checks that it is one clean disk,
as real items are. (Expect invalid samples from a model trained for a minute.)"""),
    new_code_cell("""from geoface.ddpm.model import load_run, sample, to_geometry_images
from geoface.ddpm.evaluate import mesh_validity

run = load_run(WORK / "run")
x = sample(run, "a smiling face", n=SAMPLES, steps=20, quiet=True)
gis = to_geometry_images(x, run.state)
fig, ax = plt.subplots(1, SAMPLES, figsize=(2 * SAMPLES, 2.3))
for a, g in zip(np.atleast_1d(ax), gis):
    a.imshow(np.moveaxis(g.image[3:6], 0, -1)); a.axis("off")
fig.suptitle('normal images of samples for "a smiling face"'); plt.show()
for k, g in enumerate(gis):
    v = mesh_validity(g)
    print(f"sample {k}: valid {v.valid}" + ("" if v.valid else f" ({v.reason})"))"""),
]

SPLAT = [
    new_markdown_cell("""# Gaussian splats of a real head, and a talking avatar

Two consumers of the geometry in `geoface.splat`, at sizes that run in under a minute on a CPU
(17 s on the 2-core test machine):

1. **fit** — 3D Gaussians fitted to renders of a real ICT-FaceKit head (`fit_mesh`): one Gaussian
   per vertex to start, Adam on L1 + D-SSIM, 3DGS density control; PSNR on held-out views
2. **export** — the Gaussians as a standard 3DGS `.ply` that other splat viewers open
3. **talk** — a THGS talking avatar trained on a short synthetic talking-head video, then
   animated from the audio

The command-line versions are `geoface splat fit`, `geoface talk synth|train|animate`; measured
results at full size are in `docs/splatting.md` and `docs/thgs.md`."""),
    new_code_cell("""# parameters
RES = 96             # image side of the training views (the benchmark: 128)
ITERS = 150          # fitting steps (the benchmark: 1,200)
VERTICES = 3000      # the head decimated to about this many vertices (one Gaussian each to start)
TALK_SECONDS = 2.0   # length of the synthetic talking video
TALK_ITERS = 60      # avatar training steps (the benchmark: 5,000)"""),
    new_code_cell("""import tempfile
from pathlib import Path

import numpy as np
from IPython.display import Image, display

WORK = Path(tempfile.mkdtemp(prefix="geoface_splat_nb_"))""" + SHOW),
    new_markdown_cell("""## 1. Fit Gaussians to a real head

The head is coloured by region so the fit has something to reproduce. `fit_mesh` renders the mesh
from orbit cameras (the ground truth), fits, and keeps a few views out for the held-out PSNR."""),
    new_code_cell("""from geoface.splat.fit import FitConfig, fit_mesh, heldout_images
from geoface.synth.ict import ict_head, load_ict_model

head = ict_head(load_ict_model(), seed=3, expression={"mouthSmile_L": 0.5, "mouthSmile_R": 0.5})
# fewer vertices, fewer Gaussians: a quadric decimation (pymeshlab) to VERTICES
import pymeshlab
from scipy.spatial import cKDTree
ms = pymeshlab.MeshSet()
ms.add_mesh(pymeshlab.Mesh(head.V, head.F))
ms.meshing_decimation_quadric_edge_collapse(targetfacenum=2 * VERTICES, preservenormal=True)
V, F = ms.current_mesh().vertex_matrix(), ms.current_mesh().face_matrix().astype(np.int64)
face = head.face_mask[cKDTree(head.V).query(V)[1]]
colors = np.where(face[:, None], [0.86, 0.62, 0.52], [0.45, 0.33, 0.28])
fit = fit_mesh(V, F, colors, FitConfig(res=RES, iters=ITERS, views=16, heldout=3, seed=0), progress=False)
print(f"{len(V)} vertices; " + fit.summary())"""),
    new_code_cell("""pairs = heldout_images(fit, V, F, colors)
row = np.concatenate([np.concatenate([gt, pred], 0) for gt, pred in pairs[:3]], 1)
print("held-out views: ground truth (top), Gaussians (bottom)")
show(row, width=3 * 2 * RES)"""),
    new_markdown_cell("""## 2. Export

`save_ply` writes the standard 3DGS layout (positions, normals, SH colour, opacity logit, log
scales, rotation quaternion), which splat viewers read."""),
    new_code_cell("""from geoface.splat.ply import load_ply, save_ply

save_ply(fit.gaussians, WORK / "head_gs.ply")
back = load_ply(WORK / "head_gs.ply")
print(f"{len(back.means)} Gaussians, {(WORK / 'head_gs.ply').stat().st_size / 1e6:.1f} MB")"""),
    new_markdown_cell("""## 3. A talking avatar (THGS)

`make_synthetic_talking` writes a short video of the procedural head speaking (frames, audio,
tracked poses that leave the jaw to the audio). `train_thgs` fits the avatar: LBS with a voxel
skinning grid, learnable expression blendshapes, and the spatial audio attention module that moves
the mouth with the sound. `animate` drives it from the audio alone."""),
    new_code_cell("""from geoface.thgs import animate, load_thgs, train_thgs, THGSConfig
from geoface.thgs.eval import evaluate_thgs
from geoface.thgs.data import load_talking, make_synthetic_talking

talk = make_synthetic_talking(WORK / "talk", seconds=TALK_SECONDS, res=64, n_vertices=2000, quiet=True)
train_thgs(talk, WORK / "avatar", THGSConfig(iters=TALK_ITERS, stage_scale=TALK_ITERS / 100_000), progress=False, log=lambda *a: None)
model = load_thgs(WORK / "avatar")
ev = evaluate_thgs(model, load_talking(talk))
print(f"held-out frames {ev['frames']}: PSNR {ev['psnr']:.1f} dB")
print(f"lip sync: r {ev['lipsync_corr']:.2f} between the rendered mouth's opening and the audio's loudness "
      f"(the real frames: r {ev['lipsync_corr_real']:.2f})")"""),
    new_markdown_cell("""Read the lip-sync figure with care here: 2 s of video leave 10 held-out frames, too few
for a correlation to mean anything (the real frames' own value, printed beside it, shows how
noisy it is), and TALK_ITERS steps are too few for the mouth to learn the audio. `docs/thgs.md`
measures it on longer clips after 5,000 steps: r 0.45 for the avatar where the real frames'
own is 0.47 (and −0.09 without the audio attention module)."""),
    new_code_cell("""frames, seconds = animate(model, talk / "audio.wav")
strip = np.concatenate(list(frames[:: max(1, len(frames) // 6)][:6]), 1)
print(f"{len(frames)} frames rendered from the audio, {len(frames) / max(np.sum(seconds), 1e-9):.0f} frames/s; "
      "every few frames, shown 3x (nearest pixel) so that the mouth can be judged")
show(np.repeat(np.repeat(strip, 3, axis=0), 3, axis=1))"""),
]

TEX = [
    new_markdown_cell("""# Skin textures: GDE + HFDR at toy size

The ultra-high-resolution texture model reconstructs albedo, micro-normal and specular maps from
one photo: a Normal&UV predictor, a Global Distribution Extractor (GDE) at low resolution with a
hash encoding of the predicted UV, and a High-Frequency Detail Refiner (HFDR) on full-resolution
patches. This notebook trains it on a handful of procedural skin samples and compares the refined
maps with the upsampled GDE maps (the super-resolution baseline).

The command-line version is `geoface texture synth|train|reconstruct`; measured results at 1K are
in `docs/textures.md`."""),
    new_code_cell("""# parameters
COUNT = 6            # training samples (the benchmark: 48)
RES = 128            # photo side (the benchmark: 1,024)
EPOCHS = 8           # epochs per stage (the benchmark: 100)"""),
    new_code_cell("""import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from IPython.display import Image, display

WORK = Path(tempfile.mkdtemp(prefix="geoface_tex_nb_"))"""),
    new_markdown_cell("""## 1. Data

Each sample is a procedural head with procedural skin (pores, freckles, specular variation) seen
from a near-frontal camera under random lights; the sample stores the photo and the true maps in
image space."""),
    new_code_cell("""from geoface.texture.synth import make_texture_dataset
from geoface.texture.model import load_sample

paths = make_texture_dataset(WORK / "tex", count=COUNT + 1, res=RES, map_res=256, vertices=4000, quiet=True)
train_dir = WORK / "train"; train_dir.mkdir()
for p in paths[:-1]:
    (train_dir / p.name).symlink_to(p)
test = load_sample(paths[-1])
fig, ax = plt.subplots(1, 4, figsize=(12, 3))
for a, (img, title) in zip(ax, [(test["photo"], "photo"), (test["maps"][..., :3], "albedo"),
                                (test["maps"][..., 3:6], "micro-normal"), (test["maps"][..., 6], "specular")]):
    a.imshow(img, cmap="gray"); a.set_title(title); a.axis("off")
plt.show()"""),
    new_markdown_cell("""## 2. Train the three stages

Predictor, then GDE + hash encoding, then HFDR on patches (`k` × `k` per image)."""),
    new_code_cell("""from geoface.texture.model import TextureTrainConfig, train_texture
from geoface.texture.nets import TextureNetConfig

nets = TextureNetConfig(predictor_widths=[8, 16], gde_widths=[8, 16], hfdr_widths=[8, 16], hash_log2_table=12, hash_max_res=128)
cfg = TextureTrainConfig(nets=nets, gde_res=RES // 4, k=2, epochs=(EPOCHS,) * 3, lr=3e-3, batch=2, hfdr_patches=2)
info = train_texture(train_dir, WORK / "model", cfg, quiet=True)
fig, ax = plt.subplots(figsize=(5, 3))
for stage, h in info["history"].items():
    ax.plot(h, label=stage)
ax.set_xlabel("epoch"); ax.set_ylabel("loss"); ax.legend(); plt.show()"""),
    new_markdown_cell("""## 3. Reconstruct a held-out photo

`reconstruct(..., refine=False)` is the baseline (GDE maps upsampled); the full model adds HFDR.
PSNR inside the face mask, against the true maps."""),
    new_code_cell("""from geoface.texture.model import TextureModel, reconstruct
from geoface.splat.fit import psnr

model = TextureModel.load(WORK / "model")
full = reconstruct(model, test["photo"])
base = reconstruct(model, test["photo"], refine=False)
m = test["mask"]
for name, sl in [("albedo", slice(0, 3)), ("micronormal", slice(3, 6)), ("specular", slice(6, 7))]:
    gt = test["maps"][..., sl]
    print(f"{name:<12} GDE upsampled {psnr(base[name], gt, m):5.1f} dB   GDE + HFDR {psnr(full[name], gt, m):5.1f} dB")
fig, ax = plt.subplots(1, 3, figsize=(9, 3))
for a, (img, title) in zip(ax, [(test["maps"][..., :3], "true albedo"), (base["albedo"], "GDE upsampled"), (full["albedo"], "GDE + HFDR")]):
    a.imshow(np.clip(img, 0, 1)); a.set_title(title); a.axis("off")
plt.show()"""),
]


def write(name: str, cells) -> None:
    nb = new_notebook(cells=cells, metadata={"kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
                                             "language_info": {"name": "python"}})
    nbformat.validate(nb)
    nbformat.write(nb, NOTEBOOKS / name)


if __name__ == "__main__":
    write("03_ddpm.ipynb", DDPM)
    write("04_splats_and_avatar.ipynb", SPLAT)
    write("05_skin_textures.ipynb", TEX)
