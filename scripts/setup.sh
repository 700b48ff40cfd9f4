#!/usr/bin/env bash
# Create .venv and install areasearch with its test tools. Idempotent.
# Environment: TORCH_INDEX_URL, the package index of PyTorch (default: PyPI).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install --quiet --upgrade pip
# PyTorch first, so that the package's `torch` requirement is already met. From PyPI by default; on
# Linux that is the CUDA build (several GB). TORCH_INDEX_URL picks another index, e.g. PyTorch's
# CPU-only wheels for a machine without a GPU:
#   TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu bash scripts/setup.sh
if [ -n "${TORCH_INDEX_URL:-}" ]; then
  .venv/bin/python -m pip install --quiet --index-url "$TORCH_INDEX_URL" "torch==2.13.0"
else
  .venv/bin/python -m pip install --quiet "torch==2.13.0"
fi
# the optional extras too (the ROS 2 node, MCAP episodes), so that their tests run
.venv/bin/python -m pip install --quiet -e ".[dev,ros2,mcap]"
