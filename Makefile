# geoface — `make demo` and `make test` create .venv and install everything themselves.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.geoface-installed
OUT    := demo_out

.PHONY: install cgal cgal-headers cholmod chromium test demo bench docs notebook notebooks clean distclean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt setup.py geoface/param/_native/regular_triangulation.cpp
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	-@$(MAKE) --no-print-directory cgal-headers
	$(PY) -m pip install --disable-pip-version-check -q -c constraints.txt -e ".[all,dev]"
	$(PY) -m pip install --disable-pip-version-check -q -c constraints.txt --no-deps mediapipe
	@$(PY) -c "from geoface.param import regular as r; print('CGAL exact power diagrams:', 'built' if r.available() else 'NOT built: ' + r.INSTALL_HINT)"
	-@$(MAKE) --no-print-directory cholmod
	-@$(MAKE) --no-print-directory chromium
	touch $(STAMP)

# Debian packages, best effort (root only): install, and on failure refresh the lists once and retry.
APT_INSTALL = timeout 900 apt-get install -y -qq --no-install-recommends
define apt_get
	if command -v apt-get >/dev/null && [ "$$(id -u)" = 0 ]; then \
		$(APT_INSTALL) $(1) >/dev/null 2>&1 || { timeout 600 apt-get update -qq >/dev/null 2>&1; $(APT_INSTALL) $(1) >/dev/null 2>&1; } || true; fi
endef

# CGAL's headers (Debian's libcgal-dev) for the exact regular triangulations behind optimal
# transport; the extension is compiled by pip (setup.py).  `make cgal` installs and rebuilds.
cgal-headers:
	@if [ ! -f /usr/include/CGAL/Regular_triangulation_2.h ]; then $(call apt_get,libcgal-dev); fi

cgal: cgal-headers
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --disable-pip-version-check -q -c constraints.txt --no-deps -e .
	@$(PY) -c "from geoface.param import regular as r; print('CGAL exact power diagrams:', 'built' if r.available() else 'NOT built: ' + r.INSTALL_HINT)"

# Optional, best effort: CHOLMOD (scikit-sparse 0.4.16 builds against Debian's SuiteSparse 5)
# and OpenBLAS make Ricci-flow Newton steps ~3x faster. Without them geoface uses SciPy's SuperLU.
cholmod:
	@if [ ! -f /usr/include/suitesparse/cholmod.h ]; then $(call apt_get,libsuitesparse-dev libopenblas0-pthread); fi
	@if [ -f /usr/include/suitesparse/cholmod.h ]; then \
		timeout 600 $(PY) -m pip install --disable-pip-version-check -q scikit-sparse==0.4.16 >/dev/null 2>&1 \
		&& echo "CHOLMOD: installed" || echo "CHOLMOD: not available (SciPy SuperLU will be used)"; \
	else echo "CHOLMOD: SuiteSparse headers not found (SciPy SuperLU will be used)"; fi

# Optional, best effort: a real browser for the web viewer's test (headless Chromium + its driver).
chromium:
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then $(call apt_get,chromium chromium-driver); fi
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then echo "Chromium: installed"; \
	else echo "Chromium: not available (the web viewer's browser test will be skipped)"; fi

test: $(STAMP)
	@$(PY) -m compileall -q geoface tests >/dev/null  # bytecode once, not in every process the tests start
	GEOFACE_QUIET=1 $(PY) -m pytest -q -n 2 --dist worksteal tests

# The documentation site in site/ (offline; warnings are errors): the guides in docs/, the
# command-line reference and the API reference generated from the code.
docs: $(STAMP)
	GEOFACE_QUIET=1 $(PY) data_tools/gen_docs.py
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict -q
	@echo "documentation in site/index.html"

# JupyterLab on the tutorials (the `lab` extra, installed on first use)
notebook: $(STAMP)
	@$(PY) -c "import jupyterlab" 2>/dev/null || $(PY) -m pip install -q -c constraints.txt -e ".[lab]"
	$(VENV)/bin/jupyter lab notebooks/

# run every notebook again and store its outputs (what the repository page shows)
notebooks: $(STAMP)
	$(PY) data_tools/run_notebooks.py

demo: $(STAMP)
	@mkdir -p $(OUT)
	@# the demo replaces its own outputs in $(OUT) (--force); geoface refuses to replace files otherwise
	@echo "== the procedural head (smiling), 20K vertices"
	$(VENV)/bin/geoface synth head -o $(OUT)/head.obj --vertices 20000 --seed 0 --expression smile=0.6 --meta $(OUT)/head.json --force
	$(VENV)/bin/geoface inspect $(OUT)/head.obj
	@echo "== a messy scan of it: holes, near-duplicate vertices, debris, a non-manifold fin"
	$(PY) data_tools/make_messy_head.py $(OUT)/messy_head.ply --vertices 20000 --seed 0
	$(VENV)/bin/geoface inspect $(OUT)/messy_head.ply
	$(VENV)/bin/geoface repair $(OUT)/messy_head.ply -o $(OUT)/messy_head_disk.ply --force
	@echo "== the same, closed at the neck: cut open at the lowest plane"
	$(PY) data_tools/make_messy_head.py $(OUT)/closed_head.ply --vertices 20000 --seed 1 --closed
	$(VENV)/bin/geoface repair $(OUT)/closed_head.ply -o $(OUT)/closed_head_disk.ply --open plane --force
	@echo "== a genus-2 surface: handles cut and capped, then opened"
	$(VENV)/bin/geoface synth surface genus2 -o $(OUT)/genus2.obj --force
	$(VENV)/bin/geoface repair $(OUT)/genus2.obj -o $(OUT)/genus2_disk.obj --up z --open cap --force
	@echo "== the head to geometry images (Ricci flow, OT with the face magnified 2.5x) and back"
	$(VENV)/bin/geoface convert $(OUT)/head.obj -o $(OUT)/head_gim --res 256 --roi $(OUT)/head.json --lam 2.5 --force
	$(VENV)/bin/geoface reconstruct $(OUT)/head_gim -o $(OUT)/head_reconstructed.obj --force
	@echo "== look at it (off-screen pyvista): the head, its UV distortion, the geometry images"
	$(VENV)/bin/geoface view $(OUT)/head.obj --screenshot $(OUT)/head.png --force
	$(VENV)/bin/geoface view $(OUT)/head_reconstructed.obj --screenshot $(OUT)/head_reconstructed.png --force
	$(VENV)/bin/geoface view $(OUT)/head_gim --screenshot $(OUT)/head_gim_montage.png --force
	@echo "== a small labelled dataset: 6 synthetic heads x 2 corner sets, 2 worker processes"
	$(PY) data_tools/make_synthetic_heads.py $(OUT)/heads --count 6 --vertices 3000 --seed 0
	$(VENV)/bin/geoface dataset build $(OUT)/heads -o $(OUT)/dataset --res 128 --augment 2 --workers 2
	@echo "== three real heads (the ICT-FaceKit model, shipped with geoface) to geometry images, beside the procedural one"
	$(VENV)/bin/geoface synth ict -o $(OUT)/ict_smile.obj --seed 1 --expression mouthSmile_L=0.9,mouthSmile_R=0.9 --meta $(OUT)/ict_smile.json --force
	$(VENV)/bin/geoface synth ict -o $(OUT)/ict_jaw.obj --seed 2 --expression jawOpen=0.6,browInnerUp_L=0.7,browInnerUp_R=0.7 --meta $(OUT)/ict_jaw.json --force
	$(VENV)/bin/geoface synth ict -o $(OUT)/ict_wink.obj --seed 3 --expression eyeBlink_L=1,mouthSmile_L=0.5 --meta $(OUT)/ict_wink.json --force
	for h in ict_smile ict_jaw ict_wink; do \
		$(VENV)/bin/geoface convert $(OUT)/$$h.obj -o $(OUT)/$${h}_gim --res 256 --roi $(OUT)/$$h.json --lam 2.5 --force || exit 1; \
		$(VENV)/bin/geoface view $(OUT)/$${h}_gim --screenshot $(OUT)/$${h}_gim_montage.png --force || exit 1; \
	done
	@echo "outputs in $(OUT)/ (see $(OUT)/head_gim/preview.png, $(OUT)/ict_*_gim/preview.png, $(OUT)/*.png, $(OUT)/dataset/manifest.jsonl)"

bench: $(STAMP)
	GEOFACE_QUIET=1 $(PY) bench/bench_repair.py
	GEOFACE_QUIET=1 $(PY) bench/bench_param.py
	-@$(PY) -m pip install --disable-pip-version-check -q pysdot==0.2.16 >/dev/null 2>&1 || echo "pysdot not installable: OT comparison skipped"
	GEOFACE_QUIET=1 $(PY) bench/bench_convert.py
	GEOFACE_QUIET=1 $(PY) bench/bench_bake.py
	GEOFACE_QUIET=1 $(PY) bench/bench_dataset.py

clean:
	rm -rf $(OUT) bench_out .pytest_cache

distclean: clean
	rm -rf $(VENV) *.egg-info
