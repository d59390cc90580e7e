#!/usr/bin/env bash
# Installs every Debian package topos needs to build, test, benchmark and run its examples.
# Idempotent: when everything is present it only checks and returns in a second or two.
# Also the JavaScript libraries of the hopnet report and viewer (npm, pinned; see below).
set -euo pipefail

packages=(
  build-essential cmake ninja-build ccache pkg-config
  libeigen3-dev libcgal-dev libboost-graph-dev
  libtorch-dev libopenblas0-pthread
  libgloo-dev  # headers of the Gloo LibTorch links: c10d's ProcessGroupGloo (data-parallel training)
  libbullet-dev libbullet-extras-dev
  libtcmalloc-minimal4  # topos::tcmalloc: the programs' malloc (HOPNet's training step 30 % faster)
  nlohmann-json3-dev libcli11-dev catch2 libbenchmark-dev
  libzip-dev  # topos::data: TU and DGCNN datasets read from the zips they are published as
  python3  # scripts/check_torch_file.py: the tests' torch.load compatibility check
  python3-torch  # tests/nn/test_python_interop.cpp: torch.load / torch.save where users are
  # The Python package (python/, TOPOS_PYTHON): its extension on pybind11 and torch's casters,
  # and its tests (tests/python: pytest, numpy, scipy.sparse as TopoNetX's users hold operators).
  python3-dev pybind11-dev python3-numpy python3-scipy python3-pytest
  clang-format  # ctest code_style (scripts/check_style.sh): the tree stays as .clang-format says
)
# Headless Chromium is only needed for the viewer screenshot test: scripts/test.sh asks for it
# (TOPOS_WITH_CHROMIUM=1); the demo does not.
if [ "${TOPOS_WITH_CHROMIUM:-0}" = "1" ]; then packages+=(chromium); fi
# The fuzzers (scripts/fuzz.sh) and clang-tidy need clang and its runtime libraries (libFuzzer,
# the sanitizers); the normal build and CI do not.
if [ "${TOPOS_WITH_FUZZ:-0}" = "1" ]; then packages+=(clang libclang-rt-dev clang-tidy); fi

# npm installs the report's JavaScript libraries below (Debian's nodejs ships without it; a
# machine with Node.js from elsewhere usually has its npm already).
if ! command -v npm >/dev/null 2>&1; then packages+=(npm); fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages present"
else
  echo "setup: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# The HTML report and the 3D rollout viewer (apps/hopnet/web/) inline three.js and Chart.js
# from the npm registry, pinned. Debian's libjs-three is three r111 (2019), 76 releases behind,
# and its libjs-chart.js is 3.9; npm has the maintained versions. They go to one folder that the
# hopnet program reads when it writes a page (TOPOS_JS_DIR overrides it at build and run time).
js_dir="${TOPOS_JS_DIR:-/usr/local/share/topos/js}"
js_packages=(three@0.187.0 chart.js@4.6.1)
js_missing=()
for spec in "${js_packages[@]}"; do
  name="${spec%@*}" version="${spec##*@}"
  have=$(node -p "require('$js_dir/node_modules/$name/package.json').version" 2>/dev/null || true)
  if [ "$have" != "$version" ]; then js_missing+=("$spec"); fi
done
if [ ${#js_missing[@]} -eq 0 ]; then
  echo "setup: JavaScript libraries present in $js_dir"
else
  echo "setup: npm install ${js_missing[*]} into $js_dir"
  $SUDO mkdir -p "$js_dir"
  $SUDO npm install --prefix "$js_dir" --no-audit --no-fund --no-update-notifier --loglevel=error "${js_missing[@]}"
fi
