#!/usr/bin/env bash
# The window itself on a CPU driver (issue 15, target 4): how long a new user waits, measured on the running
# window rather than on a benchmark of its parts. Each run opens the demo pair in a fresh window on a virtual X
# server, with `--frame-log`, and, once the first full-quality 3-D view is shown, orbits the camera by a mouse drag
# in the 3-D view (a change that needs the whole view again) and waits for the full view once more.
#
#   bash data-scripts/window_bench.sh [BINARY ...]
#
# BINARY defaults to target/release/warpbench; with several, the runs alternate between them (A B A B ...), so that
# a change can be measured against its base in one sitting. ROUNDS (default 3) runs per binary. Per run it prints
#   loaded   seconds from the window's first frame to the first frame with the pair shown (reading, preparing)
#   first    seconds from that frame to the first frame that shows the full-quality 3-D view
#   change   seconds from the frame where the drag's button was released to the first full view after it
#   frames   window frames drawn while that full view was being made
# and the median of each per binary at the end. Needs Xvfb and xdotool; the window is 1280×860 (its default).
set -euo pipefail

root="$(cd "$(dirname "$0")/.." && pwd)"
rounds="${ROUNDS:-3}"
bins=("$@")
[ ${#bins[@]} -gt 0 ] || bins=("$root/target/release/warpbench")
for b in "${bins[@]}"; do
    [ -x "$b" ] || { echo "window_bench: $b is not an executable (build it: cargo build --release -p warpbench-app)" >&2; exit 2; }
done
command -v Xvfb >/dev/null && command -v xdotool >/dev/null \
    || { echo "window_bench: needs Xvfb and xdotool" >&2; exit 2; }

work="$(mktemp -d)"
xvfb_pid=""
app_pid=""
cleanup() {
    [ -n "$app_pid" ] && kill "$app_pid" 2>/dev/null || true
    [ -n "$xvfb_pid" ] && kill "$xvfb_pid" 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT
# FRAME_LOGS=DIR keeps each run's frame log there.
keep="${FRAME_LOGS:-}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$work/xdg}"
mkdir -p "$XDG_RUNTIME_DIR"

display=":$((90 + RANDOM % 100))"
Xvfb "$display" -screen 0 1920x1080x24 -nolisten tcp >/dev/null 2>&1 &
xvfb_pid=$!
export DISPLAY="$display"
for _ in $(seq 50); do xdotool getmouselocation >/dev/null 2>&1 && break; sleep 0.1; done

# Waits until the frame log $1 has a line matching the awk condition $2 (at most $3 seconds).
wait_for() {
    local log="$1" cond="$2" limit="$3" start=$SECONDS
    until [ -f "$log" ] && awk -F'\t' "$cond {found=1} END {exit !found}" "$log"; do
        if (( SECONDS - start > limit )); then
            echo "window_bench: gave up after ${limit} s waiting for: $cond" >&2
            return 1
        fi
        sleep 0.2
    done
}

results="$work/results.tsv"
for round in $(seq "$rounds"); do
    for i in "${!bins[@]}"; do
        bin="${bins[$i]}"
        log="$work/frames-$round-$i.tsv"
        # A state folder of its own per run: no autosave of another run to recover, none of the user's touched.
        WARPBENCH_STATE_DIR="$work/state-$round-$i" "$bin" --frame-log "$log" >/dev/null 2>"$work/stderr-$round-$i.txt" &
        app_pid=$!
        wait_for "$log" '$3 == "full"' 600
        window="$(xdotool search --sync --pid "$app_pid" --onlyvisible | head -1)"
        # The default layout is four-up: the 3-D view is the top left pane of the views (x 320-625, y 75-435 at the
        # default 1280×860; the settings panel is left of it, the axial slice right of it).
        xdotool mousemove --window "$window" 440 250 mousedown 1
        for step in $(seq 10); do xdotool mousemove --window "$window" $((440 + 6 * step)) 250; sleep 0.05; done
        xdotool mouseup 1
        wait_for "$log" '$4 == 1 {r=1} r && $3 == "full"' 600
        kill "$app_pid" 2>/dev/null || true
        wait "$app_pid" 2>/dev/null || true
        app_pid=""
        [ -z "$keep" ] || { mkdir -p "$keep"; cp "$log" "$keep/"; }
        awk -F'\t' -v bin="$bin" '
            /^#/ { next }
            NR == 2 { t0 = $1 }
            $2 == "ready" && ready == "" { ready = $1 }
            $3 == "full" && first == "" { first = $1 }
            $4 == 1 && first != "" && released == "" { released = $1 }
            released != "" && $1 > released && $3 == "full" && done == "" { done = $1 }
            released != "" && done == "" { frames++ }
            END { printf "%s\t%.2f\t%.2f\t%.2f\t%d\n", bin, ready - t0, first - ready, done - released, frames }
        ' "$log" | tee -a "$results" | awk -F'\t' '{printf "%s  loaded %s s  first %s s  change %s s  frames %s\n", $1, $2, $3, $4, $5}'
    done
done

echo "medians over $rounds runs ($(nproc) cores, $(date -u +%Y-%m-%d), load $(cut -d' ' -f1-3 /proc/loadavg)):"
for bin in "${bins[@]}"; do
    awk -F'\t' -v bin="$bin" '
        $1 == bin { n++; a[n] = $2; b[n] = $3; c[n] = $4 }
        function median(x, n,    i, j, t) {
            for (i = 1; i <= n; i++) for (j = i + 1; j <= n; j++) if (x[j] < x[i]) { t = x[i]; x[i] = x[j]; x[j] = t }
            return (n % 2) ? x[(n + 1) / 2] : (x[n / 2] + x[n / 2 + 1]) / 2
        }
        END { printf "%s  loaded %.2f s  first full view %.2f s  full view after a change %.2f s\n", bin, median(a, n), median(b, n), median(c, n) }
    ' "$results"
done
