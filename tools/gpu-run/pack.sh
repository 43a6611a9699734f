#!/bin/bash
# Builds the GPU-side binaries on this machine (no renderer, no oneDNN, CUDA
# kernels for sm_90) and packs them, with the few shared libraries they need
# that a GPU machine's image may lack, into .gpu-carry/ at the repository
# root: the folder the device tool carries (`carry: [".gpu-carry"]`), which
# tools/gpu-run/run.sh runs from there. cuDNN is not packed: run.sh takes it
# (with NVRTC and cuBLASLt) from the GPU machine's Python packages.
#
#   tools/gpu-run/pack.sh            # BUILD=build-gpu ARCH=90 JOBS=2
#
# Prints the packed size; fails if a binary links libcuda or a shared
# CUDA runtime, if the pack outgrows LIMIT_MB (default 16; the binaries
# and libraries, about 25 MiB, travel as carry.tar.xz, about 6), or if the
# pack and the working tree (about 48 MiB) come to more than the 64 MiB
# the device tool carries (tools/gpu-run/tree_size.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
B=${BUILD:-build-gpu}
C=.gpu-carry
LIMIT_MB=${LIMIT_MB:-16}

mkdir -p "$B"
cmake -S . -B "$B" -DCMAKE_BUILD_TYPE=Release -DCMAKE_CUDA_ARCHITECTURES="${ARCH:-90}" \
      -DHF_WITH_ONEDNN=OFF -DHF_RENDERER=OFF -DHF_BUILD_TESTS=ON > "$B/configure.log" 2>&1 ||
  { cat "$B/configure.log"; exit 1; }
grep -q "cudnn backend is built" "$B/configure.log" ||
  { echo "pack.sh: CMake found no CUDA/cuDNN: the cudnn backend would be missing" >&2; exit 1; }
nice -n 10 cmake --build "$B" -j"${JOBS:-2}" --target hairfilter hairfilterd hairfilter-load \
  test_cudnn_backend test_cudnn_graph test_cudnn_layout test_cudnn_kernels

rm -rf "$C"
mkdir -p "$C/bin" "$C/lib"
cp "$B/hairfilter" "$B/hairfilterd" "$B/hairfilter-load" "$C/bin/"
for t in backend graph layout kernels; do cp "$B/tests/gpu/test_cudnn_$t" "$C/bin/"; done

# Shared libraries, except glibc, the C++ runtime (both on every image)
# and cuDNN (from the GPU machine's Python packages).
for b in "$C"/bin/*; do ldd "$b" | awk '$3 ~ /^\// {print $3}'; done | sort -u |
  grep -vE '/(libc|libm|libdl|librt|libpthread|libstdc\+\+|libgcc_s|ld-linux[^/]*)\.so|libcudnn' |
  xargs -r cp -L -t "$C/lib"

if ldd "$C"/bin/* | grep -E 'libcuda\.|libcudart'; then
  echo "pack.sh: a binary links the CUDA driver or a shared CUDA runtime" >&2
  exit 1
fi
if ldd "$C/bin/hairfilter" | grep -qiE 'osmesa|llvm'; then
  echo "pack.sh: hairfilter links the renderer's libraries" >&2
  exit 1
fi

{
  echo "commit $(git rev-parse HEAD)$(git diff --quiet HEAD -- . ':!.gpu-carry' || echo ' (with local changes)')"
  echo "built $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(uname -m), $(lscpu | sed -n 's/^Model name: *//p')"
  echo "cmake -DCMAKE_CUDA_ARCHITECTURES=${ARCH:-90} -DHF_WITH_ONEDNN=OFF -DHF_RENDERER=OFF"
  /usr/local/cuda/bin/nvcc --version | tail -1
  grep -hE '#define CUDNN_(MAJOR|MINOR|PATCHLEVEL) ' /usr/local/cuda/include/cudnn_version.h | tr '\n' ' '
  echo
  (cd "$C" && du -k bin/* lib/*)
} > "$C/MANIFEST"

# Packed with xz: the carried files and the working tree travel together
# within 64 MiB, and the tree is over 40 MiB; run.sh unpacks it (with tar,
# else Python's tarfile) into a folder of its own.
progs=$(ls "$C/bin" | wc -l)
libs=$(ls "$C/lib" | wc -l)
raw=$(du -sk "$C" | cut -f1)
tar -cJf "$C/carry.tar.xz" -C "$C" bin lib
rm -rf "$C/bin" "$C/lib"
kib=$(du -sk "$C" | cut -f1)
echo "pack.sh: $C: $progs programs, $libs libraries, ${raw} KiB, packed into ${kib} KiB"
cat "$C/MANIFEST"
if [ "$kib" -gt $((LIMIT_MB * 1024)) ]; then
  echo "pack.sh: $C is over ${LIMIT_MB} MiB" >&2
  exit 1
fi
tools/gpu-run/tree_size.sh "$C"
