#!/usr/bin/env bash
# The GPU benchmarks of issue 15 (target 5) and issue 17 (shader vs texture) in one run, for a machine with a real GPU: the frame, control-eval,
# export and drag benches at 1920×1080 with 512×512×300 volumes where the bench takes a size. A GPU machine may have
# neither a Rust toolchain nor the network, so it is two steps:
#
#   bash data-scripts/gpu_bench.sh pack          # on the build machine: release bench binaries, stripped, packed
#                                                # into data-cache/gpu-bench.tar.gz (about 30 MB), with the root
#                                                # they were built in
#   bash data-scripts/gpu_bench.sh run [OUTDIR]  # on the GPU machine, from a checkout that has data-cache/ and
#                                                # tests/data/: runs everything (a few minutes) and writes one log
#                                                # per bench and summary.txt into OUTDIR (default
#                                                # data-cache/gpu-bench-out)
#   bash data-scripts/gpu_bench.sh smoke [OUTDIR]  # `run` at tiny sizes, to check the pack on a CPU driver
#
# The drag bench reads the demo pair from the tests/data/ of the root it was built in; `run` links that root to this
# checkout when it is missing (when it cannot, the bench says it uses the procedural phantom pair instead).
# Each bench prints its adapter first; a run that reports a CPU adapter (llvmpipe, lavapipe) is not a GPU figure.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
pack="$root/data-cache/gpu-bench.tar.gz"
benches=(frame control_eval export drag)

case "${1:-}" in
pack)
    cd "$root"
    stage="$(mktemp -d)"
    trap 'rm -rf "$stage"' EXIT
    mkdir -p "$stage/bin" "$root/data-cache"
    # The executables cargo built for each bench, from its JSON messages.
    cargo bench --no-run -p warpbench-gpu --bench frame --bench control_eval --bench export \
        -p warpbench-app --bench drag --message-format=json 2>/dev/null |
        python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and "bench" in m["target"]["kind"]:
        print(m["target"]["name"], m["executable"])
' | while read -r name exe; do
        strip -o "$stage/bin/$name" "$exe"
    done
    for b in "${benches[@]}"; do
        [ -x "$stage/bin/$b" ] || { echo "gpu_bench.sh: the $b bench was not built" >&2; exit 1; }
    done
    echo "$root" >"$stage/built_root"
    git -C "$root" rev-parse HEAD >"$stage/commit"
    tar -C "$stage" -czf "$pack" bin built_root commit
    ls -l "$pack"
    ;;
run | smoke)
    out="${2:-$root/data-cache/gpu-bench-out}"
    [ -f "$pack" ] || { echo "gpu_bench.sh: $pack is missing; run 'pack' on the build machine first" >&2; exit 2; }
    mkdir -p "$out"
    work="$(mktemp -d)"
    trap 'rm -rf "$work"' EXIT
    tar -C "$work" -xzf "$pack"
    built_root="$(cat "$work/built_root")"
    if [ ! -e "$built_root/tests/data/nifti" ]; then
        mkdir -p "$(dirname "$built_root")" 2>/dev/null && ln -sfn "$root" "$built_root" 2>/dev/null ||
            echo "gpu_bench.sh: cannot link $built_root to $root; the drag bench uses the phantom pair" >&2
    fi
    summary="$out/summary.txt"
    {
        echo "commit $(cat "$work/commit"), $(date -u +%Y-%m-%dT%H:%MZ)"
        nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null || true
        nproc
    } >"$summary"
    bin="$work/bin"
    run_one() { # LOG BENCH ARGS...
        local log="$out/$1.log" exe="$bin/$2"
        shift 2
        echo "== $(basename "$exe") $*" | tee -a "$summary"
        # Each bench only runs with --bench among its arguments, as cargo passes it.
        if timeout 300 "$exe" "$@" --bench >"$log" 2>&1; then
            tail -n 40 "$log" >>"$summary"
        else
            echo "(exit $?; see $log)" | tee -a "$summary"
            tail -n 20 "$log" >>"$summary"
        fi
    }
    if [ "$1" = run ]; then
        run_one frame frame --size 1920x1080 --dims 512x512x300 --frames 20
        # Issue 17: Brunet et al. 2006's Table 1, the same deformation in the shader and through a 64³ texture.
        run_one frame_procedural frame --procedural --size 1920x1080 --dims 256x256x192 --frames 20
        run_one control_eval control_eval --iterations 50
        run_one control_eval_n1000 control_eval --n 1000 --iterations 50
        run_one export export --dims 512 --repeats 3
        run_one drag drag --size 1920x1080 --pairs 100 --events 20 --gpu-eval
        run_one drag_n1000 drag --size 1920x1080 --pairs 1000 --events 20 --gpu-eval
    else
        run_one frame frame --size 64x64 --dims 32x32x32 --frames 1
        run_one frame_procedural frame --procedural --size 64x64 --dims 32x32x32 --frames 1
        run_one control_eval control_eval --iterations 1
        run_one export export --dims 32 --tps-dims 8 --gpu-tps-dims 8 --ctrl 8 --repeats 1
        run_one drag drag --size 64x64 --pairs 20 --events 1
    fi
    cat "$summary"
    ;;
*)
    echo "usage: bash data-scripts/gpu_bench.sh pack | run [OUTDIR] | smoke [OUTDIR]" >&2
    exit 2
    ;;
esac
