"""Audio features for talking avatars: offline log-mel spectra from WAV files, or precomputed arrays.

:func:`audio_features` gives one feature vector per video frame: ``(T, D)``. A ``.wav`` is read
with :mod:`scipy.io.wavfile` (mono mix, any rate, int or float samples), analysed with 25 ms Hann
windows every 10 ms into ``n_mels`` log-mel bands (HTK mel scale, 50 Hz – min(8 kHz, sr/2)), and
the windows are averaged per frame at ``fps``. ``.npy``/``.npz`` files hold features a user
extracted elsewhere (e.g. wav2vec): ``(T, D)`` (an ``.npz`` under the key ``features``); they
are resampled to the requested frame count by linear interpolation when the count differs.
Nothing is downloaded.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geoface.errors import AvatarError

__all__ = ["read_wav", "log_mel", "audio_features", "envelope", "audio_context", "speech_like"]

#: sample rates read_wav accepts (log-mel features need at least ~100 samples per 10 ms hop)
MIN_SAMPLE_RATE = 8000
MAX_SAMPLE_RATE = 384000


def read_wav(path) -> tuple[np.ndarray, int]:
    """(mono float64 samples in [-1, 1], sample rate)."""
    from scipy.io import wavfile

    import struct
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns on chunks it skips
            sr, x = wavfile.read(str(path))
    except (OSError, ValueError, EOFError, IndexError, TypeError, struct.error) as e:
        raise AvatarError(f"{path}: not a readable WAV file ({type(e).__name__}: {e})") from None
    if not MIN_SAMPLE_RATE <= int(sr) <= MAX_SAMPLE_RATE:
        raise AvatarError(f"{path}: sample rate {sr} Hz; speech needs {MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE} Hz")
    x = np.asarray(x)
    if x.dtype.kind not in "iuf":
        raise AvatarError(f"{path}: unsupported sample format {x.dtype}")
    if np.issubdtype(x.dtype, np.integer):
        x = x.astype(np.float64) / float(np.iinfo(x.dtype).max)
    x = x.astype(np.float64)
    if x.ndim == 2:
        x = x.mean(1)
    if x.ndim != 1 or len(x) == 0 or not np.isfinite(x).all():
        raise AvatarError(f"{path}: empty or non-finite audio")
    return x, int(sr)


def _mel_filters(n_mels: int, n_fft: int, sr: int, fmin: float = 50.0, fmax: float | None = None) -> np.ndarray:
    fmax = min(fmax or 8000.0, sr / 2)
    mel = lambda f: 2595.0 * np.log10(1 + f / 700.0)  # noqa: E731
    imel = lambda m: 700.0 * (10 ** (m / 2595.0) - 1)  # noqa: E731
    pts = imel(np.linspace(mel(fmin), mel(fmax), n_mels + 2))
    freqs = np.fft.rfftfreq(n_fft, 1.0 / sr)
    Fb = np.zeros((n_mels, len(freqs)))
    for i in range(n_mels):
        lo, c, hi = pts[i], pts[i + 1], pts[i + 2]
        Fb[i] = np.clip(np.minimum((freqs - lo) / (c - lo), (hi - freqs) / (hi - c)), 0, None)
    return Fb


def log_mel(x, sr: int, n_mels: int = 40, win: float = 0.025, hop: float = 0.01) -> tuple[np.ndarray, float]:
    """Log-mel spectrogram ``(windows, n_mels)`` and the window hop in seconds."""
    x = np.asarray(x, np.float64)
    nw, nh = int(round(win * sr)), int(round(hop * sr))
    if len(x) < nw:
        x = np.pad(x, (0, nw - len(x)))
    n = 1 + (len(x) - nw) // nh
    idx = np.arange(nw)[None] + nh * np.arange(n)[:, None]
    frames = x[idx] * np.hanning(nw)
    n_fft = 1 << (nw - 1).bit_length()
    P = np.abs(np.fft.rfft(frames, n_fft)) ** 2
    M = P @ _mel_filters(n_mels, n_fft, sr).T
    return np.log(M + 1e-8), nh / sr


def audio_features(path_or_array, n_frames: int, fps: float, *, sr: int | None = None, n_mels: int = 40) -> np.ndarray:
    """``(n_frames, D)`` float32 per-frame features (module doc)."""
    if isinstance(path_or_array, (str, Path)):
        p = Path(path_or_array)
        if p.suffix.lower() in (".npy", ".npz"):
            try:
                if p.suffix.lower() == ".npy":
                    A = np.load(p, allow_pickle=False)
                else:
                    with np.load(p, allow_pickle=False) as d:
                        A = d["features"]
            except (OSError, KeyError, ValueError) as e:
                raise AvatarError(f"{p}: cannot read features ({type(e).__name__}: {e})") from None
            A = np.asarray(A, np.float64)
            if A.ndim != 2 or len(A) < 1 or not np.isfinite(A).all():
                raise AvatarError(f"{p}: features must be a finite (T, D) array; got {A.shape}")
            if len(A) != n_frames:
                t = np.linspace(0, len(A) - 1, n_frames)
                A = np.stack([np.interp(t, np.arange(len(A)), A[:, j]) for j in range(A.shape[1])], 1)
            return A.astype(np.float32)
        x, sr = read_wav(p)
    else:
        if sr is None:
            raise AvatarError("sr is required with a sample array")
        x = np.asarray(path_or_array, np.float64)
    S, hop = log_mel(x, sr, n_mels)
    t_win = (np.arange(len(S)) + 0.5) * hop
    k = np.clip((t_win * fps).astype(int), 0, None)
    out = np.full((n_frames, S.shape[1]), np.log(1e-8))
    for f in range(n_frames):
        rows = S[k == f]
        if len(rows):
            out[f] = rows.mean(0)
    return out.astype(np.float32)


def envelope(x, sr: int, fps: float, n_frames: int) -> np.ndarray:
    """RMS loudness per video frame, ``(n_frames,)``."""
    x = np.asarray(x, np.float64)
    edges = (np.arange(n_frames + 1) / fps * sr).astype(int)
    return np.array([np.sqrt(np.mean(x[a:b] ** 2)) if b > a and a < len(x) else 0.0
                     for a, b in zip(edges[:-1], edges[1:])])


def audio_context(features, window: int) -> np.ndarray:
    """Each frame's features beside those of the ``window`` frames before and after it:
    ``(T, D)`` → ``(T, (2 window + 1) D)``, in the order −window … +window (the first and last
    frames repeated past the ends).  Lips move ahead of and behind the sound they make, so one
    frame's spectrum says less about the mouth than its neighbours' do."""
    A = np.asarray(features, dtype=np.float32)
    if A.ndim != 2:
        raise AvatarError(f"audio features must be (frames, D); got shape {A.shape}")
    if window < 0:
        raise AvatarError(f"the audio window must be >= 0 frames; got {window}")
    if window == 0 or not len(A):
        return A
    idx = np.clip(np.arange(len(A))[:, None] + np.arange(-window, window + 1)[None], 0, len(A) - 1)
    return A[idx].reshape(len(A), -1)


def speech_like(seconds: float, sr: int = 16000, seed: int = 0):
    """A speech-like signal: (samples, loudness envelope at sr, per-sample roundedness 0..1)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * sr)
    t = np.arange(n) / sr
    env = np.zeros(n)
    rnd = np.zeros(n)
    f1 = np.full(n, 500.0)
    pos = 0.2
    while pos < seconds - 0.2:
        if rng.random() < 0.15:  # a pause
            pos += rng.uniform(0.25, 0.5)
            continue
        dur = rng.uniform(0.16, 0.3)
        a, b = int(pos * sr), int(min(pos + dur, seconds) * sr)
        u = np.linspace(0, 1, b - a)
        env[a:b] = np.maximum(env[a:b], rng.uniform(0.5, 1.0) * np.sin(np.pi * u) ** 1.5)
        o = rng.random() < 0.35
        rnd[a:b] = np.maximum(rnd[a:b], (1.0 if o else 0.0) * np.sin(np.pi * u))
        f1[a:b] = 450.0 if o else rng.uniform(650, 800)
        pos += dur + rng.uniform(0.02, 0.08)
    f0 = 120 + 15 * np.sin(2 * np.pi * 0.7 * t)
    phase = np.cumsum(2 * np.pi * f0 / sr)
    src = np.sign(np.sin(phase)) * 0.5 + 0.1 * rng.normal(size=n)  # buzz + breath
    from scipy.signal import lfilter

    out = np.zeros(n)
    blk = sr // 100
    for s in range(0, n, blk):  # time-varying two-formant resonator, 10 ms blocks
        seg = src[s:s + blk]
        y = np.zeros_like(seg)
        for F, bw in ((f1[s], 90.0), (1200.0 + 600 * (1 - rnd[s]), 120.0)):
            r = np.exp(-np.pi * bw / sr)
            a = [1, -2 * r * np.cos(2 * np.pi * F / sr), r * r]
            y += lfilter([1 - r], a, seg)
        out[s:s + blk] = y
    out = out / (np.abs(out).max() + 1e-9) * env
    return out.astype(np.float32), env, rnd
