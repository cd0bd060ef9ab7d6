"""Screenshot of `terra view` for the README: open a bundle in the viewer, run a find query and a
plan through the page in headless Chromium (scripts/setup-test-browser.sh), save a PNG.

    python scripts/viewer_screenshot.py campus.terra docs/viewer.png \
        --query "get bike from the bicycle rack" --goal "get bike from the bicycle rack" --prefer sidewalk
"""

from __future__ import annotations

import argparse
import time

from terra.loaded import LoadedBundle
from terra.viewer.app import TerraViewer, free_port
from terra.viewer.browser import HeadlessPage, browser_missing


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("bundle")
    parser.add_argument("out")
    parser.add_argument("--query", default="")
    parser.add_argument("--goal", default="")
    parser.add_argument("--start", default="")
    parser.add_argument("--prefer", default="")
    parser.add_argument("--size", default="1400x900")
    args = parser.parse_args()
    if browser_missing():
        raise SystemExit(browser_missing())
    viewer = TerraViewer(LoadedBundle(args.bundle), port=free_port("127.0.0.1"))
    width, height = (int(v) for v in args.size.split("x"))
    page = HeadlessPage(viewer.url, (width, height))
    try:
        page.wait_for_text("points")
        if args.query:
            page.type_into("query", args.query)
            page.click("Run query")
            page.wait_for_text("objects for")
        if args.goal:
            page.type_into("start", args.start)
            page.type_into("goal", args.goal)
            page.type_into("prefer", args.prefer)
            page.click("Plan")
            page.wait_for_text("Path ")
        time.sleep(3.0)  # let the last scene updates draw
        page.dismiss_notifications()
        time.sleep(0.5)
        page.screenshot(args.out)
    finally:
        page.close()
        viewer.stop()
    print(args.out)


if __name__ == "__main__":
    main()
