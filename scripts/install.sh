#!/usr/bin/env bash
# Installs the system libraries Open3D and CGAL need, a CPU build of torch, then voro3d into .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"

need_apt=()
for pkg in libusb-1.0-0 libvulkan1 mesa-vulkan-drivers libgl1 libegl1 libgomp1 g++ libcgal-dev libgmp-dev libmpfr-dev; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if [ ${#need_apt[@]} -gt 0 ] && command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# A CPU build of torch first, so the torch extra's torch>=2.2 is already met (no multi-GB CUDA wheel).
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
    if command -v nvidia-smi >/dev/null 2>&1; then
        .venv/bin/python -m pip install -q "torch>=2.2"
    else
        .venv/bin/python -m pip install -q torch==2.13.0
    fi
fi
# Every extra, so that the tests cover training and ONNX export (torch, onnx) and `voro3d batch --engine ray`.
.venv/bin/python -m pip install -q -e ".[torch,onnx,ray,dev]"
