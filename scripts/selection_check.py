#!/usr/bin/env python3
"""Clicks a point of a scene in the Rerun viewer, headless, and reports what changed.

    DISPLAY=:99 python3 scripts/selection_check.py RUN.rrd X Y [SECONDS_TO_LOAD [TAB_X,TAB_Y]]

TAB_X,TAB_Y, if given, is clicked first (e.g. a plot tab's title) and the two screenshots are
taken after it.

Needs rerun-sdk==0.36.3, an X display (Xvfb :99 -screen 0 1600x1000x24) and xdotool.
Writes selection-before.png and selection-after.png (1600 x 1000) in the current folder and
prints how many pixels of the plots (right half, above the legend) changed by more
than a faint re-draw: a selected fibre's line is drawn opaque and wider there.
"""
import os
import signal
import subprocess
import sys
import time

from PIL import Image, ImageChops
from rerun.experimental import ViewerClient

src, x, y = sys.argv[1], sys.argv[2], sys.argv[3]
wait = float(sys.argv[4]) if len(sys.argv) > 4 else 45.0
first = sys.argv[5].split(",") if len(sys.argv) > 5 else None
viewer = subprocess.Popen(["rerun", src, "--window-size", "1600x1000", "--port", "9877"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
time.sleep(wait)
client = ViewerClient.connect("rerun+http://127.0.0.1:9877/proxy")


def shot(name):
    # the pointer rests in a corner, so no hover highlight is in the picture
    subprocess.run(["xdotool", "mousemove", "1599", "999"], check=True)
    time.sleep(4)
    client.save_screenshot(os.path.abspath(name))
    time.sleep(3)


def click(px, py):
    subprocess.run(["xdotool", "mousemove", px, py], check=True)
    time.sleep(0.5)
    subprocess.run(["xdotool", "click", "1"], check=True)
    time.sleep(1.5)


if first:
    click(first[0], first[1])
shot("selection-before.png")
click(x, y)
shot("selection-after.png")
viewer.send_signal(signal.SIGINT)
viewer.wait(timeout=30)
plots = (850, 50, 1300, 580)
a = Image.open("selection-before.png").convert("L").crop(plots)
b = Image.open("selection-after.png").convert("L").crop(plots)
changed = ImageChops.difference(a, b).point(lambda v: 255 if v > 20 else 0).histogram()[255]
print(f"plot pixels changed by the click: {changed}")
