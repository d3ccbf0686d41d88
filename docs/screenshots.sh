#!/usr/bin/env bash
# Regenerates the screenshots in docs/ from a quick run, headless:
#   docs/screenshots.sh [RUN_DIR]     (default: runs `fiberflow launch launch/quick.toml` first)
# Needs: rerun-sdk==0.36.3 (pip), Xvfb and a software Vulkan driver
# (apt-get install xvfb mesa-vulkan-drivers libvulkan1). Each picture: the viewer opens the
# file in an Xvfb display, is given time to load it, and writes the PNG on request; the
# script exits non-zero if any picture was not written.
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
  python3 - "$1" "$2" "$3" <<'PY'
import os, subprocess, sys, time
from rerun.experimental import ViewerClient
src, png, wait = sys.argv[1], sys.argv[2], float(sys.argv[3])
if os.path.exists(png):
    os.remove(png)
viewer = subprocess.Popen(["rerun", src, "--window-size", "1600x1000", "--port", "9877"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
try:
    time.sleep(wait)
    ViewerClient.connect("rerun+http://127.0.0.1:9877/proxy").save_screenshot(os.path.abspath(png))
    for _ in range(50):
        if os.path.exists(png) and os.path.getsize(png) > 0:
            break
        time.sleep(0.2)
finally:
    viewer.terminate()
    viewer.wait()
if not os.path.exists(png):
    sys.exit(f"no screenshot written for {src}")
print(png)
PY
}
shot "$run/run.rrd" docs/rerun-quick.png 40
shot "$run/run.mcap" docs/rerun-mcap-points.png 40
