#!/usr/bin/env bash
# Installs voro3d into .venv: `install.sh demo` what the demo needs (voro3d alone, no torch),
# `install.sh test` everything the tests need (a CPU build of torch, then the torch, onnx, ray and dev extras).
# Both first install the system libraries Open3D and CGAL need, where apt-get is there and they are missing.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
what="${1:-test}"
case "$what" in
    demo) echo "installing voro3d into .venv (about 3-4 minutes, ~1.1 GB; once)" ;;
    test) echo "installing torch (CPU), onnx, ray and the test tools into .venv (about 3-4 more minutes, ~1.1 GB more; once)" ;;
    *) echo "usage: scripts/install.sh demo|test" >&2; exit 2 ;;
esac

need_apt=()
for pkg in libusb-1.0-0 libvulkan1 mesa-vulkan-drivers libgl1 libegl1 libgomp1 g++ libcgal-dev libgmp-dev libmpfr-dev; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if [ ${#need_apt[@]} -gt 0 ] && command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
# A download cut off midway (a CI run lost ray's 79 MB wheel at 62.7 MB six times over) is resumed by pip
# and, failing that, the whole install is tried again: three tries, half a minute apart.
retry() {
    local try
    for try in 1 2 3; do
        "$@" && return 0
        [ "$try" -lt 3 ] && { echo "failed (try $try of 3): $*; trying again in 30 s" >&2; sleep 30; }
    done
    return 1
}
retry .venv/bin/python -m pip install -q --upgrade pip
pip_install() { retry .venv/bin/python -m pip install -q --resume-retries 20 "$@"; }
if [ "$what" = demo ]; then
    # The demo (python -m voro3d.demo) and the voro3d command need no extra: no torch, no ray, no test tools.
    pip_install -e .
    exit 0
fi
# A CPU build of torch first, so the torch extra's torch>=2.2 is already met (no multi-GB CUDA wheel).
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
    if command -v nvidia-smi >/dev/null 2>&1; then
        pip_install "torch>=2.2"
    else
        pip_install torch==2.13.0
    fi
fi
# Every extra, so that the tests cover training and ONNX export (torch, onnx) and `voro3d batch --engine ray`.
pip_install -e ".[torch,onnx,ray,dev]"
