#!/usr/bin/env bash
# Screenshots of the rerun viewer (0.36.3) on a machine without a display or GPU: the native
# viewer under Xvfb, rendering with Mesa's software Vulkan (lavapipe). The X window itself stays
# black there; rerun reads its own frame back, so --screenshot-to (first frame) and the viewer's
# gRPC screenshot (any frame) work.
#
#   scripts/rerun_screenshot.sh RECORDING.rrd BLUEPRINT.rbl OUT.png [LEFT_PRESSES]
#
# Without LEFT_PRESSES: the first frame. With it: the viewer plays for 4 s, pauses, steps back
# LEFT_PRESSES frames with the Left key (a few presses may be dropped), and saves that frame.
# Needs: apt-get install xvfb xdotool mesa-vulkan-drivers; pip install rerun-sdk==0.36.3.
set -euo pipefail
rrd=$1 blueprint=$2 out=$3 presses=${4:-}
display=:78
Xvfb $display -screen 0 2000x1300x24 & xvfb=$!
trap 'kill $xvfb ${viewer:-} 2>/dev/null || true' EXIT
export DISPLAY=$display XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg-rerun}
mkdir -p -m 700 "$XDG_RUNTIME_DIR"
sleep 2
xdotool mousemove 1990 1290   # the pointer outside the window: no hover tooltips
if [ -z "$presses" ]; then
  # Saves, then exits with 102 (rerun panics on shutdown after a --screenshot-to; the PNG is whole).
  rerun --renderer vulkan --window-size 1600x1000 --screenshot-to "$out" "$rrd" "$blueprint" || true
  exit 0
fi
rerun --renderer vulkan --window-size 1600x1000 "$rrd" "$blueprint" & viewer=$!
sleep 25
xdotool windowfocus "$(xdotool search --name Rerun | head -1)"
xdotool mousemove 600 400
xdotool key space; sleep 4; xdotool key space
for _ in $(seq "$presses"); do xdotool key Left; sleep 0.15; done
xdotool mousemove 1990 1290; sleep 1
python3 -c 'import sys; from rerun.experimental import ViewerClient; ViewerClient.connect().save_screenshot(sys.argv[1])' "$out"
