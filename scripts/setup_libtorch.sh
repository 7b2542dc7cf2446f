#!/usr/bin/env bash
# Puts a CPU libtorch 2.9.0 (the version burn-tch 0.22.1's tch 0.22.0 is built against) in a
# folder outside the repository, for `cargo build --features libtorch` (docs/gpu.md).
#
# Only PyPI is needed: PyTorch's own libtorch zips are not on the package registries, so the
# library comes out of the torch 2.9.0 wheel. That wheel is a CUDA build, so:
# - the CUDA libraries are left out (no GPU is used; they would need ~3 GB of NVIDIA wheels);
# - libtorch.so, an empty library whose only job is to load libtorch_cpu and libtorch_cuda,
#   no longer asks for libtorch_cuda (patchelf, from Debian's `patchelf` package);
# - libtorch_cpu.so's profiler links the CUDA runtime and CUPTI, which come from their two
#   small NVIDIA wheels (they load without a GPU).
#
# Usage: scripts/setup_libtorch.sh [DIR]   (default: $HOME/.cache/pipeline/libtorch-2.9.0)
# Prints the environment to export for the build and for running the binary.
set -euo pipefail

dir="${1:-$HOME/.cache/pipeline/libtorch-2.9.0}"
lib="$dir/torch/lib"
if [[ -f "$lib/libtorch_cpu.so" && -f "$dir/.complete" ]]; then
    echo "libtorch 2.9.0 already in $dir" >&2
else
    command -v patchelf >/dev/null || {
        echo "patchelf is missing: apt-get install -y patchelf" >&2
        exit 1
    }
    wheels="$(mktemp -d)"
    trap 'rm -rf "$wheels"' EXIT
    echo "downloading the torch 2.9.0 wheel (about 900 MB) and the CUDA runtime wheels from PyPI" >&2
    python3 -m pip download --quiet --no-deps -d "$wheels" "torch==2.9.0" \
        "nvidia-cuda-runtime-cu12==12.8.90" "nvidia-cuda-cupti-cu12==12.8.90"
    rm -rf "$dir" && mkdir -p "$dir"
    python3 - "$wheels" "$dir" <<'EOF'
import os, sys, zipfile
wheels, out = sys.argv[1], sys.argv[2]
cuda_only = ("libtorch_cuda", "libc10_cuda", "libcaffe2_nvrtc", "libtorch_nvshmem")
os.makedirs(os.path.join(out, "torch", "lib"), exist_ok=True)
for name in sorted(os.listdir(wheels)):
    with zipfile.ZipFile(os.path.join(wheels, name)) as z:
        if name.startswith("torch-"):
            keep = [n for n in z.namelist()
                    if n.startswith(("torch/include/", "torch/share/", "torch/lib/"))
                    and not os.path.basename(n).startswith(cuda_only)]
            z.extractall(out, keep)
        else:
            for n in z.namelist():
                base = os.path.basename(n)
                if "/lib/" in n and base.startswith(("libcudart.so", "libcupti.so")):
                    with open(os.path.join(out, "torch", "lib", base), "wb") as f:
                        f.write(z.read(n))
EOF
    patchelf --remove-needed libtorch_cuda.so "$lib/libtorch.so"
    missing="$(ldd "$lib/libtorch_cpu.so" "$lib/libtorch.so" | grep 'not found' || true)"
    if [[ -n "$missing" ]]; then
        echo "libtorch in $dir still misses libraries:" >&2
        echo "$missing" >&2
        exit 1
    fi
    touch "$dir/.complete"
fi
cat <<EOF
export LIBTORCH="$dir/torch"
export LIBTORCH_CXX11_ABI=1
export LD_LIBRARY_PATH="$lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
EOF
