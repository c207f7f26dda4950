#!/usr/bin/env bash
# The renderer checked on a real GPU in one run: every test of the gpu crate, then the frame, control-eval, export
# and drag benches at the sizes of the issue's targets (1920×1080, two 512×512×300 volumes), and the registration
# bench (a 256³ pair, the samples of mutual information and of local correlation on the CPU and on the GPU), with one
# summary. A GPU
# machine may have neither a Rust toolchain nor the network, so it is two steps:
#
#   bash data-scripts/gpu_check.sh pack          # on the build machine: release test and bench binaries, stripped,
#                                                # xz-packed into data-cache/gpu-check.tar.xz (keep it under ~20 MB:
#                                                # it travels beside the checkout's tracked files)
#   bash data-scripts/gpu_check.sh run [OUTDIR]  # on the GPU machine, from a checkout that has the pack and
#                                                # tests/data/: the tests (all binaries at once, as contention is
#                                                # part of the check), then the benches; at most 5 minutes; writes
#                                                # summary.txt and logs.tar.xz into OUTDIR (default
#                                                # data-cache/gpu-check-out)
#   bash data-scripts/gpu_check.sh smoke [OUTDIR]  # `run` with the benches at tiny sizes, to check a pack on a CPU
#                                                  # driver (lavapipe)
#
# The test binaries read their fixtures and goldens from the root they were built in; `run` links that root to this
# checkout when it is missing. Each test and bench prints its adapter; a summary that names a CPU adapter (llvmpipe,
# lavapipe) is not a GPU figure. The summary also holds the device's filter precision as the probe measured it and
# every GPU-vs-CPU verdict line (with its derived tolerance), so that a failure can be read without the logs.
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
pack="$root/data-cache/gpu-check.tar.xz"
benches=(frame control_eval export drag register)
# The pack's budget: it travels beside the checkout's tracked files, within 64 MiB together.
max_pack_bytes=$((20 * 1024 * 1024))

case "${1:-}" in
pack)
    cd "$root"
    stage="$(mktemp -d)"
    trap 'rm -rf "$stage"' EXIT
    mkdir -p "$stage/tests" "$stage/bin" "$root/data-cache"
    # The executables cargo built, from its JSON messages: every test target of the gpu crate (its unit tests too),
    # and the five benches.
    {
        cargo test --release --no-run --locked -p warpbench-gpu --message-format=json 2>/dev/null
        cargo bench --no-run --locked -p warpbench-gpu --bench frame --bench control_eval --bench export \
            -p warpbench-app --bench drag --bench register --message-format=json 2>/dev/null
    } | python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") != "compiler-artifact" or not m.get("executable"):
        continue
    kind = m["target"]["kind"]
    if "bench" in kind:
        print("bin", m["target"]["name"], m["executable"])
    elif m["profile"]["test"]:
        print("tests", "lib" if "lib" in kind else m["target"]["name"], m["executable"])
' | while read -r dir name exe; do
        strip -o "$stage/$dir/$name" "$exe"
    done
    for b in "${benches[@]}"; do
        [ -x "$stage/bin/$b" ] || { echo "gpu_check.sh: the $b bench was not built" >&2; exit 1; }
    done
    [ -n "$(ls "$stage/tests")" ] || { echo "gpu_check.sh: no test binary was built" >&2; exit 1; }
    echo "$root" >"$stage/built_root"
    git -C "$root" rev-parse HEAD >"$stage/commit"
    tar -C "$stage" -cf - tests bin built_root commit | xz -9 -T0 >"$pack"
    size=$(stat -c %s "$pack")
    echo "gpu_check.sh: $pack, $((size / 1024)) KiB: $(ls "$stage/tests" | wc -l) test binaries, ${#benches[@]} benches"
    if [ "$size" -gt "$max_pack_bytes" ]; then
        echo "gpu_check.sh: the pack is over $((max_pack_bytes / 1024 / 1024)) MiB" >&2
        exit 1
    fi
    ;;
run | smoke)
    mode="$1"
    out="${2:-$root/data-cache/gpu-check-out}"
    [ -f "$pack" ] || { echo "gpu_check.sh: $pack is missing; run 'pack' on the build machine first" >&2; exit 2; }
    mkdir -p "$out"
    work="$(mktemp -d)"
    logs="$work/logs"
    trap 'rm -rf "$work"' EXIT
    mkdir -p "$logs"
    xz -dc "$pack" | tar -C "$work" -xf -
    built_root="$(cat "$work/built_root")"
    if [ ! -e "$built_root/crates/gpu/tests/golden" ]; then
        mkdir -p "$(dirname "$built_root")" 2>/dev/null && ln -sfn "$root" "$built_root" 2>/dev/null ||
            echo "gpu_check.sh: cannot link $built_root to $root; the goldens and the demo pair are missing" >&2
    fi
    summary="$out/summary.txt"
    started=$(date +%s)
    {
        echo "gpu_check.sh $mode: commit $(cat "$work/commit"), $(date -u +%Y-%m-%dT%H:%MZ)"
        nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv,noheader 2>/dev/null || true
        echo "$(nproc) CPU cores"
    } >"$summary"
    export REQUIRE_GPU_ADAPTER=1 RUST_BACKTRACE=1

    # Tests: every binary at once (two threads each), as the first real-GPU run did: sharing the GPU is part of the
    # check (a wait that never returns shows as a timeout). Each has 150 s; one still running then has its threads'
    # stacks written to its log (gdb or cuda-gdb, where the machine has one) before it is stopped.
    echo "== tests" >>"$summary"
    debugger="$(command -v gdb || command -v cuda-gdb || true)"
    pids=()
    for t in "$work"/tests/*; do
        name="$(basename "$t")"
        (
            cd "$built_root/crates/gpu" 2>/dev/null || cd "$root/crates/gpu"
            log="$logs/test_$name.log"
            "$t" --test-threads 2 --nocapture >"$log" 2>&1 &
            pid=$!
            for _ in $(seq 150); do
                kill -0 "$pid" 2>/dev/null || break
                sleep 1
            done
            if kill -0 "$pid" 2>/dev/null; then
                echo "gpu_check.sh: still running after 150 s; the threads' stacks:" >>"$log"
                [ -n "$debugger" ] && timeout 60 "$debugger" -batch -p "$pid" -ex 'thread apply all bt' >>"$log" 2>&1
                kill -9 "$pid" 2>/dev/null
                wait "$pid" 2>/dev/null
                echo 124 >"$logs/test_$name.rc"
            else
                wait "$pid"
                echo $? >"$logs/test_$name.rc"
            fi
        ) &
        pids+=($!)
    done
    wait "${pids[@]}" || true
    passed=0
    failed=0
    for t in "$work"/tests/*; do
        name="$(basename "$t")"
        log="$logs/test_$name.log"
        rc="$(cat "$logs/test_$name.rc" 2>/dev/null || echo '?')"
        result="$(grep -E '^test result' "$log" | tail -n 1 || true)"
        [ "$rc" = 0 ] && passed=$((passed + 1)) || failed=$((failed + 1))
        [ "$rc" = 124 ] && result="TIMED OUT after 150 s (a wait that never returned?)"
        echo "-- $name (rc $rc): ${result:-no result line}" >>"$summary"
        # Failures with their messages; the tests' own verdict lines (derived tolerances, measured distances); for a
        # binary that timed out, where its threads were (the hang guards' phases, the stacks' warpbench frames).
        grep -E '^test .* FAILED$|panicked at|has been running for over|hang guard|phase' "$log" | head -n 20 \
            >>"$summary" || true
        [ "$rc" = 124 ] && { grep -E '^Thread |warpbench|wgpu|vk[A-Z]' "$log" | head -n 40 >>"$summary" || true; }
        grep -A3 'panicked at' "$log" | grep -vE 'panicked at|^--$|stack backtrace|^ +[0-9]+:' | head -n 12 \
            >>"$summary" || true
        grep -E 'filter [0-9]+ bits|trilinear filter weights|hits on both|worst distance|allowed' "$log" |
            sort -u | head -n 40 >>"$summary" || true
    done
    echo "tests: $passed binaries passed, $failed failed" >>"$summary"

    # Benches, one after another.
    bin="$work/bin"
    bench() { # LOG BENCH ARGS...
        local log="$logs/$1.log" exe="$bin/$2"
        shift 2
        echo "== $(basename "$exe") $*" >>"$summary"
        local t0=$SECONDS
        # Each bench only runs with --bench among its arguments, as cargo passes it.
        if (cd "$built_root" 2>/dev/null || cd "$root"; timeout 150 "$exe" "$@" --bench) >"$log" 2>&1; then
            echo "(rc 0, $((SECONDS - t0)) s)" >>"$summary"
        else
            echo "(rc $?, $((SECONDS - t0)) s; see $(basename "$log"))" >>"$summary"
        fi
        tail -n 30 "$log" >>"$summary"
    }
    if [ "$mode" = run ]; then
        bench frame_big frame --size 1920x1080 --dims 512x512x300 --frames 20
        # The same with half-float control textures: does a 64-bit texel make the pull-back cheaper here?
        bench frame_big_ctrl_f16 frame --size 1920x1080 --dims 512x512x300 --frames 20 --ctrl-f16
        bench frame_procedural frame --procedural --size 1920x1080 --dims 256x256x192 --frames 20
        bench frame_procedural_ctrl_f16 frame --procedural --size 1920x1080 --dims 256x256x192 --frames 20 --ctrl-f16
        bench drag100 drag --size 1920x1080 --pairs 100 --events 20 --gpu-eval
        bench drag1000 drag --size 1920x1080 --pairs 1000 --events 20 --gpu-eval
        # The same drag refitting in full at every event: the route before issue 28's drag path.
        bench drag1000_refit drag --size 1920x1080 --pairs 1000 --events 10 --gpu-eval --full-refit
        bench control_eval control_eval --iterations 50
        bench export export --dims 512 --repeats 3
        bench register register --size 256 --rounds 3
        bench register_lncc register --size 256 --rounds 1 --metric lncc
    else
        bench frame_big frame --size 64x64 --dims 32x32x32 --frames 1
        bench frame_procedural frame --procedural --size 64x64 --dims 32x32x32 --frames 1
        bench drag100 drag --size 64x64 --pairs 20 --events 1 --gpu-eval
        bench control_eval control_eval --iterations 1
        bench export export --dims 32 --ctrl 8 --centres 20 --repeats 1
        bench register register --size 32 --rounds 1
        bench register_lncc register --size 32 --rounds 1 --metric lncc
    fi
    echo "== $(($(date +%s) - started)) s in all" >>"$summary"
    tar -C "$work" -cf - logs | xz -6 >"$out/logs.tar.xz"
    cat "$summary"
    [ "$failed" = 0 ]
    ;;
*)
    echo "usage: bash data-scripts/gpu_check.sh pack | run [OUTDIR] | smoke [OUTDIR]" >&2
    exit 2
    ;;
esac
