# uiofmu: the two commands a new user needs are `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install demo test test-fast test-blas lint docs fmus examples clean fuzz

FUZZ_SECONDS ?= 600
FUZZ_SEED    ?= 0

# quiet: one line says what happens; pip's own errors still show
$(STAMP): pyproject.toml
	@echo "installing uiofmu (editable) with its test, mujoco, control and docs extras into $(VENV)/ ..."
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install --quiet --disable-pip-version-check --upgrade pip
	@$(PY) -m pip install --quiet --disable-pip-version-check -e ".[test,mujoco,control,docs]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/uiofmu demo --out out/demo

# on every core (pytest-xdist; each test file on one worker, so its module fixtures are built once)
test: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile

# the suite without the tests marked valgrind, cmake, mujoco or slow (see pyproject.toml)
test-fast: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile -m "not valgrind and not cmake and not mujoco and not slow"

# the numerically sensitive tests (verdicts of the examples, reproducers and edge plants; the design
# rules) under other OpenBLAS kernels and thread counts: the same answers
# on every machine. SkylakeX only where the CPU has AVX-512.
BLAS_TESTS   := tests/test_same_answers.py tests/test_design_rules.py tests/test_fmus_catalogue.py \
                tests/test_largest_margin.py::test_a_plant_whose_first_margins_differ_above_the_cap_is_designed_under_every_kernel
BLAS_KERNELS ?= Prescott Sandybridge Haswell $(shell grep -qw avx512f /proc/cpuinfo 2>/dev/null && echo SkylakeX)
test-blas: $(STAMP)
	@set -e; for k in default $(BLAS_KERNELS); do for t in 1 2; do \
	  echo "== OPENBLAS_CORETYPE=$$k OPENBLAS_NUM_THREADS=$$t"; \
	  if [ $$k = default ]; then env -u OPENBLAS_CORETYPE OPENBLAS_NUM_THREADS=$$t $(PY) -m pytest -q -n 2 \
	    --dist loadfile -m "not slow" $(BLAS_TESTS); \
	  else OPENBLAS_CORETYPE=$$k OPENBLAS_NUM_THREADS=$$t $(PY) -m pytest -q -n 2 --dist loadfile -m "not slow" \
	    $(BLAS_TESTS); fi; \
	done; done

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# the documentation site (mkdocs.yml, docs/) into site/; any warning fails it (so no --quiet: it
# silences the warnings, and with them what --strict counts)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# a long fuzzing campaign: the C FMU's call sequences under ASan + UBSan (all families), then
# hostile problem files, cards, step specs and tables through the command line
fuzz: $(STAMP)
	$(PY) tests/cfuzz.py --seconds $(FUZZ_SECONDS) --family all
	$(PY) tests/fuzz_campaign.py --cases 4000 --seed $(FUZZ_SEED) --seconds $(FUZZ_SECONDS)

# the FMU catalogue: every example's observer and plant FMU, checked (validate, our master, fmpy, ecospy;
# each FMU alone in the Compliance Checker and fmusim of ../shared/importers/ where they are, results on the
# console only); writes fmus/README.md (in git; tests/test_fmus_catalogue.py fails when it is stale)
fmus: $(STAMP)
	$(PY) examples/build_fmus.py --out fmus

# every example script, each writing under examples/out/ (the catalogue there too: fmus/README.md is
# written by `make fmus` only)
examples: $(STAMP)
	for f in examples/*.py; do case $$f in */build_fmus.py) $(PY) $$f --out examples/out/fmus || exit 1;; \
	  */test_*.py) $(PY) -m pytest -q $$f || exit 1;; *) $(PY) $$f || exit 1;; esac; done

clean:
	rm -rf out examples/out build site *.egg-info
	find fmus -mindepth 1 -not -name README.md -exec rm -rf {} +
