#!/usr/bin/env bash
# Installs every Debian package topos needs to build, test, benchmark and run its examples.
# Idempotent: when everything is present it only checks and returns in a second or two.
set -euo pipefail

packages=(
  build-essential cmake ninja-build ccache pkg-config
  libeigen3-dev libcgal-dev libboost-graph-dev
  libtorch-dev libopenblas0-pthread
  libgloo-dev  # headers of the Gloo LibTorch links: c10d's ProcessGroupGloo (data-parallel training)
  libbullet-dev libbullet-extras-dev
  nlohmann-json3-dev libcli11-dev catch2 libbenchmark-dev
  python3  # scripts/check_torch_file.py: the tests' torch.load compatibility check
  python3-torch  # tests/nn/test_python_interop.cpp: torch.load / torch.save where users are
)
# Headless Chromium is only needed for the viewer screenshot test: scripts/test.sh asks for it
# (TOPOS_WITH_CHROMIUM=1); the demo does not.
if [ "${TOPOS_WITH_CHROMIUM:-0}" = "1" ]; then packages+=(chromium); fi
# The fuzzers (scripts/fuzz.sh) and clang-tidy need clang and its runtime libraries (libFuzzer,
# the sanitizers); the normal build and CI do not.
if [ "${TOPOS_WITH_FUZZ:-0}" = "1" ]; then packages+=(clang libclang-rt-dev clang-tidy); fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages present"
  exit 0
fi
echo "setup: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
