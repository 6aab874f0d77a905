"""Look at what geoface makes in a web browser: ``geoface view --web PATH [PATH ...]``.

A local `viser <https://viser.studio>`_ server shows, side by side in one scene (so one camera
moves them all, e.g. an original beside its reconstruction):

* **a mesh** (OBJ, PLY, OFF, STL, ...): its texture or vertex colours, or plain grey; smooth or
  flat shading; a wireframe; UV-distortion colouring (quasi-conformal ratio, log area ratio)
  when it has UVs; its boundary loops in red;
* **a geometry-image folder** (``geoface convert`` output): the surface it encodes, and beside it
  the images — position, normal, texture, mask, and the ROI when the folder has one;
* **a 3D Gaussian-splat PLY** (``geoface splat fit``, an avatar export): viser's splat renderer;
* **an avatar** (a ``geoface talk train`` model folder; drive it with ``--audio``, or with a
  ``talk synth`` data folder to see its frames beside the render): the animated splats, a frame
  slider and play / pause.

The camera starts in front of the first item (:func:`geoface.mesh.frame.mesh_frame`: a head
faces you whichever axis it was scanned along). The server listens on ``127.0.0.1`` unless told
otherwise; ``exit_after`` (seconds) or ``idle_exit`` (seconds after the last browser left) stop
it by themselves (scripts, tests).

Python::

    from geoface.webview import WebView
    view = WebView(["head.obj", "gimage/"], port=8080)
    print(view.url)
    view.serve()          # until Ctrl-C
"""

from __future__ import annotations

from .items import DEFAULT_PORT, item_kind, uv_distortion_colors
from .server import WebView

__all__ = ["WebView", "item_kind", "uv_distortion_colors", "DEFAULT_PORT"]
