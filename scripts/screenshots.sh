#!/usr/bin/env bash
# Regenerates the screenshots in docs/ from a quick run, headless:
#   scripts/screenshots.sh [RUN_DIR]     (default: runs `fiberflow launch launch/quick.toml` first)
# Needs: rerun-sdk==0.36.3 (pip), Xvfb and a software Vulkan driver
# (apt-get install xvfb mesa-vulkan-drivers libvulkan1; xdotool, if present, parks the
# pointer). Each picture: the viewer opens the
# file in an Xvfb display, is given time to load it, writes the PNG on request and is then
# closed with Ctrl-C. The script fails if a picture was not written or the viewer ended
# otherwise: a viewer that exits on its own (a crash while loading or drawing) passes its
# exit status on; one that closes on Ctrl-C with another status than 0 or 130 fails it.
set -euo pipefail
cd "$(dirname "$0")/.."
run="${1:-}"
if [[ -z "$run" ]]; then
  run="$(mktemp -d)/quick"
  cargo run --release --bin fiberflow -- launch launch/quick.toml --out "$run"
fi
if [[ -z "${DISPLAY:-}" ]]; then
  Xvfb :99 -screen 0 1600x1000x24 >/dev/null 2>&1 &
  xvfb=$!
  trap 'kill $xvfb 2>/dev/null || true' EXIT
  export DISPLAY=:99
  sleep 2
fi
shot() { # FILE PNG SECONDS_TO_LOAD
  # the pointer rests in the bottom-right corner, so no hover tooltip covers the picture
  command -v xdotool >/dev/null && xdotool mousemove 1599 999 || true
  python3 - "$1" "$2" "$3" <<'PY'
import os, signal, subprocess, sys, time
from rerun.experimental import ViewerClient
src, png, wait = sys.argv[1], sys.argv[2], float(sys.argv[3])
if os.path.exists(png):
    os.remove(png)
viewer = subprocess.Popen(["rerun", src, "--window-size", "1600x1000", "--port", "9877"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
deadline = time.time() + wait
while time.time() < deadline and viewer.poll() is None:
    time.sleep(0.5)
if viewer.poll() is not None:
    # the viewer died while loading: its own status is ours
    print(f"the viewer exited with status {viewer.returncode} while loading {src}", file=sys.stderr)
    sys.exit(viewer.returncode or 1)
ViewerClient.connect("rerun+http://127.0.0.1:9877/proxy").save_screenshot(os.path.abspath(png))
for _ in range(50):
    if os.path.exists(png) and os.path.getsize(png) > 0 or viewer.poll() is not None:
        break
    time.sleep(0.2)
if viewer.poll() is not None:
    print(f"the viewer exited with status {viewer.returncode} while writing {png}", file=sys.stderr)
    sys.exit(viewer.returncode or 1)
# closed as from its terminal (Ctrl-C); 130 is its normal answer to that
viewer.send_signal(signal.SIGINT)
try:
    status = viewer.wait(timeout=30)
except subprocess.TimeoutExpired:
    viewer.kill()
    sys.exit(f"the viewer did not close on Ctrl-C after writing {png}")
if status not in (0, 130):
    sys.exit(f"the viewer closed with status {status} after writing {png}")
if not os.path.exists(png):
    sys.exit(f"no screenshot written for {src}")
print(png)
PY
}
shot "$run/run.rrd" docs/rerun-quick.png 40
shot "$run/run.mcap" docs/rerun-mcap-points.png 40
