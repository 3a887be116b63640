"""Open a campaign's report.html in headless Chromium: a screenshot, its console messages (a
page without error prints none), and whether its script sorted the trials table.

    python benchmarks/report_in_chromium.py out/report-demo/report.html --screenshot report.png

Needs a Chromium on PATH (``chromium``; not a Python package, so not in the test extra).
Exit status 1 if the page logged anything to its console or its table was not sorted.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path)
    ap.add_argument("--screenshot", type=Path, default=Path("report.png"))
    ap.add_argument("--size", default="1200,1600", help="window width,height [px]")
    args = ap.parse_args()
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("report_in_chromium: no chromium on PATH", file=sys.stderr)
        return 2
    if not args.report.is_file():
        print(f"report_in_chromium: {args.report}: no such file", file=sys.stderr)
        return 2
    url = args.report.resolve().as_uri()
    base = [browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"]
    shot = subprocess.run([*base, f"--window-size={args.size}", "--enable-logging=stderr",
                           "--v=0", f"--screenshot={args.screenshot.resolve()}", url],
                          capture_output=True, text=True, timeout=120)
    console = [ln for ln in shot.stderr.splitlines() if ":CONSOLE" in ln]
    dom = subprocess.run([*base, "--dump-dom", url], capture_output=True, text=True,
                         timeout=120).stdout
    sorted_by = re.findall(r'<th class="sorted[^"]*">([^<]*)', dom)
    print(f"screenshot {args.screenshot} ({args.screenshot.stat().st_size} bytes); "
          f"console messages: {len(console)}; trials sorted by: "
          f"{sorted_by[0] if sorted_by else 'nothing'}")
    for ln in console:
        print("  " + ln)
    return 0 if not console and sorted_by else 1


if __name__ == "__main__":
    sys.exit(main())
