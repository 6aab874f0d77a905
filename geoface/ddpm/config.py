"""The hyper-parameters of a text-guided DDPM run (:mod:`geoface.ddpm.model`): :class:`DDPMConfig`,
checked on construction and saved as the checkpoint's ``config.json``, and the named model
sizes (:data:`PRESETS`)."""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

from .._io import atomic_write_text
from ..errors import CheckpointError


PREDICTIONS = ("epsilon", "v_prediction", "sample")


@dataclass
class DDPMConfig:
    """All hyper-parameters of a run; saved as ``config.json``."""
    res: int = 64
    channels: int = 9
    block_out_channels: tuple = (64, 128, 256)
    layers_per_block: int = 2
    attention_head_dim: int = 8
    norm_num_groups: int = 32
    # levels (0 = full resolution) whose down/up blocks have cross-attention; None = all but the
    # coarsest (the original layout).  Self-attention at 64x64 costs 4096^2 per head: on a CPU
    # use e.g. (2, 3) with four levels.  The middle block always has cross-attention.
    attention_levels: tuple | None = None
    text_encoder: str = "minilm"       # minilm | clip:PATH | hash[:DIM]
    text_max_length: int = 32
    cross_attention_dim: int = 384     # = text encoder dim (filled in at train time)
    num_train_timesteps: int = 1000
    cfg_dropout: float = 0.1
    lr: float = 1e-4
    weight_decay: float = 1e-2
    ema_decay: float = 0.999
    batch_size: int = 8
    steps: int = 10000
    checkpoint_every: int = 500
    augment: bool = True
    seed: int = 0
    # the stacked modalities (channels = 3 per modality); a dataset without texture trains on
    # position + normal (6 channels)
    modalities: tuple[str, ...] = ("position", "normal", "texture")
    # denoise (x - mean image) / std per modality (module docs); configs written before this
    # option existed load with False
    standardize: bool = True
    # what the UNet predicts: "epsilon" (the paper), "v_prediction" or "sample" (x0)
    prediction: str = "epsilon"
    # the UNet sees ``patch x patch`` pixel blocks folded into channels (pixel unshuffle): a 64²
    # image is denoised by a 32² network with 4x the channels (simple diffusion's patching)
    patch: int = 1
    # noise-schedule shift (simple diffusion): the cosine schedule's log-SNR lowered by
    # 2 log(shift), so that a 64² image is as noisy at step t as a 32² one with shift 2
    schedule_shift: float = 1.0
    # standardise by one spread per modality and pixel (DataStats) instead of one per modality
    stats_per_pixel: bool = False
    # "constant", or "cosine": the learning rate falls from lr to lr/10 over ``steps``
    lr_schedule: str = "constant"

    def __post_init__(self):
        from geoface.nn.config import check_ranges

        def need(ok, what, value):
            if not ok:
                raise CheckpointError(f"{what}; got {value!r}")

        check_ranges(self, ints={"res": (4, 8192), "channels": (1, 4096), "layers_per_block": (1, 64),
                                 "attention_head_dim": (1, 4096), "norm_num_groups": (1, 4096),
                                 "text_max_length": (1, 4096), "cross_attention_dim": (1, 65536),
                                 "num_train_timesteps": (2, 1_000_000), "batch_size": (1, 1 << 20),
                                 "steps": (0, 1 << 40), "checkpoint_every": (1, 1 << 40)},
                     reals={"cfg_dropout": (0.0, 1.0, False, False), "lr": (0.0, 10.0, True, False),
                            "weight_decay": (0.0, 100.0, False, False), "ema_decay": (0.0, 1.0, False, True)})
        boc = self.block_out_channels
        need(isinstance(boc, (tuple, list)) and 1 <= len(boc) <= 12
             and all(isinstance(c, int) and not isinstance(c, bool) and 1 <= c <= 65536 for c in boc),
             "block_out_channels must be 1 to 12 positive integers", boc)
        need(all(c % self.norm_num_groups == 0 for c in boc),
             f"every block_out_channels entry must be a multiple of norm_num_groups ({self.norm_num_groups})", boc)
        if self.attention_levels is not None:
            lv = self.attention_levels
            need(isinstance(lv, (tuple, list)) and all(isinstance(k, int) and 0 <= k < len(boc) for k in lv),
                 f"attention_levels must be levels in 0..{len(boc) - 1}", lv)
        need(isinstance(self.modalities, (tuple, list)) and 1 <= len(self.modalities) <= 8
             and all(isinstance(m, str) for m in self.modalities) and len(set(self.modalities)) == len(self.modalities),
             "modalities must be distinct modality names", self.modalities)
        if self.prediction not in PREDICTIONS:
            raise CheckpointError(f"prediction must be one of {', '.join(PREDICTIONS)}; got {self.prediction!r}")
        if int(self.patch) < 1 or int(self.res) % int(self.patch):
            raise CheckpointError(f"patch must be a positive divisor of res {self.res}; got {self.patch}")
        if self.lr_schedule not in ("constant", "cosine"):
            raise CheckpointError(f"lr_schedule must be 'constant' or 'cosine'; got {self.lr_schedule!r}")
        if not float(self.schedule_shift) > 0:
            raise CheckpointError(f"schedule_shift must be positive; got {self.schedule_shift}")

    @classmethod
    def preset(cls, name: str = "small", **overrides) -> "DDPMConfig":
        """A named model size (:data:`PRESETS`) with ``overrides`` applied."""
        if name not in PRESETS:
            raise CheckpointError(f"unknown model preset {name!r}; presets are {', '.join(PRESETS)}")
        kw = {**PRESETS[name], **overrides}
        if kw.get("attention_levels") == "coarse":
            # self-attention only where the feature map is 16x16 or coarser (and at most the two
            # coarsest levels): its memory grows with the fourth power of the side
            n, res = len(kw["block_out_channels"]), int(kw.get("res", cls.res)) // int(kw.get("patch", 1))
            kw["attention_levels"] = tuple(k for k in range(max(0, n - 2), n) if res >> k <= 16) or (n - 1,)
        return cls(**kw)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict, where: str = "config.json") -> "DDPMConfig":
        from geoface.nn.config import config_from_dict

        if isinstance(d, dict) and "standardize" not in d:  # a run from before standardisation
            d = {**d, "standardize": False}
        return config_from_dict(cls, d, where=where)

    def save(self, path: str | os.PathLike) -> None:
        atomic_write_text(path, self.to_json())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "DDPMConfig":
        path = Path(path)
        if not path.is_file():
            raise CheckpointError(f"missing {path.name} in {path.parent}")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise CheckpointError(f"{path} is not a valid config ({e})") from None
        return cls.from_dict(d, where=str(path))


#: named model sizes.  ``small`` (the command line's default, 5.9 M parameters at 32² and 64² with a
#: 384-d text encoder) is the one the README's results are measured with; ``base`` is the
#: paper-sized layout (for a GPU); ``tiny`` is for smoke tests.  ``attention_levels="coarse"``:
#: self-attention on the feature maps of 16² and coarser among the two coarsest levels.
PRESETS = {
    "tiny": dict(block_out_channels=(16, 32), layers_per_block=1, attention_head_dim=8, norm_num_groups=8,
                 attention_levels=(1,)),
    "small": dict(block_out_channels=(32, 64, 96, 128), layers_per_block=1, attention_head_dim=8, norm_num_groups=8,
                  attention_levels="coarse", lr=3e-4, ema_decay=0.995),
    "base": dict(block_out_channels=(64, 128, 256, 256), layers_per_block=2, attention_head_dim=8, norm_num_groups=32,
                 attention_levels=(1, 2, 3), lr=1e-4, ema_decay=0.999),
}
