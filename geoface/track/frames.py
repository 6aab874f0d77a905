"""Frames to track: an image, a folder of images or a video file, read whole
(:func:`read_frames`) or streamed (:class:`FrameSource`), checked as they come."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["read_frames", "FrameSource", "as_uint8", "TRACK_MAX_PIXELS"]


def as_uint8(img) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)
    if a.ndim != 3 or a.shape[2] != 3:
        raise GeofaceError(f"frames must be (H, W, 3) RGB images; got {a.shape}")
    return np.ascontiguousarray(a)


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v")


#: the largest photo the tracker decodes (about 100 megapixels: a medium-format camera's); the
#: face mesh looks at 256² crops, so more only costs memory
TRACK_MAX_PIXELS = 10_000 * 10_000


def read_frames(path) -> tuple[list, list, float | None]:
    """(frames as (H, W, 3) uint8 RGB, their names, the frame rate or None) of an image file, a
    folder of images (sorted by name) or a video file (decoded by imageio-ffmpeg's ffmpeg)."""
    from geoface.images import read_image

    p = Path(path)
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES and f.is_file())
        if not files:
            raise GeofaceError(f"{p}: no images ({', '.join(_IMAGE_SUFFIXES)}) in the folder")
        stems: dict = {}
        for f in files:  # each frame's outputs (its mask) are named by its stem
            if f.stem in stems:
                raise GeofaceError(f"{p}: two frames share the name {f.stem!r} ({stems[f.stem]}, {f.name}); "
                                   "rename one")
            stems[f.stem] = f.name
        from geoface._io import image_size

        for f in files:
            image_size(f, max_pixels=TRACK_MAX_PIXELS)
        frames = [as_uint8(read_image(f)) for f in files]
        if len({f.shape for f in frames}) > 1:
            raise GeofaceError(f"{p}: the images are not all the same size")
        return frames, [f.name for f in files], None
    if not p.is_file():
        raise GeofaceError(f"{p}: no such file or folder")
    if p.suffix.lower() in VIDEO_SUFFIXES:
        from geoface.video import read_video

        frames, fps = read_video(p)
        return list(frames), [f"{k:06d}" for k in range(len(frames))], fps
    if p.suffix.lower() in _IMAGE_SUFFIXES:
        from geoface._io import image_size

        image_size(p, max_pixels=TRACK_MAX_PIXELS)  # a photo, not a poster: refused before decoding
        return [as_uint8(read_image(p))], [p.name], None
    raise GeofaceError(f"{p}: not an image ({', '.join(_IMAGE_SUFFIXES)}), a video ({', '.join(VIDEO_SUFFIXES)}) "
                       "or a folder of images")


class FrameSource:
    """The frames of a video file or a folder of images, decoded afresh each time it is iterated
    (a long clip never sits in memory whole): ``names``, ``fps`` (the video's, else None),
    ``size`` (W, H), ``len()``."""

    def __init__(self, path):
        from geoface.images import read_image

        p = Path(path)
        self.path = p
        if p.is_dir():
            frames_check = read_frames  # the folder's checks (names, sizes) without decoding it twice
            files = sorted(f for f in p.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES and f.is_file())
            if not files:
                frames_check(p)  # the one-line error
            from geoface._io import image_size

            sizes = {image_size(f, max_pixels=TRACK_MAX_PIXELS) for f in files}
            stems = [f.stem for f in files]
            if len(set(stems)) != len(stems):
                frames_check(p)
            self.files, self.names, self.fps = files, [f.name for f in files], None
            first = as_uint8(read_image(files[0]))
            if None not in sizes and len(sizes) > 1:
                raise GeofaceError(f"{p}: the images are not all the same size")
            self.size = (first.shape[1], first.shape[0])
            self._n = len(files)
        elif p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES:
            from geoface.video import iter_video, video_rate

            self.files, self.fps = None, video_rate(p)
            first = next(iter_video(p))
            self.size = (first.shape[1], first.shape[0])
            from geoface.video import probe_video

            self._n = int(probe_video(p)["frames"])  # counted by ffmpeg without decoding
            self.names = [f"{k:06d}" for k in range(self._n)]
        elif p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES:
            raise GeofaceError(f"{p}: one image; a clip is a video or a folder of frames")
        else:
            read_frames(p)  # the one-line error for anything else
            raise GeofaceError(f"{p}: not a video or a folder of frames")

    def __len__(self) -> int:
        return self._n

    def __iter__(self):
        if self.files is None:
            from geoface.video import iter_video

            yield from iter_video(self.path)
            return
        from geoface.images import read_image

        for f in self.files:
            a = as_uint8(read_image(f))
            if (a.shape[1], a.shape[0]) != self.size:
                raise GeofaceError(f"{f}: {a.shape[1]}×{a.shape[0]}, not {self.size[0]}×{self.size[1]} as the first frame")
            yield a
