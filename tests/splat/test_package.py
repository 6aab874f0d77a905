import subprocess
import sys


def test_splat_init_is_light_and_exports_functions():
    code = ("import sys, geoface.splat as s; assert 'torch' not in sys.modules; "
            "from geoface.splat import rasterize, look_at; assert callable(rasterize) and callable(look_at)")
    subprocess.run([sys.executable, "-c", code], check=True)
